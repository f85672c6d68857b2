//! Initial points for scenes without an SfM point cloud (multi-view video: Panoptic, Neural 3D
//! Video), triangulated from feature matches between posed views.
//!
//! SpacetimeGaussians starts from a COLMAP point cloud per frame, triangulated with the known
//! poses (`point_triangulator`), every point tagged with its frame's time; a scene that ships
//! no points would otherwise start from random points in a box. Here, for a few frames spread
//! over the segment (a still scene: all its training views), each training view is matched with
//! its neighbour views of the same time (LPM's detector, descriptor and matcher,
//! `lpm::features`; neighbours by optical-axis angle, `lpm::neighbours`), matches off their
//! epipolar lines are dropped (`lpm::epipolar`, from the known poses), and each remaining match
//! is triangulated at the midpoint of the closest points of its two rays. A point is kept when
//! it lies in front of both cameras, reprojects within [`MAX_REPROJECTION_PX`] in both and its
//! rays meet at an angle of at least [`MIN_PARALLAX_DEG`] (below that, depth is unreliable). Its
//! colour is the mean of the two pixels; its time the frame's.

use crate::lpm::epipolar::{fundamental, symmetric_epipolar_distance};
use crate::lpm::features::{detect_and_describe, match_features, FeatureSettings, Features};
use crate::lpm::neighbours::{select_neighbours_at_times, NeighbourChoice, NeighbourSettings};
use crate::scene::images::load_view_image;
use crate::scene::{Image, PinholeCamera, Pose, Scene};
use crate::splats::GaussianParams;
use glam::DVec3;
use rand::seq::SliceRandom;
use rand::SeedableRng;
use rayon::prelude::*;

/// Frames of a video segment the points come from, spread evenly over it.
pub const VIDEO_FRAMES: usize = 10;
/// Neighbour views each view is matched with.
pub const NEIGHBOURS: usize = 2;
/// Largest symmetric epipolar distance of a kept match, pixels.
pub const MAX_EPIPOLAR_PX: f64 = 1.5;
/// Largest reprojection error of a kept point in either view, pixels.
pub const MAX_REPROJECTION_PX: f64 = 2.0;
/// Smallest angle between a kept point's two rays, degrees.
pub const MIN_PARALLAX_DEG: f64 = 2.0;
/// Views are matched at their source size, downscaled to at most this width (the training
/// size may be far coarser: Panoptic at `-r 4` is 160×90, where FAST's 20-pixel border leaves
/// little to match).
pub const MATCH_MAX_WIDTH: u32 = 1600;

/// Triangulated points: positions, colours and, for a video scene, each point's time.
#[derive(Debug, Clone, Default)]
pub struct TriangulatedPoints {
    pub positions: Vec<[f64; 3]>,
    pub colors: Vec<[u8; 3]>,
    pub times: Vec<f64>,
    /// View pairs matched and matches that passed the epipolar test.
    pub pairs: usize,
    pub matches: usize,
}

/// The world-space ray of pixel `xy` (pixel centres at +0.5): origin and unit direction.
fn pixel_ray(camera: &PinholeCamera, pose: &Pose, xy: [f64; 2]) -> (DVec3, DVec3) {
    let d_cam = [
        (xy[0] - camera.cx) / camera.fx,
        (xy[1] - camera.cy) / camera.fy,
        1.0,
    ];
    let origin = DVec3::from(pose.center());
    let through = DVec3::from(pose.inverse_transform(d_cam));
    (origin, (through - origin).normalize_or_zero())
}

/// The midpoint of the closest points of two rays, when they are not parallel and the closest
/// points lie in front of both origins; with the angle between the rays (radians).
pub fn ray_midpoint(oa: DVec3, da: DVec3, ob: DVec3, db: DVec3) -> Option<(DVec3, f64)> {
    // Minimise |oa + s·da − (ob + t·db)|² over s, t (unit directions).
    let w = oa - ob;
    let b = da.dot(db);
    let (d, e) = (da.dot(w), db.dot(w));
    let denom = 1.0 - b * b;
    if denom <= 1e-12 {
        return None;
    }
    let s = (b * e - d) / denom;
    let t = (e - b * d) / denom;
    if !(s > 0.0 && t > 0.0) {
        return None;
    }
    let p = 0.5 * ((oa + s * da) + (ob + t * db));
    Some((p, b.clamp(-1.0, 1.0).acos()))
}

/// Pixel error of `p` seen by `camera` at `pose` against `xy`; infinite behind the camera.
fn reprojection_error(camera: &PinholeCamera, pose: &Pose, p: DVec3, xy: [f64; 2]) -> f64 {
    let c = pose.transform(p.to_array());
    if c[2].is_nan() || c[2] <= 1e-9 {
        return f64::INFINITY;
    }
    let q = camera.project(c);
    (q[0] - xy[0]).hypot(q[1] - xy[1])
}

fn pixel_colour(img: &Image, xy: [f64; 2]) -> [f32; 3] {
    let x = (xy[0].floor().max(0.0) as u32).min(img.width - 1);
    let y = (xy[1].floor().max(0.0) as u32).min(img.height - 1);
    img.pixel(x, y)
}

/// A triangulated point and its colour.
type ColouredPoint = ([f64; 3], [u8; 3]);

/// One view as matched: its camera at the matching size, its features and the image's colour
/// at each keypoint (the image itself is dropped after detection, so memory does not grow with
/// the number of views: 200 N3DV views at 1600×1200 would hold 4.6 GB of f32 images).
struct Source {
    camera: PinholeCamera,
    pose: Pose,
    features: Features,
    colours: Vec<[f32; 3]>,
}

impl Source {
    fn load(scene: &Scene, v: usize, settings: &FeatureSettings) -> anyhow::Result<Source> {
        let mut view = scene.views[v].clone();
        let width = view
            .source_width
            .min(MATCH_MAX_WIDTH)
            .max(view.camera.width);
        let height = ((width as f64 * view.source_height as f64 / view.source_width as f64).round()
            as u32)
            .max(1);
        view.camera = view.camera.resized(width, height);
        let image = load_view_image(&view)?;
        let features = detect_and_describe(&image, settings);
        let colours = features
            .xy
            .iter()
            .map(|xy| pixel_colour(&image, xy.map(|v| v as f64)))
            .collect();
        Ok(Source {
            camera: view.camera,
            pose: view.pose,
            features,
            colours,
        })
    }
}

/// Triangulates the matches of one view pair: points with colours, and the matches that passed
/// the epipolar test.
fn triangulate_pair(
    a: &Source,
    b: &Source,
    settings: &FeatureSettings,
) -> (Vec<ColouredPoint>, usize) {
    let (fa, fb) = (&a.features, &b.features);
    let f = fundamental(&a.camera, &a.pose, &b.camera, &b.pose);
    let mut out = Vec::new();
    let mut kept_matches = 0;
    for (i, j) in match_features(fa, fb, settings) {
        let xa = fa.xy[i].map(|v| v as f64);
        let xb = fb.xy[j].map(|v| v as f64);
        if symmetric_epipolar_distance(&f, xa, xb) > MAX_EPIPOLAR_PX {
            continue;
        }
        kept_matches += 1;
        let (oa, da) = pixel_ray(&a.camera, &a.pose, xa);
        let (ob, db) = pixel_ray(&b.camera, &b.pose, xb);
        let Some((p, angle)) = ray_midpoint(oa, da, ob, db) else {
            continue;
        };
        if angle < MIN_PARALLAX_DEG.to_radians()
            || reprojection_error(&a.camera, &a.pose, p, xa) > MAX_REPROJECTION_PX
            || reprojection_error(&b.camera, &b.pose, p, xb) > MAX_REPROJECTION_PX
        {
            continue;
        }
        let (ca, cb) = (a.colours[i], b.colours[j]);
        let colour =
            [0, 1, 2].map(|c| ((ca[c] + cb[c]) * 0.5 * 255.0).round().clamp(0.0, 255.0) as u8);
        out.push((p.to_array(), colour));
    }
    (out, kept_matches)
}

/// The training views the points come from: for a video scene those of [`VIDEO_FRAMES`] times
/// spread evenly over its distinct times, for a still scene all of them.
pub fn source_views(scene: &Scene) -> Vec<usize> {
    let Some(times) = scene.view_times.as_deref() else {
        return scene.train.clone();
    };
    let mut distinct: Vec<f64> = scene.train.iter().map(|&v| times[v]).collect();
    distinct.sort_by(f64::total_cmp);
    distinct.dedup();
    let n = distinct.len();
    let k = VIDEO_FRAMES.min(n);
    let chosen: Vec<f64> = (0..k).map(|i| distinct[i * n / k.max(1)]).collect();
    scene
        .train
        .iter()
        .copied()
        .filter(|&v| chosen.contains(&times[v]))
        .collect()
}

/// Triangulates points for `scene` (see the module docs), at most `max_points` of them (a seeded
/// uniform subset when more were found).
pub fn triangulate_scene(
    scene: &Scene,
    max_points: usize,
    seed: u64,
) -> anyhow::Result<TriangulatedPoints> {
    let views = source_views(scene);
    let settings = FeatureSettings::default();
    let loaded: Vec<Source> = views
        .par_iter()
        .map(|&v| Source::load(scene, v, &settings))
        .collect::<anyhow::Result<_>>()?;
    let slot = |v: usize| views.iter().position(|&x| x == v).expect("a source view");
    let neighbours = select_neighbours_at_times(
        &scene.views,
        &views,
        scene.view_times.as_deref(),
        None,
        &NeighbourSettings {
            max_angle_deg: 45.0,
            max_neighbours: NEIGHBOURS,
            // The random pick this initialisation was measured with (docs/spacetime.md, Panoptic).
            choice: NeighbourChoice::Random,
            seed,
        },
    );
    let pairs = neighbours.pairs();
    let per_pair: Vec<(Vec<ColouredPoint>, usize, f64)> = pairs
        .par_iter()
        .map(|&(a, b)| {
            let (pts, kept) = triangulate_pair(&loaded[slot(a)], &loaded[slot(b)], &settings);
            let t = scene.view_times.as_deref().map_or(0.0, |t| t[a]);
            (pts, kept, t)
        })
        .collect();
    let mut all: Vec<([f64; 3], [u8; 3], f64)> = Vec::new();
    let mut matches = 0;
    for (pts, kept, t) in per_pair {
        matches += kept;
        all.extend(pts.into_iter().map(|(p, c)| (p, c, t)));
    }
    if all.len() > max_points {
        let mut rng = rand_pcg::Pcg64::seed_from_u64(seed ^ 0x7472_6961);
        all.shuffle(&mut rng);
        all.truncate(max_points);
    }
    Ok(TriangulatedPoints {
        positions: all.iter().map(|p| p.0).collect(),
        colors: all.iter().map(|p| p.1).collect(),
        times: all.iter().map(|p| p.2).collect(),
        pairs: pairs.len(),
        matches,
    })
}

/// The initial model of `tri`'s points (scales from their 3 nearest neighbours, opacity 0.1,
/// as SfM points), topped up to `total` with random points in the scene's box
/// (`Scene::random_init_box`): surfaces without texture (walls, floors, sky) get no matches,
/// and the random points give training something there. The triangulated points come first.
pub fn topped_up_model(
    tri: &TriangulatedPoints,
    scene: &Scene,
    total: usize,
    seed: u64,
    sh_degree: u32,
) -> anyhow::Result<GaussianParams> {
    use crate::splats::init::{from_sfm_points, random_init};
    let n = tri.positions.len();
    let mut params = from_sfm_points(&tri.positions, &tri.colors, sh_degree)?;
    if n < total {
        let (center, half) = scene.random_init_box();
        let r = random_init(total - n, center, [half; 3], seed, sh_degree)?;
        params.positions.extend(r.positions);
        params.log_scales.extend(r.log_scales);
        params.rotations.extend(r.rotations);
        params.opacity_logits.extend(r.opacity_logits);
        params.sh_dc.extend(r.sh_dc);
        params.sh_rest.extend(r.sh_rest);
    }
    Ok(params)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn rays_through_a_point_meet_there() {
        let p = DVec3::new(0.3, -0.2, 4.0);
        let (oa, ob) = (DVec3::new(-1.0, 0.0, 0.0), DVec3::new(1.0, 0.5, 0.0));
        let (da, db) = ((p - oa).normalize(), (p - ob).normalize());
        let (m, angle) = ray_midpoint(oa, da, ob, db).unwrap();
        assert!(m.distance(p) < 1e-12, "{m:?}");
        assert!((angle - da.angle_between(db)).abs() < 1e-12);
        // Parallel rays, and rays meeting behind an origin, give nothing.
        assert!(ray_midpoint(oa, da, ob, da).is_none());
        assert!(ray_midpoint(oa, -da, ob, -db).is_none());
    }
}
