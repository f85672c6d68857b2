//! `partition`: cuts a scene into overlapping blocks on its ground plane, writes the plan, each
//! block as a scene folder, and (with `--slurm`) the job scripts that train and merge them.

use std::path::PathBuf;

use clap::Args;
use lpmsplat::partition::{self, blocks, slurm, GridChoice, PartitionOptions, Plan, Targets};
use lpmsplat::scene::{colmap, Scene, SceneFormat};

use super::SceneArgs;
use lpmsplat::train::density::growth::Budget;

#[derive(Args, Debug)]
pub struct PartitionArgs {
    #[command(flatten)]
    pub scene: SceneArgs,
    /// The plan's folder: plan.json, blocks/<name>/ (scene folders), slurm/ with --slurm; the
    /// blocks' runs go to runs/<name>/ and the merge to merged/. Must not hold a plan yet.
    #[arg(long, short = 'o')]
    pub out: PathBuf,
    /// The grid, COLUMNSxROWS (e.g. 2x2), columns along the scene's longest ground axis.
    /// Default: the coarsest grid whose every block meets --max-views / --max-gaussians /
    /// --memory (one of them is needed without --blocks).
    #[arg(long, value_name = "CxR", value_parser = parse_grid)]
    pub blocks: Option<(usize, usize)>,
    /// Per-block target: at most this many training views.
    #[arg(long, value_name = "N")]
    pub max_views: Option<usize>,
    /// Per-block target: at most this many expected Gaussians.
    #[arg(long, value_name = "N", value_parser = parse_count)]
    pub max_gaussians: Option<u64>,
    /// Per-block target: at most this much estimated device memory (MiB).
    #[arg(long, value_name = "MIB")]
    pub memory: Option<f64>,
    /// Margin on each side of a block's core, as a share of the core's size: the views over
    /// it train the block, its Gaussians are dropped in the merge.
    #[arg(long, default_value_t = 0.2)]
    pub margin: f64,
    /// A view outside a block's region joins the block when this share of what it sees (its
    /// SfM observations; its image cells without them) lies in the block's core.
    #[arg(long, default_value_t = 0.25)]
    pub visibility: f64,
    /// Write each block's loss masks (`loss_masks.json`): a block learns, in each view, only
    /// the image cells whose nearest SfM point lies in its region (and the cells around them),
    /// or, where no point projects, whose ray ends over its region; the rest of the view is
    /// another block's to explain (docs/partition.md).
    #[arg(long)]
    pub loss_masks: bool,
    /// The merged model's Gaussian budget (500k, 2.5M, or 3x the SfM points), shared among
    /// the blocks by the points of their regions: each block's run gets `--budget` its share.
    /// Pair it with a strategy that fills a budget (`-- --strategy mcmc`), or it is a cap.
    /// Required for a scene without SfM points (transforms): a count, shared by training views.
    #[arg(long, value_name = "N", value_parser = Budget::parse)]
    pub budget: Option<Budget>,
    /// Without --budget: the Gaussians expected per SfM point of a block's region, for the
    /// plan's estimates (a rough figure; a budget makes them exact).
    #[arg(long, default_value_t = 20.0)]
    pub growth: f64,
    /// The image cache the block runs will use (MiB; train's --image-cache), for the memory
    /// estimates.
    #[arg(long, value_name = "MIB", default_value_t = 2048.0)]
    pub image_cache: f64,
    /// A coarse model of the whole scene (a short `train` of it at the same -r, e.g. 600
    /// iterations) that every block starts from (`--init-ply` on a fresh start): each block
    /// then learns its region against the rest of the scene already in place instead of
    /// explaining the other blocks' content with floaters. On Truck 2x2 it takes the merged
    /// model from 3.3 dB behind the whole scene's to level with it. A block starts from the
    /// coarse Gaussians in its region and a share of the rest (--coarse-backdrop), written as
    /// `coarse.ply` in its folder and counted in the plan's estimates (docs/partition.md).
    #[arg(long, value_name = "PLY")]
    pub coarse: Option<PathBuf>,
    /// With --coarse: the share of the coarse model outside a block's region that the block
    /// keeps as its backdrop, the most opaque and largest Gaussians first (1: all of it).
    #[arg(long, value_name = "SHARE", default_value_t = 1.0, requires = "coarse")]
    pub coarse_backdrop: f64,
    /// Each block clones and splits only Gaussians in its region (its core and margin): every
    /// block run gets `--grow-within <its folder>/region.json`, so a block does not regrow the
    /// rest of the scene its views see (with --coarse, its backdrop stays as it came).
    #[arg(long)]
    pub grow_within_region: bool,
    #[command(flatten)]
    pub slurm: super::slurm_args::SlurmArgs,
    /// `train` arguments for every block, after `--` (e.g. `-- --iterations 30000 --lpm`).
    /// `-r` is passed on from the scene flags.
    #[arg(last = true, allow_hyphen_values = true)]
    pub train_args: Vec<String>,
}

fn parse_grid(s: &str) -> Result<(usize, usize), String> {
    let bad = || format!("'{s}' is not a grid. Fix: give COLUMNSxROWS, e.g. 2x2 or 4x1");
    let (c, r) = s.split_once(['x', 'X']).ok_or_else(bad)?;
    let (c, r): (usize, usize) = (
        c.trim().parse().map_err(|_| bad())?,
        r.trim().parse().map_err(|_| bad())?,
    );
    if c == 0 || r == 0 {
        return Err(bad());
    }
    Ok((c, r))
}

pub(super) fn parse_count(s: &str) -> Result<u64, String> {
    Budget::parse_count(s).map(|n| n as u64)
}

pub fn run(args: &PartitionArgs) -> anyhow::Result<()> {
    let plan_path = args.out.join("plan.json");
    anyhow::ensure!(
        !plan_path.exists(),
        "{}: the folder holds a plan already (and perhaps its runs). Fix: choose another -o, \
         or remove the folder to plan again",
        plan_path.display()
    );
    let targets = Targets {
        max_views: args.max_views,
        max_gaussians: args.max_gaussians,
        memory_mib: args.memory,
    };
    let grid = match args.blocks {
        Some((columns, rows)) => {
            anyhow::ensure!(
                targets == Targets::default(),
                "--blocks with --max-views / --max-gaussians / --memory: give a grid or targets, \
                 not both"
            );
            GridChoice::Fixed { columns, rows }
        }
        None => {
            anyhow::ensure!(
                targets != Targets::default(),
                "partition needs --blocks CxR, or a per-block target (--max-views, \
                 --max-gaussians or --memory) to choose the grid by"
            );
            GridChoice::Fit(targets)
        }
    };
    let opts = args.scene.load_options()?;
    let scene = Scene::load_in_file_frame(&args.scene.scene, &opts)?;
    scene.check_coordinates()?;
    let model = match &scene.format {
        SceneFormat::Colmap { sparse_dir, binary } => {
            Some(colmap::read_model(sparse_dir, *binary)?)
        }
        SceneFormat::NerfSynthetic | SceneFormat::Nerfstudio => None,
        SceneFormat::Video => anyhow::bail!(
            "{}: partition cuts still scenes (COLMAP or transforms.json); a multi-view video \
             is one capture point for every frame. Fix: train it whole",
            args.scene.scene.display()
        ),
    };
    let frame = scene.clone().into_training_frame().frame;
    let points = scene.points.as_ref().map_or(0, |p| p.len());
    let budget = args.budget.map(|b| b.resolve(points) as u64);
    anyhow::ensure!(
        !args
            .train_args
            .iter()
            .any(|a| a == "--init-ply" || a.starts_with("--init-ply=")),
        "partition -- --init-ply: a block's start from a model is the plan's to know (its \
         estimates count it, and a resumed block must not get it). Fix: pass it as \
         `partition --coarse PLY`"
    );
    let coarse = args
        .coarse
        .as_deref()
        .map(|path| partition::coarse::CoarseModel::read(path, args.coarse_backdrop))
        .transpose()?;
    let mut train_args = Vec::new();
    if let Some(r) = args.scene.resolution {
        train_args.extend(["-r".to_string(), r.to_string()]);
    }
    train_args.extend(args.train_args.iter().cloned());
    let popts = PartitionOptions {
        grid,
        margin: args.margin,
        visibility: args.visibility,
        budget,
        growth: args.growth,
        image_cache_mib: args.image_cache,
        coarse,
    };
    let mut plan = partition::make_plan(&scene, frame, &popts, train_args)?;
    plan.grow_within_region = args.grow_within_region;
    std::fs::create_dir_all(&args.out)?;
    let out = std::path::absolute(&args.out)?;
    match &model {
        Some(model) => blocks::write_block_folders(&out, &plan, model, &scene.root)?,
        None => blocks::write_transforms_block_folders(&out, &plan, &scene.root)?,
    }
    if let Some(c) = &popts.coarse {
        partition::blocks::write_block_starts(&out, &plan, c)?;
    }
    if plan.grow_within_region {
        blocks::write_growth_regions(&out, &plan)?;
    }
    if args.loss_masks {
        let shares = partition::masks::write_block_masks(&out, &plan, &scene)?;
        for (b, share) in plan.blocks.iter().zip(shares) {
            println!(
                "{}: loss masks learn {:.1} % of its training views' pixels",
                b.name,
                100.0 * share
            );
        }
    }
    if args.slurm.slurm {
        let sopts = args.slurm.options()?;
        slurm::write_scripts(&slurm::block_array(&plan, &out, &sopts), &sopts)?;
    }
    // The plan last: a folder with plan.json is a complete one.
    plan.write(&plan_path)?;
    print_plan(&plan);
    println!("wrote {}", plan_path.display());
    if args.slurm.slurm {
        println!(
            "submit: bash {}/slurm/submit.sh   (again after a failure: only what is missing)",
            out.display()
        );
    } else {
        // One line a block: with a budget each block trains to its own share of it.
        println!("train each block, then merge them:");
        for b in &plan.blocks {
            let budget = match plan.budget {
                Some(_) => format!(" --budget {}", b.expected_gaussians),
                None => String::new(),
            };
            let start = match &plan.coarse {
                Some(_) => format!(
                    " --init-ply {}",
                    out.join(partition::blocks::block_start_path(b)).display()
                ),
                None => String::new(),
            };
            let region = match plan.grow_within_region {
                true => format!(
                    " --grow-within {}",
                    out.join(blocks::region_path(b)).display()
                ),
                false => String::new(),
            };
            println!(
                "  lpmsplat train {} -o {} {}{budget}{start}{region}",
                out.join(&b.folder).display(),
                out.join("runs").join(&b.name).display(),
                plan.train_args.join(" "),
            );
        }
        println!(
            "  lpmsplat merge {} --runs {}/runs -o {}/merged",
            plan_path.display(),
            out.display(),
            out.display()
        );
    }
    Ok(())
}

fn print_plan(plan: &Plan) {
    println!(
        "{}x{} blocks (margin {}, visibility {}); the whole scene: {} training views, {} test \
         views, {} SfM points, ~{} Gaussians, ~{:.0} MiB",
        plan.columns,
        plan.rows,
        plan.margin,
        plan.visibility,
        plan.whole.train_views,
        plan.whole.test_views,
        plan.whole.points,
        plan.whole.expected_gaussians,
        plan.whole.memory_mib
    );
    if let Some(c) = &plan.coarse {
        println!(
            "every block starts from the coarse model {} ({} Gaussians): those in its region \
             and {:.0} % of the rest (its coarse.ply, counted in its estimate)",
            c.ply.display(),
            c.gaussians,
            100.0 * c.backdrop
        );
    }
    println!(
        "{:<8} {:>6} {:>5} {:>9} {:>9} {:>9} {:>11} {:>9}",
        "block", "train", "test", "core pts", "region", "start", "Gaussians", "MiB"
    );
    for b in &plan.blocks {
        println!(
            "{:<8} {:>6} {:>5} {:>9} {:>9} {:>9} {:>11} {:>9.0}",
            b.name,
            b.train_views.len(),
            b.test_views.len(),
            b.core_points,
            b.region_points,
            b.start_gaussians.map_or("-".into(), |s| s.to_string()),
            b.expected_gaussians,
            b.memory_mib
        );
    }
}
