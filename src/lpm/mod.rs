//! Localized Point Management, CPU half: correspondences (cached), neighbour views, error regions,
//! region pairing, cone intersection and error zones. See `docs/algorithms/lpm.md` (steps 1–6).
//!
//! Typical use:
//! * before training: [`load_or_build`] (or [`extract_correspondences`]) → [`Correspondences`]
//!   with its [`MatchSummary`];
//! * at each LPM step for view V: pick V' with [`Neighbours::pick`], take the regions from
//!   [`regions::error_regions`] (or a GPU block mask through [`regions::regions_from_blocks`]),
//!   then [`record::zones_for_step`] gives the [`ZoneRecord`]s to upload.
//!
//! The GPU half (steps 1–2 and 7–8) is [`gpu::LpmGpu`]; [`crate::reference::lpm_membership`] is its CPU twin.
//! [`strategy::LpmStrategy`] puts it all together as a density strategy of the trainer
//! (`crate::train::strategy`), wrapping ADC.

pub mod cache;
pub mod config;
pub mod correspondences;
mod debug_dump;
pub mod enclosing_sphere;
pub mod epipolar;
pub mod features;
pub mod gpu;
pub mod neighbours;
pub mod pairing;
pub mod record;
pub mod region_units;
pub mod regions;
pub mod report;
pub mod reset_settings;
pub mod strategy;
pub mod surface;
pub mod view_points;
pub mod zones;

pub use correspondences::PairMatches;
pub use neighbours::{NeighbourChoice, NeighbourSettings, Neighbours};
pub use record::{zones_for_step, ConeRadius, StepZones, ZoneRecord};
pub use regions::{BlockMask, Region, RegionSettings};
pub use zones::{Zone, ZoneGeometry, ZoneSettings};

use crate::scene::{Image, Scene};
use cache::{CacheMiss, Fnv};
use features::{FeatureSettings, Features};
use rayon::prelude::*;
use std::path::Path;
use std::time::Instant;

/// The cache's file name (the caller chooses the folder: the output folder or the scene's).
pub const CACHE_FILE_NAME: &str = "lpm_correspondences.bin";

/// Where correspondences come from.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Hash)]
pub enum MatchSource {
    /// SfM tracks when the scene has them, else features.
    #[default]
    Auto,
    Tracks,
    Features,
}

/// Everything that decides the correspondences (hashed into the cache key).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct MatchSettings {
    pub source: MatchSource,
    pub neighbours: NeighbourSettings,
    pub features: FeatureSettings,
    /// Feature matches farther than this (symmetric epipolar distance, pixels) are dropped; track
    /// matches are kept and only measured against it.
    pub epipolar_threshold_px: f64,
}

impl Default for MatchSettings {
    fn default() -> Self {
        Self {
            source: MatchSource::Auto,
            neighbours: NeighbourSettings::default(),
            features: FeatureSettings::default(),
            epipolar_threshold_px: 3.0,
        }
    }
}

impl MatchSettings {
    pub fn hash(&self) -> u64 {
        let mut h = Fnv::default();
        h.u64(match self.source {
            MatchSource::Auto => 0,
            MatchSource::Tracks => 1,
            MatchSource::Features => 2,
        });
        let n = &self.neighbours;
        h.f64(n.max_angle_deg)
            .u64(n.max_neighbours as u64)
            .u64(n.seed);
        // A cache built with the other choice (or before there was one) is stale.
        h.u64(match n.choice {
            neighbours::NeighbourChoice::Random => 1,
            neighbours::NeighbourChoice::Overlap => 2,
        });
        let f = &self.features;
        h.f64(f.fast_threshold as f64)
            .u64(f.max_keypoints as u64)
            .f64(f.ratio as f64)
            .u64(f.max_hamming as u64);
        h.f64(self.epipolar_threshold_px);
        h.finish()
    }

    /// The source actually used for `scene` (resolves `Auto`).
    pub fn resolved_source(&self, scene: &Scene) -> MatchSource {
        match self.source {
            MatchSource::Auto if has_tracks(scene) => MatchSource::Tracks,
            MatchSource::Auto => MatchSource::Features,
            s => s,
        }
    }
}

fn has_tracks(scene: &Scene) -> bool {
    scene
        .points
        .as_ref()
        .is_some_and(|p| p.tracks.iter().any(|t| t.len() >= 2))
        && scene
            .views
            .iter()
            .any(|v| v.keypoints.as_ref().is_some_and(|k| !k.xy.is_empty()))
}

/// Neighbours of every training view and the matches of every neighbour pair.
#[derive(Debug, Clone, PartialEq)]
pub struct Correspondences {
    pub neighbours: Neighbours,
    /// Sorted by (a, b), a < b; one entry per neighbour pair (possibly with no matches).
    pub pairs: Vec<PairMatches>,
}

impl Correspondences {
    /// The matches of the unordered pair.
    pub fn pair(&self, a: usize, b: usize) -> Option<&PairMatches> {
        let key = (a.min(b) as u32, a.max(b) as u32);
        self.pairs
            .binary_search_by(|p| (p.a, p.b).cmp(&key))
            .ok()
            .map(|i| &self.pairs[i])
    }

    /// Matches seen from `view` towards `other`: (points in `view`, points in `other`).
    pub fn oriented(
        &self,
        view: usize,
        other: usize,
    ) -> Option<correspondences::OrientedMatches<'_>> {
        self.pair(view, other)?.oriented(view)
    }
}

/// Whether the cache was used.
#[derive(Debug, Clone, PartialEq)]
pub enum CacheStatus {
    /// No cache path was given.
    NotUsed,
    Loaded,
    Built,
    /// The cache was stale or corrupt (the reason says which) and was rebuilt.
    Rebuilt(String),
}

/// What an extraction produced, for the `match` subcommand and the training log.
#[derive(Debug, Clone, PartialEq)]
pub struct MatchSummary {
    pub source: MatchSource,
    /// How the neighbour views were chosen.
    pub neighbour_choice: NeighbourChoice,
    pub pairs: usize,
    /// (a, b, matches) per pair.
    pub matches_per_pair: Vec<(u32, u32, usize)>,
    pub pairs_without_matches: usize,
    /// Matches before the epipolar filter (features) or all track matches.
    pub candidates: usize,
    /// Matches within `epipolar_threshold_px`.
    pub inliers: usize,
    /// inliers / candidates (0 when there are no candidates).
    pub inlier_ratio: f64,
    /// Symmetric epipolar distance over the candidates, pixels (NaN when there are none).
    pub epipolar_median_px: f64,
    pub epipolar_p95_px: f64,
    /// Training views whose neighbours are the nearest centre (none within the angle).
    pub views_by_nearest_centre: usize,
    /// Training views with no neighbour at all (a scene with one training view).
    pub views_without_neighbours: usize,
    /// Views (features source) where the detector found no keypoint.
    pub views_without_keypoints: usize,
    pub seconds: f64,
    pub cache: CacheStatus,
}

impl MatchSummary {
    pub fn matches_min_median_max(&self) -> (usize, usize, usize) {
        let mut m: Vec<usize> = self.matches_per_pair.iter().map(|p| p.2).collect();
        if m.is_empty() {
            return (0, 0, 0);
        }
        m.sort_unstable();
        (m[0], m[m.len() / 2], m[m.len() - 1])
    }
}

impl std::fmt::Display for MatchSummary {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        let (lo, med, hi) = self.matches_min_median_max();
        writeln!(
            f,
            "source: {:?}   neighbours: {}   cache: {:?}   time: {:.2} s",
            self.source,
            self.neighbour_choice.name(),
            self.cache,
            self.seconds
        )?;
        writeln!(
            f,
            "pairs: {} ({} without matches)   matches per pair: min {lo} / median {med} / max {hi}",
            self.pairs, self.pairs_without_matches
        )?;
        writeln!(
            f,
            "epipolar inliers: {}/{} ({:.1} %)   symmetric epipolar error: median {:.3} px, p95 {:.3} px",
            self.inliers,
            self.candidates,
            100.0 * self.inlier_ratio,
            self.epipolar_median_px,
            self.epipolar_p95_px
        )?;
        write!(
            f,
            "views: {} by nearest centre, {} without neighbours, {} without keypoints",
            self.views_by_nearest_centre,
            self.views_without_neighbours,
            self.views_without_keypoints
        )
    }
}

/// Loads an image for view index `i` at the view's training resolution.
pub type ImageLoader<'a> = &'a (dyn Fn(usize) -> anyhow::Result<Image> + Sync);

fn percentile(sorted: &[f64], q: f64) -> f64 {
    if sorted.is_empty() {
        return f64::NAN;
    }
    sorted[((q * (sorted.len() - 1) as f64).round() as usize).min(sorted.len() - 1)]
}

fn epipolar_errors(scene: &Scene, p: &PairMatches) -> Vec<f64> {
    let (va, vb) = (&scene.views[p.a as usize], &scene.views[p.b as usize]);
    let f = epipolar::fundamental(&va.camera, &va.pose, &vb.camera, &vb.pose);
    p.xy_a
        .iter()
        .zip(&p.xy_b)
        .map(|(a, b)| {
            epipolar::symmetric_epipolar_distance(
                &f,
                [a[0] as f64, a[1] as f64],
                [b[0] as f64, b[1] as f64],
            )
        })
        .collect()
}

/// Pair statistics common to every path; `candidate_errors` holds the epipolar errors of all
/// candidates.
fn summarise(
    source: MatchSource,
    settings: &MatchSettings,
    neighbours: &Neighbours,
    scene: &Scene,
    pairs: &[PairMatches],
    mut candidate_errors: Vec<f64>,
) -> MatchSummary {
    let threshold = settings.epipolar_threshold_px;
    candidate_errors.sort_by(|a, b| a.total_cmp(b));
    let inliers = candidate_errors.iter().filter(|&&e| e <= threshold).count();
    let candidates = candidate_errors.len();
    let train = &scene.train;
    MatchSummary {
        source,
        neighbour_choice: settings.neighbours.choice,
        pairs: pairs.len(),
        matches_per_pair: pairs.iter().map(|p| (p.a, p.b, p.len())).collect(),
        pairs_without_matches: pairs.iter().filter(|p| p.is_empty()).count(),
        candidates,
        inliers,
        inlier_ratio: if candidates > 0 {
            inliers as f64 / candidates as f64
        } else {
            0.0
        },
        epipolar_median_px: percentile(&candidate_errors, 0.5),
        epipolar_p95_px: percentile(&candidate_errors, 0.95),
        views_by_nearest_centre: train
            .iter()
            .filter(|&&v| neighbours.kind.get(v) == Some(&neighbours::NeighbourKind::NearestCentre))
            .count(),
        views_without_neighbours: train
            .iter()
            .filter(|&&v| neighbours.of.get(v).is_none_or(|n| n.is_empty()))
            .count(),
        views_without_keypoints: 0,
        seconds: 0.0,
        cache: CacheStatus::NotUsed,
    }
}

/// The neighbours of `scene`'s training views (at the same time in a video), ranked by shared
/// SfM tracks under [`neighbours::NeighbourChoice::Overlap`] when the scene has tracks.
pub fn scene_neighbours(scene: &Scene, s: &NeighbourSettings) -> Neighbours {
    let covisible = match (s.choice, &scene.points) {
        (neighbours::NeighbourChoice::Overlap, Some(p)) if has_tracks(scene) => {
            Some(neighbours::Covisibility::from_tracks(&p.tracks))
        }
        _ => None,
    };
    neighbours::select_neighbours_at_times(
        &scene.views,
        &scene.train,
        scene.view_times.as_deref(),
        covisible.as_ref(),
        s,
    )
}

/// Extracts the correspondences of every neighbour pair of the training views. `load_image` is
/// only called for the features source (once per view, in parallel; images are dropped after
/// detection so memory stays at a few images). `progress`, when given, gets its length set and
/// one tick per view (features) and per pair.
pub fn extract_correspondences(
    scene: &Scene,
    settings: &MatchSettings,
    load_image: ImageLoader,
    progress: Option<&indicatif::ProgressBar>,
) -> anyhow::Result<(Correspondences, MatchSummary)> {
    let start = Instant::now();
    let neighbours = scene_neighbours(scene, &settings.neighbours);
    let pair_list = neighbours.pairs();
    let source = settings.resolved_source(scene);
    let thr = settings.epipolar_threshold_px;
    let tick = || {
        if let Some(p) = progress {
            p.inc(1);
        }
    };

    let (pairs, errors, no_kp) = match source {
        MatchSource::Tracks | MatchSource::Auto => {
            if let Some(p) = progress {
                p.set_length(pair_list.len() as u64);
            }
            let index = correspondences::TrackIndex::new(scene)?;
            let pairs: Vec<PairMatches> = pair_list
                .par_iter()
                .map(|&(a, b)| {
                    let m = index.matches(scene, a, b);
                    tick();
                    m
                })
                .collect();
            let errors: Vec<f64> = pairs
                .iter()
                .flat_map(|p| epipolar_errors(scene, p))
                .collect();
            (pairs, errors, 0)
        }
        MatchSource::Features => {
            let mut used: Vec<usize> = pair_list.iter().flat_map(|&(a, b)| [a, b]).collect();
            used.sort_unstable();
            used.dedup();
            if let Some(p) = progress {
                p.set_length((used.len() + pair_list.len()) as u64);
            }
            let feats: Vec<(usize, Features)> = used
                .par_iter()
                .map(|&v| {
                    let img = load_image(v)?;
                    let mut f = features::detect_and_describe(&img, &settings.features);
                    // Keypoints must be in the camera's pixels even if the loader returned another size.
                    let cam = &scene.views[v].camera;
                    if img.width != cam.width || img.height != cam.height {
                        let (sx, sy) = (
                            cam.width as f32 / img.width as f32,
                            cam.height as f32 / img.height as f32,
                        );
                        for p in &mut f.xy {
                            *p = [p[0] * sx, p[1] * sy];
                        }
                    }
                    tick();
                    Ok((v, f))
                })
                .collect::<anyhow::Result<_>>()?;
            let no_kp = feats.iter().filter(|(_, f)| f.xy.is_empty()).count();
            let get = |v: usize| &feats[feats.binary_search_by_key(&v, |e| e.0).unwrap_or(0)].1;
            let results: Vec<(PairMatches, Vec<f64>)> = pair_list
                .par_iter()
                .map(|&(a, b)| {
                    let (fa, fb) = (get(a), get(b));
                    let (va, vb) = (&scene.views[a], &scene.views[b]);
                    let fm = epipolar::fundamental(&va.camera, &va.pose, &vb.camera, &vb.pose);
                    let mut pm = PairMatches {
                        a: a as u32,
                        b: b as u32,
                        ..Default::default()
                    };
                    let mut errs = Vec::new();
                    for (i, j) in features::match_features(fa, fb, &settings.features) {
                        let (pa, pb) = (fa.xy[i], fb.xy[j]);
                        let e = epipolar::symmetric_epipolar_distance(
                            &fm,
                            [pa[0] as f64, pa[1] as f64],
                            [pb[0] as f64, pb[1] as f64],
                        );
                        errs.push(e);
                        if e <= thr {
                            pm.xy_a.push(pa);
                            pm.xy_b.push(pb);
                        }
                    }
                    tick();
                    (pm, errs)
                })
                .collect();
            let errors = results.iter().flat_map(|r| r.1.iter().copied()).collect();
            (results.into_iter().map(|r| r.0).collect(), errors, no_kp)
        }
    };
    let mut summary = summarise(source, settings, &neighbours, scene, &pairs, errors);
    summary.views_without_keypoints = no_kp;
    summary.seconds = start.elapsed().as_secs_f64();
    Ok((Correspondences { neighbours, pairs }, summary))
}

/// Loads the correspondences from `cache_path` when it matches the scene and settings, else
/// extracts them and writes the cache (atomically). A stale or corrupt cache is rebuilt and the
/// reason reported in [`MatchSummary::cache`].
pub fn load_or_build(
    scene: &Scene,
    settings: &MatchSettings,
    cache_path: &Path,
    load_image: ImageLoader,
    progress: Option<&indicatif::ProgressBar>,
) -> anyhow::Result<(Correspondences, MatchSummary)> {
    let start = Instant::now();
    let (sh, st) = (cache::scene_hash(scene), settings.hash());
    let miss = match cache::read_cache(cache_path, sh, st, scene.views.len()) {
        Ok(pairs) => {
            let neighbours = scene_neighbours(scene, &settings.neighbours);
            let expected = neighbours.pairs();
            let got: Vec<(usize, usize)> =
                pairs.iter().map(|p| (p.a as usize, p.b as usize)).collect();
            if got == expected {
                let errors = pairs
                    .iter()
                    .flat_map(|p| epipolar_errors(scene, p))
                    .collect();
                let source = settings.resolved_source(scene);
                let mut summary = summarise(source, settings, &neighbours, scene, &pairs, errors);
                summary.cache = CacheStatus::Loaded;
                summary.seconds = start.elapsed().as_secs_f64();
                return Ok((Correspondences { neighbours, pairs }, summary));
            }
            CacheMiss::Stale("its pairs are not this scene's neighbour pairs".into())
        }
        Err(m) => m,
    };
    let (corr, mut summary) = extract_correspondences(scene, settings, load_image, progress)?;
    cache::write_cache(cache_path, sh, st, &corr.pairs)?;
    summary.cache = match miss {
        CacheMiss::Missing => CacheStatus::Built,
        CacheMiss::Stale(why) => {
            CacheStatus::Rebuilt(format!("{}: stale: {why}", cache_path.display()))
        }
        CacheMiss::Corrupt(why) => {
            CacheStatus::Rebuilt(format!("{}: corrupt: {why}", cache_path.display()))
        }
    };
    summary.seconds = start.elapsed().as_secs_f64();
    Ok((corr, summary))
}
