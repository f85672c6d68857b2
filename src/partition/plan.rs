//! The partition plan: the grid, each block's core, margin, views and points, and what each
//! block is expected to need. Written as `plan.json` beside the block folders; `merge` and the
//! Slurm scripts read it back.

use std::path::{Path, PathBuf};

use serde::{Deserialize, Serialize};

use super::assign::{views_for_block, Geometry};
use super::coarse::{CoarseModel, CoarseStart};
use super::grid::{balanced_cores, robust_bounds, Rect};
use super::ground::GroundFrame;
use crate::error::bad_input;
use crate::scene::{Scene, SceneFrame};

/// The plan file's `format` field.
pub const PLAN_FORMAT: &str = "lpmsplat-partition";
/// The plan file's `version` this build writes and reads.
pub const PLAN_VERSION: u32 = 1;

/// A block needs at least this many training views: fewer cannot constrain its geometry.
pub const MIN_BLOCK_VIEWS: usize = 3;

/// The most blocks along one side the automatic grid tries.
pub const MAX_SIDE: usize = 16;

/// Device bytes one Gaussian takes at a training run's peak, growth headroom and the tile
/// lists of wide Gaussians included: the larger of two measurements (lavapipe, SH degree 3).
/// Truck at `-r 4` after 2,000 iterations: a 405.9 MiB peak at 301,854 Gaussians, less its 219
/// images (111.5 MiB) and one step's render targets (~20 MiB), is 952 bytes a Gaussian. The
/// generated district (`generate-city`, 204,642 SfM points, `-r 4`) peaks at 311.3 MiB on its
/// first step, less 33 MiB of images and ~10 MiB of targets: 1.37 kB, since a model fresh from
/// sparse points is of wide Gaussians that each cover many tiles (docs/partition.md). On an
/// H100 Truck at full size peaks at 4.9 GB with 2.5 M Gaussians and 2.1 GB of images: ~1.1 kB.
pub const BYTES_PER_GAUSSIAN: f64 = 1400.0;
/// Device bytes a training image pixel takes (8 bits a channel, RGBA) while the image cache
/// holds them all.
pub const BYTES_PER_IMAGE_PIXEL: f64 = 4.0;
/// Device bytes per pixel of the largest image for the render targets, gradients and tile
/// lists of one step (an estimate: ~40 f32 planes).
pub const BYTES_PER_RENDER_PIXEL: f64 = 160.0;

/// How many blocks: a fixed grid, or the coarsest grid whose every block fits the targets.
#[derive(Debug, Clone, PartialEq)]
pub enum GridChoice {
    Fixed { columns: usize, rows: usize },
    Fit(Targets),
}

/// Per-block targets for [`GridChoice::Fit`]; at least one is set.
#[derive(Debug, Clone, Copy, PartialEq, Default, Serialize, Deserialize)]
pub struct Targets {
    pub max_views: Option<usize>,
    pub max_gaussians: Option<u64>,
    pub memory_mib: Option<f64>,
}

/// What `partition` was asked for.
#[derive(Debug, Clone, PartialEq)]
pub struct PartitionOptions {
    pub grid: GridChoice,
    /// Margin on each side, as a share of the core's points (see [`super::grid`]).
    pub margin: f64,
    /// The share of a view's sight in a core that makes it one of the block's views.
    pub visibility: f64,
    /// The whole model's Gaussian budget, shared among the blocks by their points.
    pub budget: Option<u64>,
    /// Without a budget, expected Gaussians per SfM point of a block's region.
    pub growth: f64,
    /// The training image cache (MiB): images beyond it stream from disk.
    pub image_cache_mib: f64,
    /// A coarse model of the whole scene every block starts from (`--coarse`).
    pub coarse: Option<CoarseModel>,
}

/// One block of a plan.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Block {
    /// `b<column>_<row>`.
    pub name: String,
    /// The block's scene folder, relative to the plan's folder.
    pub folder: PathBuf,
    /// The ground rectangle whose Gaussians the block keeps in the merge.
    pub core: Rect,
    /// The core grown by the margin: the block trains what stands here.
    pub region: Rect,
    /// Names of the scene's training views the block trains on.
    pub train_views: Vec<String>,
    /// Names of the scene's test views that see the block (its own evaluation).
    pub test_views: Vec<String>,
    /// SfM points in the region (the block's initial model).
    pub region_points: usize,
    /// SfM points in the core.
    pub core_points: usize,
    /// The block's Gaussian budget (`--budget` given) or estimate (its start included).
    pub expected_gaussians: u64,
    /// The Gaussians of its start from the coarse model (`<folder>/coarse.ply`), if the plan
    /// has one.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub start_gaussians: Option<u64>,
    /// Estimated device memory of its training run, MiB.
    pub memory_mib: f64,
}

/// The whole scene's figures, for comparison with the blocks'.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Whole {
    pub train_views: usize,
    pub test_views: usize,
    pub points: usize,
    pub expected_gaussians: u64,
    pub memory_mib: f64,
}

/// A partition plan (`plan.json`).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Plan {
    pub format: String,
    pub version: u32,
    /// The scene folder, absolute.
    pub scene: PathBuf,
    /// The whole scene's training frame (`train = scale · (user − origin)`): the merged
    /// model is written relative to the shift this frame asks for.
    pub frame_origin: [f64; 3],
    pub frame_scale: f64,
    pub ground: GroundFrame,
    /// The robust extent of the points on the ground (1st–99th percentile).
    pub bounds: Rect,
    pub columns: usize,
    pub rows: usize,
    pub margin: f64,
    pub visibility: f64,
    /// The whole model's budget, if one was given.
    pub budget: Option<u64>,
    /// `train` arguments every block's run gets (after the block's folder).
    pub train_args: Vec<String>,
    /// The coarse model every block starts from, if any (`--init-ply` of a fresh block run).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub coarse: Option<CoarseStart>,
    /// Each block grows only in its region (`train --grow-within <folder>/region.json`).
    #[serde(default, skip_serializing_if = "std::ops::Not::not")]
    pub grow_within_region: bool,
    pub whole: Whole,
    pub blocks: Vec<Block>,
}

impl Plan {
    pub fn frame(&self) -> SceneFrame {
        SceneFrame {
            origin: self.frame_origin,
            scale: self.frame_scale,
        }
    }

    /// The block whose core holds ground position `g` (exactly one, the cores tile the plane).
    pub fn owner(&self, g: [f64; 2]) -> Option<usize> {
        self.blocks.iter().position(|b| b.core.contains(g))
    }

    /// The largest block by estimated memory.
    pub fn largest(&self) -> Option<&Block> {
        self.blocks
            .iter()
            .max_by(|a, b| a.memory_mib.total_cmp(&b.memory_mib))
    }

    /// Writes the plan as JSON (atomically).
    pub fn write(&self, path: &Path) -> anyhow::Result<()> {
        let text = serde_json::to_string_pretty(self)?;
        crate::error::write_atomic(path, |f| {
            use std::io::Write;
            f.write_all(text.as_bytes())?;
            Ok(())
        })
    }

    /// Reads and checks a plan: its format and version, and that its blocks are a plan
    /// (names unique, folders relative and inside, cores tiling the ground, numbers finite).
    pub fn read(path: &Path) -> anyhow::Result<Plan> {
        let text = std::fs::read_to_string(path).map_err(|e| {
            crate::error::InputError::new(
                path,
                "plan",
                format!("cannot be read: {e}"),
                "pass the plan.json `partition` wrote",
            )
        })?;
        let plan: Plan = match serde_json::from_str(&text) {
            Ok(p) => p,
            Err(e) => return bad_input(
                path,
                "plan",
                format!("is not a partition plan: {e}"),
                "pass the plan.json `partition` wrote, or write the plan again with `partition`",
            ),
        };
        plan.check(path)?;
        Ok(plan)
    }

    fn check(&self, path: &Path) -> anyhow::Result<()> {
        let again = "write the plan again with `partition`";
        if self.format != PLAN_FORMAT {
            return bad_input(
                path,
                "format",
                format!("is '{}', not '{PLAN_FORMAT}'", self.format),
                "pass the plan.json `partition` wrote",
            );
        }
        if self.version != PLAN_VERSION {
            return bad_input(
                path,
                "version",
                format!(
                    "is {}; this build reads version {PLAN_VERSION}",
                    self.version
                ),
                again,
            );
        }
        if self.blocks.is_empty() || self.blocks.len() != self.columns * self.rows {
            return bad_input(
                path,
                "blocks",
                format!(
                    "{} blocks for a {}x{} grid",
                    self.blocks.len(),
                    self.columns,
                    self.rows
                ),
                again,
            );
        }
        let finite = |v: &[f64]| v.iter().all(|x| x.is_finite());
        let g = &self.ground;
        if !(finite(&self.frame_origin)
            && self.frame_scale.is_finite()
            && self.frame_scale > 0.0
            && finite(&g.origin)
            && finite(&g.u)
            && finite(&g.v)
            && finite(&g.up))
        {
            return bad_input(path, "frame / ground", "holds a non-finite number", again);
        }
        for (k, b) in self.blocks.iter().enumerate() {
            let field = |f: &str| format!("blocks[{k}] ({}) {f}", b.name);
            if self.blocks[..k].iter().any(|o| o.name == b.name) {
                return bad_input(path, field("name"), "appears twice", again);
            }
            let bad_folder = b.folder.is_absolute()
                || b.folder
                    .components()
                    .any(|c| !matches!(c, std::path::Component::Normal(_)));
            if bad_folder || b.folder.as_os_str().is_empty() {
                return bad_input(
                    path,
                    field("folder"),
                    format!(
                        "'{}' is not a folder inside the plan's own",
                        b.folder.display()
                    ),
                    again,
                );
            }
            let bounds = [b.core.u, b.core.v, b.region.u, b.region.v];
            if bounds
                .iter()
                .flat_map(|i| [i.lo, i.hi])
                .flatten()
                .any(|x| !x.is_finite())
            {
                return bad_input(
                    path,
                    field("core / region"),
                    "holds a non-finite bound",
                    again,
                );
            }
            if b.train_views.is_empty() {
                return bad_input(path, field("train_views"), "is empty", again);
            }
        }
        // The cores must tile the ground: every cell between their edges (and beyond the
        // outermost, and on each edge itself: the intervals are half-open) in exactly one.
        let probes = |axis: fn(&Rect) -> super::grid::Interval| {
            let mut e: Vec<f64> = self
                .blocks
                .iter()
                .flat_map(|b| [axis(&b.core).lo, axis(&b.core).hi])
                .flatten()
                .collect();
            e.sort_by(f64::total_cmp);
            e.dedup();
            let mut p: Vec<f64> = e.windows(2).map(|w| 0.5 * (w[0] + w[1])).collect();
            p.extend(e.iter().copied());
            match (e.first(), e.last()) {
                (Some(a), Some(b)) => p.extend([a - 1.0 - a.abs(), b + 1.0 + b.abs()]),
                _ => p.push(0.0),
            }
            p
        };
        let (pu, pv) = (probes(|r| r.u), probes(|r| r.v));
        if pu.len() * pv.len() * self.blocks.len() > 50_000_000 {
            return bad_input(path, "blocks", "too many blocks to check", again);
        }
        for &u in &pu {
            for &v in &pv {
                let owners = self
                    .blocks
                    .iter()
                    .filter(|o| o.core.contains([u, v]))
                    .count();
                if owners != 1 {
                    return bad_input(
                        path,
                        "blocks' cores",
                        format!(
                            "the point ({u}, {v}) of the ground lies in {owners} cores, not one"
                        ),
                        again,
                    );
                }
            }
        }
        Ok(())
    }
}

/// Estimated device memory (MiB) of a training run with `gaussians` Gaussians on `views`
/// images of `pixels` pixels each (the largest), with an image cache of `cache_mib`.
pub fn memory_estimate(gaussians: u64, views: usize, pixels: f64, cache_mib: f64) -> f64 {
    let mib = (1u64 << 20) as f64;
    let images = (views as f64 * pixels * BYTES_PER_IMAGE_PIXEL / mib).min(cache_mib);
    gaussians as f64 * BYTES_PER_GAUSSIAN / mib + images + pixels * BYTES_PER_RENDER_PIXEL / mib
}

/// Plans the partition of `scene` (loaded in its files' frame) whose training frame is
/// `frame`.
pub fn make_plan(
    scene: &Scene,
    frame: SceneFrame,
    opts: &PartitionOptions,
    train_args: Vec<String>,
) -> anyhow::Result<Plan> {
    anyhow::ensure!(
        opts.margin.is_finite() && (0.0..=2.0).contains(&opts.margin),
        "--margin {}: the margin is a share of a block's size on each side, 0 to 2 (e.g. 0.2)",
        opts.margin
    );
    anyhow::ensure!(
        opts.visibility.is_finite() && opts.visibility > 0.0 && opts.visibility <= 1.0,
        "--visibility {}: the share of a view's sight in a block, above 0 and at most 1 (e.g. 0.25)",
        opts.visibility
    );
    anyhow::ensure!(
        !scene.train.is_empty(),
        "{}: the scene has no training views to partition",
        scene.root.display()
    );
    let centres: Vec<[f64; 3]> = scene.views.iter().map(|v| v.pose.center()).collect();
    // The camera's up in the world: −(second row of R), image y pointing down.
    let ups: Vec<[f64; 3]> = scene
        .views
        .iter()
        .map(|v| v.pose.rotation[1].map(|x| -x))
        .collect();
    let positions: &[[f64; 3]] = scene.points.as_ref().map_or(&[], |p| &p.positions);
    let ground = GroundFrame::fit(&centres, &ups, positions);
    let geom = Geometry::new(scene, &ground);
    // Cut on the points, or the cameras when there are too few.
    let cut_on: &[[f64; 2]] = if geom.point_ground.len() >= super::ground::MIN_POINTS {
        &geom.point_ground
    } else {
        &geom.view_ground
    };
    let bounds = robust_bounds(cut_on);
    let pixels = scene
        .views
        .iter()
        .map(|v| v.camera.width as f64 * v.camera.height as f64)
        .fold(0.0, f64::max);
    let total_points = geom.point_ground.len();
    // Without SfM points (a transforms scene) there is nothing to estimate a block's share
    // from but its views: the budget is shared by training views, and is needed.
    if total_points == 0 {
        anyhow::ensure!(
            opts.budget.is_some_and(|b| b > 0),
            "{}: the scene has no SfM points (a transforms scene starts from random ones), so \
             the plan cannot estimate each block's Gaussians from them. Fix: give --budget N, \
             the merged model's Gaussians as a count (e.g. 500k); it is shared among the blocks \
             by their training views",
            scene.root.display()
        );
    }
    anyhow::ensure!(
        opts.coarse.is_none() || opts.budget.is_none(),
        "--coarse with --budget: every block would start above its share of the budget (it \
         holds the whole coarse model), and how to share a budget then is not measured. Fix: \
         drop one of them"
    );
    // A block that starts from the coarse model holds its start besides its own growth.
    let expected = |start: u64, region_points: usize, train_views: usize| -> u64 {
        start
            + match opts.budget {
                Some(b) if total_points == 0 => {
                    (b as f64 * train_views as f64 / scene.train.len() as f64).ceil() as u64
                }
                Some(b) => {
                    (b as f64 * region_points as f64 / total_points.max(1) as f64).ceil() as u64
                }
                None => (region_points as f64 * opts.growth).ceil() as u64,
            }
    };
    let whole_expected = opts
        .budget
        .unwrap_or((total_points as f64 * opts.growth).ceil() as u64);
    let whole = Whole {
        train_views: scene.train.len(),
        test_views: scene.test.len(),
        points: total_points,
        expected_gaussians: whole_expected,
        memory_mib: memory_estimate(
            whole_expected,
            scene.train.len(),
            pixels,
            opts.image_cache_mib,
        ),
    };
    let build = |columns: usize, rows: usize| -> Vec<Block> {
        balanced_cores(cut_on, columns, rows, opts.margin)
            .into_iter()
            .enumerate()
            .map(|(k, (core, region))| {
                let core_pts = geom.points_in(&core);
                let region_points = geom.points_in(&region).len();
                let pick = |candidates: &[usize]| {
                    let mut v: Vec<String> = views_for_block(
                        &geom,
                        candidates,
                        &core,
                        &region,
                        &core_pts,
                        opts.visibility,
                    )
                    .into_iter()
                    .map(|i| scene.views[i].name.clone())
                    .collect();
                    v.sort();
                    v
                };
                let train_views = pick(&scene.train);
                let test_views = pick(&scene.test);
                let start = opts
                    .coarse
                    .as_ref()
                    .map(|c| c.rows_for(&ground, &region).len() as u64);
                let expected_gaussians =
                    expected(start.unwrap_or(0), region_points, train_views.len());
                let name = format!("b{}_{}", k / rows, k % rows);
                Block {
                    folder: PathBuf::from("blocks").join(&name),
                    name,
                    core,
                    region,
                    memory_mib: memory_estimate(
                        expected_gaussians,
                        train_views.len(),
                        pixels,
                        opts.image_cache_mib,
                    ),
                    train_views,
                    test_views,
                    region_points,
                    core_points: core_pts.len(),
                    expected_gaussians,
                    start_gaussians: start,
                }
            })
            .collect()
    };
    let (columns, rows, blocks) = match &opts.grid {
        GridChoice::Fixed { columns, rows } => {
            anyhow::ensure!(
                *columns >= 1 && *rows >= 1 && *columns <= 64 && *rows <= 64,
                "--blocks {columns}x{rows}: give 1 to 64 blocks a side (e.g. 2x2)"
            );
            (*columns, *rows, build(*columns, *rows))
        }
        GridChoice::Fit(t) => fit_grid(t, bounds, &build)?,
    };
    for b in &blocks {
        if b.train_views.len() < MIN_BLOCK_VIEWS {
            anyhow::bail!(
                "{}: block {} of the {columns}x{rows} grid has {} training view(s) (at least \
                 {MIN_BLOCK_VIEWS}). Fix: fewer blocks, a larger --margin, or a lower --visibility",
                scene.root.display(),
                b.name,
                b.train_views.len()
            );
        }
    }
    Ok(Plan {
        format: PLAN_FORMAT.into(),
        version: PLAN_VERSION,
        scene: std::path::absolute(&scene.root)?,
        frame_origin: frame.origin,
        frame_scale: frame.scale,
        ground,
        bounds,
        columns,
        rows,
        margin: opts.margin,
        visibility: opts.visibility,
        budget: opts.budget,
        train_args,
        coarse: opts.coarse.as_ref().map(|c| c.start.clone()),
        grow_within_region: false,
        whole,
        blocks,
    })
}

/// Whether every block meets the targets; the first block and target that does not, if any.
fn misfit(blocks: &[Block], t: &Targets) -> Option<String> {
    for b in blocks {
        if b.train_views.len() < MIN_BLOCK_VIEWS {
            return Some(format!(
                "block {} has {} training view(s), fewer than {MIN_BLOCK_VIEWS}",
                b.name,
                b.train_views.len()
            ));
        }
        if let Some(m) = t.max_views.filter(|&m| b.train_views.len() > m) {
            return Some(format!(
                "block {} has {} training views (--max-views {m})",
                b.name,
                b.train_views.len()
            ));
        }
        if let Some(m) = t.max_gaussians.filter(|&m| b.expected_gaussians > m) {
            return Some(format!(
                "block {} expects {} Gaussians (--max-gaussians {m})",
                b.name, b.expected_gaussians
            ));
        }
        if let Some(m) = t.memory_mib.filter(|&m| b.memory_mib > m) {
            return Some(format!(
                "block {} needs about {:.0} MiB (--memory {m})",
                b.name, b.memory_mib
            ));
        }
    }
    None
}

/// The grid shapes the fit tries, fewest blocks first; of equal counts, the one whose blocks
/// are closest to square on the points' extent.
fn grid_shapes(bounds: Rect) -> Vec<(usize, usize)> {
    let size = |i: super::grid::Interval| match (i.lo, i.hi) {
        (Some(l), Some(h)) if h > l => h - l,
        _ => 1.0,
    };
    let aspect = size(bounds.u) / size(bounds.v);
    let mut shapes: Vec<(usize, usize)> = (1..=MAX_SIDE)
        .flat_map(|c| (1..=MAX_SIDE).map(move |r| (c, r)))
        .collect();
    let squareness = |&(c, r): &(usize, usize)| ((aspect * r as f64 / c as f64).ln()).abs();
    shapes.sort_by(|a, b| {
        (a.0 * a.1)
            .cmp(&(b.0 * b.1))
            .then(squareness(a).total_cmp(&squareness(b)))
    });
    shapes
}

fn fit_grid(
    t: &Targets,
    bounds: Rect,
    build: &dyn Fn(usize, usize) -> Vec<Block>,
) -> anyhow::Result<(usize, usize, Vec<Block>)> {
    let mut last = String::new();
    let mut tried_count = 0;
    for (c, r) in grid_shapes(bounds) {
        // Of each block count, only the squarest shape and its transpose are worth building.
        if c * r == tried_count {
            continue;
        }
        let blocks = build(c, r);
        match misfit(&blocks, t) {
            None => return Ok((c, r, blocks)),
            Some(why) => {
                last = format!("{c}x{r}: {why}");
                tried_count = c * r;
            }
        }
    }
    anyhow::bail!(
        "no grid up to {MAX_SIDE}x{MAX_SIDE} fits every block under the targets; the last tried, \
         {last}. The margins and the views that see into a block do not shrink with the grid. \
         Fix: raise the target, lower --margin or raise --visibility"
    )
}
