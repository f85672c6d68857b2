//! Base models: what a model changes in a training run, applied to the trainer's config.
//!
//! Today's models share the 3DGS parameter groups and PLY layout; they differ in the
//! densification statistic (Pixel-GS, docs/algorithms/base-models.md §3), in the renderer's filters
//! (Mip-Splatting, §2: a non-optimised per-Gaussian 3D filter the trainer recomputes, and the
//! 2D Mip filter), or in the primitive (2DGS, §1: surfels, with their own passes and
//! regularisers, [`crate::train::passes::surfels`]), or in time (SpacetimeGaussians lite, §4:
//! four extra parameter groups and the temporal step before the 3DGS passes,
//! [`crate::train::passes::spacetime`]).

mod gaussians3d;
mod mip_splatting;
pub mod model;
pub mod options;
pub mod output;
mod pixel_gs;
mod spacetime;
mod surfels2d;
mod trainer;

pub use model::Model;
pub use options::ModelOptions;

use crate::splats::GaussianParams;
use crate::train::density::Statistic;
use crate::train::passes::surfels::UNUSED_LOG_SCALE;
use crate::train::trainer::TrainConfig;

/// The config of a model of still 3D Gaussians (3DGS, Pixel-GS, Mip-Splatting): `statistic`
/// densifies it and `section` is its section.
fn still_gaussians(
    config: &mut TrainConfig,
    statistic: Statistic,
    section: impl crate::train::model_section::ModelSection,
) {
    config.density.statistic = statistic;
    config.set_model(section);
}

/// A still initial model as SpacetimeGaussians' initial one: every Gaussian gets the temporal
/// groups (no motion, no angular velocity, temporal log-scale 0) with its temporal centre drawn
/// uniformly in the segment's [0, 1) (seeded): with no per-frame points (the official
/// initialisation tags each SfM point with its frame's time), a uniform centre gives every
/// frame Gaussians near its time.
///
/// `full`: also the full model's feature groups, with the colour as its features (the
/// official initialisation: `f_dc` = the point colour twice, `f_t` = 0): the DC coefficients
/// become the raw base colour `0.5 + C₀·dc` (what the 3DGS colour was at degree 0, unclamped)
/// and the specular feature `f_spec` the same values.
pub fn with_temporal_groups(mut params: GaussianParams, seed: u64, full: bool) -> GaussianParams {
    use crate::splats::ExtraValues;
    use rand::{Rng, SeedableRng};
    let mut rng = rand_pcg::Pcg64::seed_from_u64(seed ^ 0x57D5);
    let n = params.len();
    if full {
        for dc in params.sh_dc.iter_mut() {
            *dc = dc.map(|v| (0.5 + crate::splats::SH_C0 * v as f64) as f32);
        }
    }
    params.extra = crate::train::passes::spacetime::extra_groups_of(full)
        .into_iter()
        .map(|group| {
            let values = match group.name.as_str() {
                "trbf_center" => (0..n).map(|_| rng.gen_range(0.0..1.0f32)).collect(),
                "f_spec" => params.sh_dc.iter().flatten().copied().collect(),
                _ => vec![0.0; n * group.stride],
            };
            ExtraValues { group, values }
        })
        .collect();
    params
}

#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Hash)]
pub enum BaseModel {
    /// 3D Gaussian Splatting (Kerbl et al. 2023), the Inria defaults.
    #[default]
    Gaussians3d,
    /// Pixel-GS (Zhang et al., ECCV 2024): the densification statistic weighted by the pixels
    /// each Gaussian covers per view, with the depth factor on the statistic only; everything
    /// else as 3DGS (the official code's defaults).
    PixelGs,
    /// Mip-Splatting (Yu et al., CVPR 2024): the 3D smoothing filter and the 2D Mip filter,
    /// with the paper's densification (3DGS's gradient test).
    MipSplatting,
    /// 2D Gaussian Splatting (Huang et al., SIGGRAPH 2024): surfels with the normal-consistency
    /// and depth-distortion regularisers, the official densification statistic and its 0.05
    /// opacity prune.
    Surfels2d,
    /// SpacetimeGaussians, lite (Li et al., CVPR 2024): 3D Gaussians with cubic motion, linear
    /// rotation and a temporal opacity, trained on multi-view video; colour without view
    /// dependence (SH degree 0).
    SpacetimeLite,
    /// SpacetimeGaussians, full: the lite model's Gaussians with 9 feature channels (raw base
    /// colour, specular feature, time feature) blended and turned into RGB per pixel by a small
    /// MLP that also sees the viewing ray (view-dependent colour without SH).
    SpacetimeFull,
}

impl BaseModel {
    pub const ALL: [BaseModel; 6] = [
        BaseModel::Gaussians3d,
        BaseModel::PixelGs,
        BaseModel::MipSplatting,
        BaseModel::Surfels2d,
        BaseModel::SpacetimeLite,
        BaseModel::SpacetimeFull,
    ];

    pub fn parse(s: &str) -> anyhow::Result<BaseModel> {
        Self::ALL
            .into_iter()
            .find(|m| m.name() == s)
            .ok_or_else(|| {
                anyhow::anyhow!(
                    "--model {s:?} is unknown. Fix: choose one of {}",
                    Self::ALL.map(|m| m.name()).join(", ")
                )
            })
    }

    /// The header comment that records which model a PLY holds (`comment lpmsplat model
    /// NAME`): `train` writes it, and `eval`, `render`, `mesh` and `bench fps` read the file
    /// as that model unless `--model` says otherwise.
    pub const PLY_COMMENT: &'static str = "lpmsplat model";

    /// This model's header comment ([`BaseModel::PLY_COMMENT`]).
    pub fn ply_comment(&self) -> String {
        format!("{} {}", Self::PLY_COMMENT, self.name())
    }

    /// The model a PLY's header records, if any; an unknown name is an error naming the file.
    pub fn recorded_in(path: &std::path::Path) -> anyhow::Result<Option<BaseModel>> {
        let comments = crate::splats::ply::ply_comments(path)?;
        let prefix = format!("{} ", Self::PLY_COMMENT);
        let Some(name) = comments.iter().find_map(|c| c.strip_prefix(&prefix)) else {
            return Ok(None);
        };
        let name = name.trim();
        match Self::ALL.into_iter().find(|m| m.name() == name) {
            Some(m) => Ok(Some(m)),
            None => crate::error::bad_input(
                path,
                format!("header comment '{} {name}'", Self::PLY_COMMENT),
                format!(
                    "names no model this build knows (it knows {})",
                    Self::ALL.map(|m| m.name()).join(", ")
                ),
                "read it with the lpmsplat version that wrote it, or pass --model",
            ),
        }
    }

    /// The model to read `path` as: the one its header records, `flag` (`--model`) when the
    /// header records none (another trainer's PLY; 3DGS when neither says, as viewers read
    /// such files). A `flag` that contradicts the header is an error naming both. A file that
    /// cannot be read gives `flag` or 3DGS, and its reader reports the problem.
    pub fn for_ply(flag: Option<BaseModel>, path: &std::path::Path) -> anyhow::Result<BaseModel> {
        let recorded = match Self::recorded_in(path) {
            Ok(r) => r,
            Err(e)
                if e.downcast_ref::<crate::error::InputError>()
                    .is_some_and(|i| i.field.starts_with("header comment")) =>
            {
                return Err(e)
            }
            Err(_) => None,
        };
        match (flag, recorded) {
            (Some(f), Some(r)) if f != r => crate::error::bad_input(
                path,
                format!("header comment '{}'", r.ply_comment()),
                format!(
                    "the file holds a {} model, but --model {} was given: read as {} it would \
                     be drawn as another model",
                    r.name(),
                    f.name(),
                    f.name()
                ),
                format!(
                    "drop --model (the file says which model it is), or pass --model {}",
                    r.name()
                ),
            ),
            (Some(f), _) => Ok(f),
            (None, Some(r)) => Ok(r),
            (None, None) => Ok(BaseModel::Gaussians3d),
        }
    }

    /// The registry: each model's [`Model`], the one place a model is listed by value.
    pub fn model(&self) -> &'static dyn Model {
        match self {
            BaseModel::Gaussians3d => &gaussians3d::Gaussians3d,
            BaseModel::PixelGs => &pixel_gs::PixelGs,
            BaseModel::MipSplatting => &mip_splatting::MipSplatting,
            BaseModel::Surfels2d => &surfels2d::Surfels2d,
            BaseModel::SpacetimeLite => &spacetime::Spacetime { full: false },
            BaseModel::SpacetimeFull => &spacetime::Spacetime { full: true },
        }
    }

    /// The CLI name.
    pub fn name(&self) -> &'static str {
        self.model().name()
    }

    /// SpacetimeGaussians (lite or full): a video model.
    pub fn is_spacetime(&self) -> bool {
        self.model().is_spacetime()
    }

    /// The iteration densification stops at in the model's official code: 9000 for
    /// SpacetimeGaussians (its `densify_until_iter`), 15,000 (the Inria default) for the others.
    pub fn default_densify_until(&self) -> u32 {
        self.model().default_densify_until()
    }

    /// The prune threshold on opacity when the user gives none (2DGS's `opacity_cull` 0.05,
    /// else the Inria 0.005).
    pub fn default_min_opacity(&self) -> f64 {
        self.model().default_min_opacity()
    }

    /// Turns a 3DGS-style initial model into this model's: for 2DGS, random rotations and the
    /// unused third log-scale; for the video models, the temporal groups.
    pub fn initialise(&self, params: GaussianParams, seed: u64) -> GaussianParams {
        self.model().initialise(params, seed)
    }

    /// [`BaseModel::initialise`] for points of which the first `times.len()` were observed at
    /// known times (triangulated from a video's frames): a video model centres those in time
    /// there (the others keep their random centre); other models ignore the times.
    pub fn initialise_at_times(
        &self,
        params: GaussianParams,
        seed: u64,
        times: &[f64],
    ) -> GaussianParams {
        let mut params = self.initialise(params, seed);
        if let Some(centres) = params
            .extra
            .iter_mut()
            .find(|e| e.group.name == "trbf_center")
        {
            for (c, &t) in centres.values.iter_mut().zip(times) {
                *c = t as f32;
            }
        }
        params
    }

    /// A renderer for this model's trained PLYs (eval, render, orbit).
    ///
    /// `times`: the time of every camera the renders index (video scenes); a video model needs
    /// them, other models ignore them.
    pub fn view_renderer(
        &self,
        ctx: &std::sync::Arc<crate::gpu::GpuContext>,
        gaussians: usize,
        camera: &crate::render::layout::CameraGpu,
        times: Option<Vec<f32>>,
        ply: Option<&std::path::Path>,
    ) -> anyhow::Result<Box<dyn crate::render::view::ViewRenderer>> {
        self.model()
            .view_renderer(ctx, gaussians, camera, times, ply, self.render_constants())
    }

    /// Maps a model of this base model through a change of frame `x ↦ k·x + b`
    /// ([`GaussianParams::map_frame`]): which of its parameters are lengths is the model's to
    /// say (a surfel's third log-scale is a fixed marker, SpacetimeGaussians' motion
    /// coefficients are lengths per unit time).
    pub fn map_frame(&self, params: &mut GaussianParams, map: (f64, [f64; 3])) {
        let m = self.model();
        params.map_frame(map, m.length_groups(), m.fixed_third_scale());
    }

    /// Reads a model of this base model that another file holds in the user's frame (less the
    /// shift its header records, [`crate::scene::frame`]) into `scene`'s training frame.
    pub fn read_ply_for_scene(
        &self,
        path: &std::path::Path,
        scene: &crate::scene::Scene,
    ) -> anyhow::Result<GaussianParams> {
        let mut params = self.read_ply(path)?;
        let shift = crate::scene::frame::shift_from_comments(
            path,
            &crate::splats::ply::ply_comments(path)?,
        )?;
        self.map_frame(&mut params, scene.frame.stored_to_train(shift));
        Ok(params)
    }

    /// Reads a trained PLY of this model (a video model's with its temporal groups; a 2DGS one
    /// also in the official 2DGS layout, with two scales). A file another base model wrote is
    /// refused where this one would draw it wrongly ([`BaseModel::check_ply_properties`],
    /// [`BaseModel::check_ply_shape`]), and a 2DGS file read as 3D Gaussians gets a warning.
    pub fn read_ply(&self, path: &std::path::Path) -> anyhow::Result<GaussianParams> {
        let names = crate::splats::ply::vertex_property_names(path)?;
        self.check_ply_properties(path, &names)?;
        let params = self.model().read_ply(path)?;
        if let Some(w) = self.check_ply_shape(path, &params)? {
            eprintln!("warning: {}: {w}", path.display());
        }
        Ok(params)
    }

    /// Reads any still model's PLY as the 3D Gaussians it draws as, for formats that hold
    /// nothing else (`.splat`): a 2DGS file in the official two-scale layout as flat discs
    /// (as our 2DGS files are), a SpacetimeGaussians one refused (it would be drawn at no
    /// time at all).
    pub fn read_still_ply(path: &std::path::Path) -> anyhow::Result<GaussianParams> {
        let names = crate::splats::ply::vertex_property_names(path)?;
        let has = |n: &str| names.iter().any(|p| p == n);
        if has("trbf_center") {
            return Err(crate::error::InputError::new(
                path,
                "property trbf_center",
                "the file holds a SpacetimeGaussians model (its temporal groups): a still format \
                 would show it at no time at all",
                "render it at a time instead (`render SCENE --model spacetime-lite --time T`, \
                 or spacetime-full with its decoder file)",
            )
            .into());
        }
        if !has("scale_2") && has("scale_1") {
            return BaseModel::Surfels2d.read_ply(path);
        }
        crate::splats::read_ply(path)
    }

    /// Refuses a PLY whose properties say another base model wrote it, where reading it as
    /// this one would silently draw something else: a SpacetimeGaussians model (its temporal
    /// groups) read as a still one would be drawn at no time, a full one read as lite would
    /// show its raw features as colours, a lite one has no features for the full model.
    pub fn check_ply_properties(
        &self,
        path: &std::path::Path,
        names: &[String],
    ) -> anyhow::Result<()> {
        let has = |n: &str| names.iter().any(|p| p == n);
        let (temporal, features) = (has("trbf_center"), has("f_spec_0"));
        let wrote = match (temporal, features) {
            (true, true) => BaseModel::SpacetimeFull,
            (true, false) => BaseModel::SpacetimeLite,
            _ => return Ok(()),
        };
        let (field, problem) = match (self.is_spacetime(), *self == wrote) {
            (_, true) => return Ok(()),
            (false, _) => (
                "property trbf_center",
                format!(
                    "the file holds a SpacetimeGaussians model (its temporal groups); as --model \
                     {} every Gaussian would be drawn at no time at all",
                    self.name()
                ),
            ),
            (true, _) if features => (
                "property f_spec_0",
                "the file holds the full SpacetimeGaussians model (9 feature channels for its \
                 decoder); as spacetime-lite its features would be drawn as colours"
                    .to_string(),
            ),
            (true, _) => (
                "property f_spec_0",
                "the file holds the lite SpacetimeGaussians model: it has no feature channels \
                 for the full model's decoder"
                    .to_string(),
            ),
        };
        Err(crate::error::InputError::new(
            path,
            field,
            problem,
            format!(
                "pass --model {} (the model it was trained as), with the video scene it was \
                 trained on",
                wrote.name()
            ),
        )
        .into())
    }

    /// What a model's shape says about the model that wrote it: under 2dgs, 3D Gaussians (a
    /// third scale not far below the other two; a surfel keeps e^−20 there, and the official
    /// 2DGS layout has none) are refused, since the surfel renderer would flatten them; under
    /// the 3D Gaussian models a file of surfels only is drawn as the flat discs it stands for
    /// (as 3DGS viewers show it) with a warning, returned, that names the flag that draws it
    /// as surfels.
    pub fn check_ply_shape(
        &self,
        path: &std::path::Path,
        params: &GaussianParams,
    ) -> anyhow::Result<Option<String>> {
        // A third scale under a thousandth of the larger of the other two is flat, and so is
        // the surfel's own (it only shrinks from UNUSED_LOG_SCALE, while a surfel whose other
        // two scales shrank past e^−13 would fail the ratio).
        let flat = |l: &[f32; 3]| l[2] <= UNUSED_LOG_SCALE || l[2] <= l[0].max(l[1]) - 1000f32.ln();
        if self.model().fixed_third_scale() {
            if let Some(i) = params.log_scales.iter().position(|l| !flat(l)) {
                let l = params.log_scales[i];
                return Err(crate::error::InputError::new(
                    path,
                    format!("vertex {i}, property scale_2"),
                    format!(
                        "the third log-scale {} is not far below the other two ({}, {}): the \
                         file holds 3D Gaussians, which --model 2dgs would draw flattened (a \
                         2DGS PLY keeps {UNUSED_LOG_SCALE} there, or has no scale_2)",
                        l[2], l[0], l[1]
                    ),
                    "pass --model 3dgs (or the model it was trained as)",
                )
                .into());
            }
            return Ok(None);
        }
        let still = !self.is_spacetime();
        if still && !params.log_scales.is_empty() && params.log_scales.iter().all(flat) {
            return Ok(Some(format!(
                "every Gaussian is flat (its third scale under a thousandth of the others): \
                 this looks like a 2DGS model, drawn here as flat 3D Gaussians as 3DGS viewers \
                 show it. Pass --model 2dgs to draw it as surfels, as it was trained (not \
                 --model {})",
                self.name()
            )));
        }
        Ok(None)
    }

    /// The rasterizer constants its renders use (eval, render, viewers of an exported PLY):
    /// those its training used ([`TrainConfig::render_constants`]).
    pub fn render_constants(&self) -> crate::render::layout::RenderConstants {
        let mut config = TrainConfig::default();
        self.configure(&mut config);
        config.render_constants()
    }

    /// Sets what this model changes in `config` (leaves the rest, the 3DGS defaults or the
    /// user's flags, alone).
    pub fn configure(&self, config: &mut TrainConfig) {
        self.model().configure(config)
    }

    /// The model a config trains (the inverse of [`BaseModel::configure`]): the one its
    /// section names ([`crate::train::model_section::ModelSection::model_name`]).
    pub fn of(config: &TrainConfig) -> BaseModel {
        let name = config.model.model_name();
        Self::ALL
            .into_iter()
            .find(|m| m.name() == name)
            .unwrap_or_else(|| {
                panic!("a config's model section names {name:?}, no model of the registry")
            })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn known_times_centre_the_first_points_of_a_video_model() {
        let params = crate::splats::init::random_init(5, [0.0; 3], [1.0; 3], 3, 0).unwrap();
        let times = [0.25, 0.5];
        let video = BaseModel::SpacetimeLite.initialise_at_times(params.clone(), 7, &times);
        let random = BaseModel::SpacetimeLite.initialise(params.clone(), 7);
        let centres = video.extra_values("trbf_center").unwrap();
        assert_eq!(&centres[..2], &[0.25, 0.5]);
        // The others keep the random centres of the same seed.
        assert_eq!(
            &centres[2..],
            &random.extra_values("trbf_center").unwrap()[2..]
        );
        // A still model has no temporal centre: the times change nothing.
        let still = BaseModel::Gaussians3d.initialise_at_times(params.clone(), 7, &times);
        assert_eq!(still.positions, params.positions);
        assert!(still.extra.is_empty());
    }

    #[test]
    fn names_round_trip_and_configure_is_inverted_by_of() {
        assert_eq!(
            BaseModel::of(&TrainConfig::default()),
            BaseModel::Gaussians3d
        );
        for m in BaseModel::ALL {
            assert_eq!(BaseModel::parse(m.name()).unwrap(), m);
            let mut c = TrainConfig::default();
            m.configure(&mut c);
            assert_eq!(BaseModel::of(&c), m);
            // The config trains the model that configured it last, whichever did before, and
            // its section's JSON names it.
            for before in BaseModel::ALL {
                let mut c = TrainConfig::default();
                before.configure(&mut c);
                m.configure(&mut c);
                assert_eq!(BaseModel::of(&c), m, "{} after {}", m.name(), before.name());
                assert_eq!(c.to_json()["model"], m.name());
            }
        }
        let e = BaseModel::parse("mip").unwrap_err().to_string();
        assert!(
            e.contains("3dgs, pixel-gs, mip-splatting, 2dgs") && e.contains("Fix"),
            "{e}"
        );
    }
}
