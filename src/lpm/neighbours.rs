//! Neighbour views (docs/algorithms/lpm.md step 3): for each training view, up to `max_neighbours` training views
//! whose optical axis makes an angle in (0, max_angle] with its own; the nearest camera centre
//! when none qualifies. Which of the qualifying views are kept is [`NeighbourChoice`]: the
//! paper's and the authors' random pick (the default), or the views that see most of the same
//! surface.
//!
//! Why overlap exists: the angle test alone says nothing about overlap. On Truck (cameras walking
//! round the truck) 70 training views lie within 45° of a typical view, most of them on the
//! other side of the truck or far along the walk; three of them at random share a median of 75
//! SfM tracks with it (9 % share none), the three that share most a median of 886. LPM pairs an
//! error region with the matched keypoints inside it, so a neighbour that sees other surfaces
//! leaves almost every region unpaired (measured at `-r 4`: 145 error regions in three steps, 4
//! paired). The authors match with SuperPoint + LightGlue, which finds some matches in most
//! pairs; our SfM tracks and classical features are sparser, so the choice matters more here.
//! Yet measured (docs/results/lpm.md, *Neighbours by overlap*), the overlap choice paired more
//! regions and made more zones without a better result: Truck `-r 4`, three seeds at 1,200
//! iterations, +0.053 dB over ADC against the random pick's +0.074, with 2.5 % more Gaussians.
//! So the random pick stays the default and overlap is an option.

use crate::scene::View;
use glam::DVec3;
use rand::seq::SliceRandom;
use rand::{Rng, SeedableRng};
use std::collections::HashMap;

/// Which of the views within the angle become a view's neighbours.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Hash)]
pub enum NeighbourChoice {
    /// The views sharing the most SfM tracks with it when the scene has tracks
    /// ([`Covisibility`]), ties and scenes without tracks by the nearest camera centre.
    Overlap,
    /// The paper and the authors' code (default): `max_neighbours` of them at random (seeded).
    #[default]
    Random,
}

impl NeighbourChoice {
    pub fn name(self) -> &'static str {
        match self {
            NeighbourChoice::Overlap => "overlap",
            NeighbourChoice::Random => "random",
        }
    }

    pub fn parse(name: &str) -> anyhow::Result<NeighbourChoice> {
        Ok(match name {
            "overlap" => NeighbourChoice::Overlap,
            "random" => NeighbourChoice::Random,
            other => anyhow::bail!(
                "LPM neighbour choice {other:?} is unknown. Fix: choose overlap or random"
            ),
        })
    }
}

/// How many SfM tracks each pair of views shares: how much of the same surface they see.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct Covisibility {
    shared: HashMap<(u32, u32), u32>,
}

impl Covisibility {
    /// From SfM tracks (per point: (view, keypoint) observations). A view observing a point
    /// twice counts once.
    pub fn from_tracks(tracks: &[Vec<(u32, u32)>]) -> Covisibility {
        let mut shared = HashMap::new();
        let mut seen: Vec<u32> = Vec::new();
        for track in tracks {
            seen.clear();
            seen.extend(track.iter().map(|&(v, _)| v));
            seen.sort_unstable();
            seen.dedup();
            for (i, &a) in seen.iter().enumerate() {
                for &b in &seen[i + 1..] {
                    *shared.entry((a, b)).or_insert(0) += 1;
                }
            }
        }
        Covisibility { shared }
    }

    /// Tracks seen by both views.
    pub fn shared(&self, a: usize, b: usize) -> u32 {
        let key = (a.min(b) as u32, a.max(b) as u32);
        self.shared.get(&key).copied().unwrap_or(0)
    }
}

/// How neighbours are chosen.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct NeighbourSettings {
    /// Largest optical-axis angle in degrees (45 by default; 90 is suggested indoors).
    pub max_angle_deg: f64,
    /// How many neighbours to keep per view (3 in the paper).
    pub max_neighbours: usize,
    /// Which of the views within the angle are kept.
    pub choice: NeighbourChoice,
    /// Seed of the [`NeighbourChoice::Random`] pick.
    pub seed: u64,
}

impl Default for NeighbourSettings {
    fn default() -> Self {
        Self {
            max_angle_deg: 45.0,
            max_neighbours: 3,
            choice: NeighbourChoice::Random,
            seed: 0,
        }
    }
}

/// How a view's neighbours were found.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum NeighbourKind {
    /// Views within the angle.
    ByAngle,
    /// None within the angle: the nearest camera centre.
    NearestCentre,
    /// No other training view exists.
    None,
}

/// The neighbours of every view (indices into `Scene::views`).
#[derive(Debug, Clone, PartialEq)]
pub struct Neighbours {
    /// Per view index; empty for views that are not training views.
    pub of: Vec<Vec<usize>>,
    pub kind: Vec<NeighbourKind>,
}

impl Neighbours {
    /// One neighbour of `view`, at random (one LPM step); `None` when it has none.
    pub fn pick(&self, view: usize, rng: &mut impl Rng) -> Option<usize> {
        self.of.get(view)?.choose(rng).copied()
    }

    /// All unordered neighbour pairs (a < b), sorted, without repeats.
    pub fn pairs(&self) -> Vec<(usize, usize)> {
        let mut p: Vec<(usize, usize)> = self
            .of
            .iter()
            .enumerate()
            .flat_map(|(v, ns)| ns.iter().map(move |&n| (v.min(n), v.max(n))))
            .collect();
        p.sort_unstable();
        p.dedup();
        p
    }
}

/// Angle in radians between the optical axes of two poses.
pub fn optical_axis_angle(a: &crate::scene::Pose, b: &crate::scene::Pose) -> f64 {
    let da = DVec3::from(a.optical_axis()).normalize_or_zero();
    let db = DVec3::from(b.optical_axis()).normalize_or_zero();
    da.dot(db).clamp(-1.0, 1.0).acos()
}

/// Chooses neighbours among the views listed in `candidates` (the training views), for each of
/// them. A view never neighbours itself; an angle of exactly 0 (same direction) does not qualify,
/// as the paper's interval is open there. Views are visited in `candidates` order with one RNG, so
/// the choice depends only on the scene, the covisibility and the seed. `covisible`: shared
/// tracks for [`NeighbourChoice::Overlap`] (`None`: rank by camera centre distance only).
pub fn select_neighbours(
    views: &[View],
    candidates: &[usize],
    covisible: Option<&Covisibility>,
    s: &NeighbourSettings,
) -> Neighbours {
    select_neighbours_at_times(views, candidates, None, covisible, s)
}

/// [`select_neighbours`] for a video scene: `times[v]` is view `v`'s time, and a view's
/// neighbours are other cameras' views of the same time (LPM in time: a zone is triangulated
/// from two views of one instant; the same camera at another time has no baseline and sees
/// other content). `None`: a still scene, every view a candidate.
pub fn select_neighbours_at_times(
    views: &[View],
    candidates: &[usize],
    times: Option<&[f64]>,
    covisible: Option<&Covisibility>,
    s: &NeighbourSettings,
) -> Neighbours {
    let same_time = |a: usize, b: usize| times.is_none_or(|t| t[a] == t[b]);
    let mut of = vec![Vec::new(); views.len()];
    let mut kind = vec![NeighbourKind::None; views.len()];
    let max_angle = s.max_angle_deg.to_radians();
    let mut rng = rand_pcg::Pcg64::seed_from_u64(s.seed ^ 0x6e65_6967_6862_6f75);
    for &v in candidates {
        let pose = &views[v].pose;
        let mut within: Vec<usize> = candidates
            .iter()
            .copied()
            .filter(|&o| o != v && same_time(o, v))
            .filter(|&o| {
                let a = optical_axis_angle(pose, &views[o].pose);
                a > 0.0 && a <= max_angle
            })
            .collect();
        if !within.is_empty() {
            match s.choice {
                NeighbourChoice::Random => within.shuffle(&mut rng),
                NeighbourChoice::Overlap => {
                    let c = DVec3::from(pose.center());
                    let dist = |o: usize| DVec3::from(views[o].pose.center()).distance_squared(c);
                    let shared = |o: usize| covisible.map_or(0, |cv| cv.shared(v, o));
                    within.sort_by(|&x, &y| {
                        shared(y)
                            .cmp(&shared(x))
                            .then(dist(x).total_cmp(&dist(y)))
                            .then(x.cmp(&y))
                    });
                }
            }
            within.truncate(s.max_neighbours.max(1));
            within.sort_unstable();
            of[v] = within;
            kind[v] = NeighbourKind::ByAngle;
            continue;
        }
        let c = DVec3::from(pose.center());
        let nearest = candidates
            .iter()
            .copied()
            .filter(|&o| o != v && same_time(o, v))
            .min_by(|&x, &y| {
                let dx = DVec3::from(views[x].pose.center()).distance_squared(c);
                let dy = DVec3::from(views[y].pose.center()).distance_squared(c);
                dx.total_cmp(&dy).then(x.cmp(&y))
            });
        if let Some(n) = nearest {
            of[v] = vec![n];
            kind[v] = NeighbourKind::NearestCentre;
        }
    }
    Neighbours { of, kind }
}
