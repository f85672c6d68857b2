//! LPM correspondences on the real scenes in ../shared/data (skipped, with a message, when the
//! folder is absent) and on the shipped small copy of lund_door (always).

use lpmsplat::lpm::{self, MatchSettings, MatchSource};
use lpmsplat::scene::{images, LoadOptions, Scene};
use std::path::Path;

fn matches(scene: &Scene, source: MatchSource) -> lpm::MatchSummary {
    let settings = MatchSettings {
        source,
        ..MatchSettings::default()
    };
    let loader = |i: usize| -> anyhow::Result<images::Image> {
        Ok(images::load_images(scene, &[i])?.remove(0))
    };
    let (_c, summary) = lpm::extract_correspondences(scene, &settings, &loader, None).unwrap();
    summary
}

fn check_door(root: &Path, factor: u32) {
    let opts = LoadOptions {
        resolution_factor: Some(factor),
        ..LoadOptions::default()
    };
    let scene = Scene::load(root, &opts).unwrap();
    let tracks = matches(&scene, MatchSource::Tracks);
    eprintln!("{} -r {factor} tracks: {tracks}", root.display());
    assert!(tracks.pairs > 0 && tracks.pairs_without_matches == 0);
    // SfM tracks are verified correspondences: they satisfy the epipolar constraint of the known
    // poses to well within a pixel (after undistortion), at any resolution.
    assert!(
        tracks.epipolar_median_px < 0.5,
        "median {}",
        tracks.epipolar_median_px
    );
    assert!(
        tracks.epipolar_p95_px < 2.0,
        "p95 {}",
        tracks.epipolar_p95_px
    );
    let features = matches(&scene, MatchSource::Features);
    eprintln!("{} -r {factor} features: {features}", root.display());
    assert_eq!(
        features.pairs, tracks.pairs,
        "same neighbour pairs for both sources"
    );
    assert!(
        features.inlier_ratio > 0.5,
        "classical matcher inlier ratio {}",
        features.inlier_ratio
    );
    assert!(features.inliers > 100);
}

#[test]
fn shipped_lund_door_tracks_and_features_satisfy_epipolar_geometry() {
    check_door(Path::new("tests/data/lund_door_small"), 2);
}

#[test]
fn shared_lund_door_tracks_and_features_satisfy_epipolar_geometry() {
    let root = Path::new("../shared/data/lund_door");
    if !root.exists() {
        eprintln!("skipped: {} is absent", root.display());
        return;
    }
    check_door(root, 4);
}

#[test]
fn single_image_scene_has_no_pairs_and_no_panic() {
    // One view: no neighbours, reported in the summary.
    let mut scene = Scene::load(
        Path::new("tests/data/lund_door_small"),
        &LoadOptions::default(),
    )
    .unwrap();
    scene.views.truncate(1);
    scene.train = vec![0];
    scene.test.clear();
    scene.points = None;
    let summary = matches(&scene, MatchSource::Auto);
    assert_eq!(summary.pairs, 0);
    assert_eq!(summary.views_without_neighbours, 1);
}

/// On real SfM tracks (the shipped lund_door), the overlap choice keeps, for every training
/// view, the views within the angle that share the most tracks with it, and the track matches
/// LPM then uses between two views are exactly their shared tracks.
#[test]
fn overlap_neighbours_on_real_tracks_share_the_most_matches() {
    use lpmsplat::lpm::neighbours::{optical_axis_angle, Covisibility, NeighbourChoice};
    use lpmsplat::lpm::{correspondences::TrackIndex, scene_neighbours, NeighbourSettings};
    let scene = Scene::load(
        Path::new("tests/data/lund_door_small"),
        &LoadOptions::default(),
    )
    .unwrap();
    let tracks = &scene.points.as_ref().unwrap().tracks;
    let cv = Covisibility::from_tracks(tracks);
    let index = TrackIndex::new(&scene).unwrap();
    let s = NeighbourSettings {
        choice: NeighbourChoice::Overlap,
        ..NeighbourSettings::default()
    };
    let n = scene_neighbours(&scene, &s);
    let mut compared = 0;
    for &v in &scene.train {
        let candidates: Vec<usize> = scene
            .train
            .iter()
            .copied()
            .filter(|&o| {
                let a = optical_axis_angle(&scene.views[v].pose, &scene.views[o].pose);
                o != v && a > 0.0 && a <= s.max_angle_deg.to_radians()
            })
            .collect();
        for &o in &candidates {
            assert_eq!(
                cv.shared(v, o) as usize,
                index.matches(&scene, v, o).xy_a.len(),
                "views {v}, {o}"
            );
        }
        let kept = &n.of[v];
        let least_kept = kept.iter().map(|&o| cv.shared(v, o)).min().unwrap();
        for &o in candidates.iter().filter(|o| !kept.contains(o)) {
            assert!(
                cv.shared(v, o) <= least_kept,
                "view {v}: {o} shares {} tracks, more than a kept neighbour ({least_kept})",
                cv.shared(v, o)
            );
            compared += 1;
        }
    }
    assert!(
        compared > 0,
        "some view had more candidates than neighbours"
    );
    // The summary says which choice made the pairs.
    let mut settings = MatchSettings::default();
    settings.neighbours.choice = NeighbourChoice::Overlap;
    let loader = |i: usize| -> anyhow::Result<images::Image> {
        Ok(images::load_images(&scene, &[i])?.remove(0))
    };
    let (_c, summary) = lpm::extract_correspondences(&scene, &settings, &loader, None).unwrap();
    assert!(
        summary.to_string().contains("neighbours: overlap"),
        "{summary}"
    );
}
