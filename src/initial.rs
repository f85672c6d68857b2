//! The initial model of a run: a PLY, the scene's SfM points, points triangulated from its views,
//! or random points in the cameras' bounds, then the base model's own groups. `train` and
//! `bench trade` both start their runs here.

use std::path::Path;

use crate::models::BaseModel;
use crate::scene::Scene;
use crate::splats::{self, read_ply, GaussianParams};

/// Where a scene without SfM points gets its initial points (`--init`).
#[derive(Debug, Clone, Copy, PartialEq, Eq, clap::ValueEnum)]
pub enum InitSource {
    /// Triangulate video scenes, random points for still ones.
    Auto,
    /// Random points in the cameras' bounds, even where the scene has SfM points.
    Random,
    Triangulate,
}

impl InitSource {
    /// Whether `scene`'s initial points are triangulated (when it has no SfM points).
    pub fn triangulates(self, scene: &Scene) -> bool {
        match self {
            InitSource::Triangulate => true,
            InitSource::Random => false,
            InitSource::Auto => scene.view_times.is_some(),
        }
    }
}

/// Fewer triangulated points than this fall back to random points (with a message).
const MIN_TRIANGULATED: usize = 100;

/// Initial Gaussians of `model`: a PLY, the SfM points, points triangulated from the views
/// (`--init`), or random points in the cameras' bounds; then the model's own groups. A video
/// model's triangulated points are centred in time at their frame's time.
pub fn initial_model(
    model: BaseModel,
    scene: &Scene,
    init_ply: Option<&Path>,
    source: InitSource,
    init_points: usize,
    seed: u64,
    sh_degree: u32,
) -> anyhow::Result<GaussianParams> {
    let ignored = |by: &str| {
        // Only when asked for by name: `auto` falls back silently.
        if source == InitSource::Triangulate {
            eprintln!("--init triangulate: not used, the initial points come from {by}");
        }
    };
    if let Some(p) = init_ply {
        ignored(&format!("--init-ply {}", p.display()));
        // Another trainer's model, or one of ours, in the user's frame (less its shift).
        let mut init = read_ply(p)?;
        let shift = crate::scene::frame::shift_from_comments(p, &splats::ply_comments(p)?)?;
        init.map_frame(scene.frame.stored_to_train(shift), &[], false);
        return Ok(model.initialise(init, seed));
    }
    let sfm = scene.points.as_ref().filter(|p| !p.is_empty());
    if let (Some(points), InitSource::Random) = (sfm, source) {
        // Asked for by name: random points even where SfM points exist (MCMC's claim is that
        // it does not need them; this is how to test it).
        eprintln!(
            "--init random: the scene's {} SfM points are not used; {init_points} random points \
             instead",
            points.len()
        );
    } else if let Some(points) = sfm {
        ignored("the scene's SfM points");
        return Ok(model.initialise(splats::init::from_sfm(points, sh_degree)?, seed));
    }
    if source.triangulates(scene) {
        let t0 = std::time::Instant::now();
        let tri = crate::triangulated_init::triangulate_scene(scene, init_points, seed)?;
        eprintln!(
            "initial points: {} triangulated from {} matches in {} view pairs ({:.1} s)",
            tri.positions.len(),
            tri.matches,
            tri.pairs,
            t0.elapsed().as_secs_f64()
        );
        if tri.positions.len() >= MIN_TRIANGULATED {
            let params = crate::triangulated_init::topped_up_model(
                &tri,
                scene,
                init_points,
                seed,
                sh_degree,
            )?;
            let params = model.initialise_at_times(params, seed, &tri.times);
            return Ok(params);
        }
        eprintln!(
            "initial points: fewer than {MIN_TRIANGULATED} triangulated; {init_points} random \
             points instead"
        );
    }
    let (center, half) = scene.random_init_box();
    let params = splats::init::random_init(init_points, center, [half; 3], seed, sh_degree)?;
    Ok(model.initialise(params, seed))
}
