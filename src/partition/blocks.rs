//! Each block as an ordinary scene folder: a COLMAP text model filtered to the block's views
//! and the points of its region, its images by reference (a link to the scene's `images/`
//! and its downscaled copies, never a copy), and `test_views.txt` naming its test views, so
//! `train` reads it like any other scene and holds out exactly the whole scene's test views.
//! A transforms scene's block is its transforms file(s) cut to the block's frames
//! ([`crate::scene::transforms::subset`]), with the scene's other entries linked in.

use std::collections::{HashMap, HashSet};
use std::path::{Path, PathBuf};

use super::coarse::{CoarseModel, BLOCK_START_FILE};
use super::grid::Interval;
use super::plan::{Block, Plan};
use crate::scene::colmap::{self, ColmapModel};
use crate::scene::split::TEST_VIEWS_FILE;
use crate::scene::transforms::subset::{write_subset, TRANSFORMS_FILES};
use crate::train::density::region::{GrowthRegion, RegionBand};

/// The block's COLMAP model: its views' images and cameras, the points whose ground position
/// lies in its region with their tracks cut to those images, and the images' keypoints
/// pointing at no point where theirs was left out.
pub fn block_model(model: &ColmapModel, plan: &Plan, block: &Block) -> ColmapModel {
    let names: HashSet<&str> = block
        .train_views
        .iter()
        .chain(&block.test_views)
        .map(String::as_str)
        .collect();
    let images: Vec<_> = model
        .images
        .iter()
        .filter(|im| names.contains(im.name.as_str()))
        .cloned()
        .collect();
    let image_ids: HashSet<u32> = images.iter().map(|im| im.id).collect();
    let camera_ids: HashSet<u32> = images.iter().map(|im| im.camera_id).collect();
    let points: Vec<_> = model
        .points
        .iter()
        .filter(|p| block.region.contains(plan.ground.coordinates(p.xyz).0))
        .map(|p| {
            let mut p = p.clone();
            p.track.retain(|(im, _)| image_ids.contains(im));
            p
        })
        .collect();
    let kept: HashSet<u64> = points.iter().map(|p| p.id).collect();
    let images = images
        .into_iter()
        .map(|mut im| {
            for id in &mut im.point3d_ids {
                if *id >= 0 && !kept.contains(&(*id as u64)) {
                    *id = -1;
                }
            }
            im
        })
        .collect();
    ColmapModel {
        cameras: model
            .cameras
            .iter()
            .filter(|c| camera_ids.contains(&c.id))
            .cloned()
            .collect(),
        images,
        points,
    }
}

/// Writes every block's folder under `out` (the plan's folder) from the scene's COLMAP model.
pub fn write_block_folders(
    out: &Path,
    plan: &Plan,
    model: &ColmapModel,
    scene_root: &Path,
) -> anyhow::Result<()> {
    let scene_root = std::path::absolute(scene_root)?;
    // The scene's image folders: images/ and the downscaled copies -r reads.
    let mut image_dirs = Vec::new();
    for entry in std::fs::read_dir(&scene_root)? {
        let name = entry?.file_name().to_string_lossy().into_owned();
        let is_copy = name
            .strip_prefix("images_")
            .is_some_and(|r| !r.is_empty() && r.bytes().all(|b| b.is_ascii_digit()));
        if name == "images" || is_copy {
            image_dirs.push(name);
        }
    }
    let by_name: HashMap<&str, ()> = model.images.iter().map(|i| (i.name.as_str(), ())).collect();
    for block in &plan.blocks {
        let dir = out.join(&block.folder);
        std::fs::create_dir_all(&dir)?;
        if let Some(missing) = block
            .train_views
            .iter()
            .chain(&block.test_views)
            .find(|n| !by_name.contains_key(n.as_str()))
        {
            anyhow::bail!(
                "block {}: view '{missing}' is not in the scene's model (the plan is not this \
                 scene's)",
                block.name
            );
        }
        colmap::write_text(
            &dir.join("sparse").join("0"),
            &block_model(model, plan, block),
        )?;
        for name in &image_dirs {
            let link = dir.join(name);
            if link.symlink_metadata().is_ok() {
                std::fs::remove_file(&link)?;
            }
            std::os::unix::fs::symlink(scene_root.join(name), &link)?;
        }
        let mut test = block.test_views.join("\n");
        test.push('\n');
        std::fs::write(dir.join(TEST_VIEWS_FILE), test)?;
    }
    Ok(())
}

/// Writes every block's folder under `out` (the plan's folder) for a transforms scene in
/// `scene_root`: its transforms file(s) holding the block's frames, and a link to every other
/// entry of the scene folder (its image folders, whatever they are called), except one that
/// holds `out` itself.
pub fn write_transforms_block_folders(
    out: &Path,
    plan: &Plan,
    scene_root: &Path,
) -> anyhow::Result<()> {
    let scene_root = std::path::absolute(scene_root)?;
    let out = std::path::absolute(out)?;
    let mut entries = Vec::new();
    for entry in std::fs::read_dir(&scene_root)? {
        let name = entry?.file_name().to_string_lossy().into_owned();
        let path = scene_root.join(&name);
        if TRANSFORMS_FILES.contains(&name.as_str())
            || name == TEST_VIEWS_FILE
            || out.starts_with(&path)
        {
            continue;
        }
        entries.push(name);
    }
    for block in &plan.blocks {
        let dir = out.join(&block.folder);
        write_subset(&scene_root, &dir, &block.train_views, &block.test_views)
            .map_err(|e| anyhow::anyhow!("block {}: {e:#}", block.name))?;
        for name in &entries {
            let link = dir.join(name);
            if link.symlink_metadata().is_ok() {
                std::fs::remove_file(&link)?;
            }
            std::os::unix::fs::symlink(scene_root.join(name), &link)?;
        }
    }
    Ok(())
}

/// The name of a block's growth region in its folder (`train --grow-within`).
pub const REGION_FILE: &str = "region.json";

/// Where a block's region file lies, relative to the plan's folder.
pub fn region_path(block: &Block) -> PathBuf {
    block.folder.join(REGION_FILE)
}

/// A block's region (its core grown by the margin) as a growth region in the scene's own
/// frame: a band along each ground axis, `axis · p` in `[lo, hi)` where the ground coordinate
/// `axis · (p − origin)` lies in the region's interval.
pub fn growth_region(plan: &Plan, block: &Block) -> GrowthRegion {
    let band = |axis: [f64; 3], i: Interval| {
        let at = axis[0] * plan.ground.origin[0]
            + axis[1] * plan.ground.origin[1]
            + axis[2] * plan.ground.origin[2];
        RegionBand {
            axis,
            lo: i.lo.map_or(f64::NEG_INFINITY, |l| l + at),
            hi: i.hi.map_or(f64::INFINITY, |h| h + at),
        }
    };
    GrowthRegion {
        bands: [
            band(plan.ground.u, block.region.u),
            band(plan.ground.v, block.region.v),
        ],
    }
}

/// Writes every block's growth region (`<folder>/region.json`) under the plan's folder `out`.
pub fn write_growth_regions(out: &Path, plan: &Plan) -> anyhow::Result<()> {
    for block in &plan.blocks {
        std::fs::write(
            out.join(region_path(block)),
            growth_region(plan, block).to_json().to_string(),
        )?;
    }
    Ok(())
}

/// Where a block's start lies, relative to the plan's folder.
pub fn block_start_path(block: &Block) -> PathBuf {
    block.folder.join(BLOCK_START_FILE)
}

/// Writes every block's start (`<block folder>/coarse.ply`: the rows of
/// [`CoarseModel::rows_for`], with the coarse file's header comments, so it is read in the
/// same frame as the same model) under the plan's folder `out`; each file holds as many
/// Gaussians as its block's `start_gaussians` in the plan.
pub fn write_block_starts(out: &Path, plan: &Plan, coarse: &CoarseModel) -> anyhow::Result<()> {
    for block in &plan.blocks {
        let rows = coarse.rows_for(&plan.ground, &block.region);
        anyhow::ensure!(
            Some(rows.len() as u64) == block.start_gaussians,
            "block {}: its start holds {} Gaussians, the plan counted {:?} (the coarse model \
             changed while partitioning?)",
            block.name,
            rows.len(),
            block.start_gaussians
        );
        crate::splats::write_ply_with_comments(
            &out.join(block_start_path(block)),
            &coarse.params.select_rows(&rows),
            &coarse.comments,
        )?;
    }
    Ok(())
}
