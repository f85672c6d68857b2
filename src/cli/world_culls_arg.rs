//! `--n3dv-culls`: SpacetimeGaussians' Neural 3D Video culls by world position
//! ([`lpmsplat::train::config::WorldCulls`]), shared by `train` and `bench trade`.

use std::path::Path;

use lpmsplat::models::BaseModel;
use lpmsplat::train::config::{TrainConfig, WorldCulls};
use lpmsplat::train::passes::world_culls::for_scene;

#[derive(Debug, Clone, Copy, PartialEq, Eq, clap::ValueEnum)]
pub enum N3dvCulls {
    /// The official rule of the scene: on for the six Neural 3D Video scenes (by folder name,
    /// beside poses_bounds.npy), with the later culls where their config uses them; off
    /// elsewhere.
    Auto,
    /// The cull before training and the later ones (the official `densify: 1`).
    Official,
    /// Only the cull before training (the official `densify: 2`: coffee_martini,
    /// flame_salmon_1).
    Initial,
    Off,
}

/// Sets `config`'s culls for the scene at `root` (after the model and the schedule are set):
/// `per_thousand` iterations stand for the official 1000 (1000 at full length).
pub fn apply(
    choice: N3dvCulls,
    root: &Path,
    model: BaseModel,
    config: &mut TrainConfig,
    per_thousand: u32,
) -> anyhow::Result<()> {
    let until = config.schedule.densify_until;
    let Some(st) = config.spacetime.as_mut() else {
        anyhow::ensure!(
            matches!(choice, N3dvCulls::Auto | N3dvCulls::Off),
            "--n3dv-culls applies to the spacetime models only (this run trains {}). Fix: drop \
             the flag",
            model.name()
        );
        return Ok(());
    };
    let later = match choice {
        N3dvCulls::Auto => for_scene(root),
        N3dvCulls::Official => Some(true),
        N3dvCulls::Initial => Some(false),
        N3dvCulls::Off => None,
    };
    st.world_culls = later.map(|l| WorldCulls::n3dv(l, until, per_thousand));
    Ok(())
}
