//! The settings that belong to one base model or another (2DGS's regularisers, the spacetime
//! models' rules, the absolute-gradient test of the gradient-densified models), as the user
//! gave them. Each model says which it takes and applies them in its own file
//! ([`super::Model::settings`], [`super::Model::apply_settings`]); [`BaseModel::apply_options`]
//! refuses the others by the flag's name and the models that take it. Not in the command
//! line's parser.

use super::BaseModel;
use crate::train::passes::spacetime_settings::ChildTime;
use crate::train::trainer::TrainConfig;

/// Model settings as given: `None` (or `false`) where not given, and the model's default
/// applies.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct ModelOptions {
    /// 2dgs: `--lambda-normal`, `--normal-from`, `--lambda-dist`, `--dist-from`,
    /// `--depth-ratio`.
    pub lambda_normal: Option<f32>,
    pub normal_from: Option<u32>,
    pub lambda_dist: Option<f32>,
    pub dist_from: Option<u32>,
    pub depth_ratio: Option<f32>,
    /// Spacetime models: `--child-time`.
    pub child_time: Option<ChildTime>,
    /// Spacetime models: `--guided-sampling on|off` (`Some(false)` off).
    pub guided_sampling: Option<bool>,
    /// Spacetime models: `--guided-from`.
    pub guided_from: Option<u32>,
    /// Spacetime models: `--omega-freeze ITERATION|off` (`Some(None)` off).
    pub omega_freeze: Option<Option<u32>>,
    /// Models densified by the mean gradient: `--densify-abs-grad`.
    pub densify_abs_grad: bool,
}

/// A model's own setting, as a group of flags: what a model declares it takes
/// ([`super::Model::settings`]) and the flags [`ModelOptions::given`] names.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum ModelSetting {
    /// 2DGS's regularisers and depth ratio.
    SurfelRegularisers,
    /// The spacetime models' time of split and cloned children.
    ChildTime,
    /// The spacetime models' guided error sampling.
    GuidedSampling,
    /// The spacetime models' angular-velocity freeze.
    OmegaFreeze,
    /// The absolute-gradient test, for models densified by the mean gradient.
    AbsGrad,
}

impl ModelOptions {
    /// `--omega-freeze`'s value: an iteration or `off`.
    pub fn parse_omega_freeze(v: &str) -> anyhow::Result<Option<u32>> {
        match v {
            "off" => Ok(None),
            n => n.parse().map(Some).map_err(|_| {
                anyhow::anyhow!(
                    "--omega-freeze {n:?} is not an iteration. Fix: give one (official 8001) or off"
                )
            }),
        }
    }

    /// The flags given, each with the setting it belongs to.
    pub fn given(&self) -> Vec<(&'static str, ModelSetting)> {
        use ModelSetting::*;
        [
            (
                "--lambda-normal",
                self.lambda_normal.is_some(),
                SurfelRegularisers,
            ),
            (
                "--normal-from",
                self.normal_from.is_some(),
                SurfelRegularisers,
            ),
            (
                "--lambda-dist",
                self.lambda_dist.is_some(),
                SurfelRegularisers,
            ),
            ("--dist-from", self.dist_from.is_some(), SurfelRegularisers),
            (
                "--depth-ratio",
                self.depth_ratio.is_some(),
                SurfelRegularisers,
            ),
            ("--child-time", self.child_time.is_some(), ChildTime),
            (
                "--guided-sampling",
                self.guided_sampling.is_some(),
                GuidedSampling,
            ),
            ("--guided-from", self.guided_from.is_some(), GuidedSampling),
            ("--omega-freeze", self.omega_freeze.is_some(), OmegaFreeze),
            ("--densify-abs-grad", self.densify_abs_grad, AbsGrad),
        ]
        .into_iter()
        .filter(|&(_, given, _)| given)
        .map(|(flag, _, setting)| (flag, setting))
        .collect()
    }
}

impl BaseModel {
    /// Whether the absolute-gradient test (`--densify-abs-grad`) combines with this model's
    /// densification statistic: the models densified by the mean gradient of 3D Gaussians.
    pub fn takes_abs_grad(&self) -> bool {
        self.model().settings().contains(&ModelSetting::AbsGrad)
    }

    /// Sets what this model changes in `config` ([`BaseModel::configure`]) with the model
    /// settings the user gave ([`super::Model::apply_settings`]); a setting the model does not
    /// take ([`super::Model::settings`]) is refused, naming its flag and the models that take
    /// it.
    pub fn apply_options(&self, o: &ModelOptions, config: &mut TrainConfig) -> anyhow::Result<()> {
        for (flag, setting) in o.given() {
            if !self.model().settings().contains(&setting) {
                let takers: Vec<&str> = Self::ALL
                    .iter()
                    .filter(|m| m.model().settings().contains(&setting))
                    .map(|m| m.name())
                    .collect();
                let takers = match takers.split_last() {
                    Some((last, [])) => last.to_string(),
                    Some((last, rest)) => format!("{} or {last}", rest.join(", ")),
                    None => "none".into(),
                };
                anyhow::bail!(
                    "{flag} applies to --model {takers} only (this run trains {}). Fix: drop the \
                     flag",
                    self.name()
                );
            }
        }
        self.configure(config);
        self.model().apply_settings(o, config)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn each_model_takes_its_own_settings_and_refuses_the_others_by_flag() {
        let all = BaseModel::ALL;
        let cases: [(ModelOptions, &str, &[BaseModel]); 5] = [
            (
                ModelOptions {
                    lambda_dist: Some(1000.0),
                    ..Default::default()
                },
                "--lambda-dist",
                &[BaseModel::Surfels2d],
            ),
            (
                ModelOptions {
                    child_time: Some(ChildTime::Parent),
                    ..Default::default()
                },
                "--child-time",
                &[BaseModel::SpacetimeLite, BaseModel::SpacetimeFull],
            ),
            (
                ModelOptions {
                    guided_from: Some(100),
                    ..Default::default()
                },
                "--guided-from",
                &[BaseModel::SpacetimeLite, BaseModel::SpacetimeFull],
            ),
            (
                ModelOptions {
                    omega_freeze: Some(None),
                    ..Default::default()
                },
                "--omega-freeze",
                &[BaseModel::SpacetimeLite, BaseModel::SpacetimeFull],
            ),
            (
                ModelOptions {
                    densify_abs_grad: true,
                    ..Default::default()
                },
                "--densify-abs-grad",
                &[
                    BaseModel::Gaussians3d,
                    BaseModel::MipSplatting,
                    BaseModel::SpacetimeLite,
                    BaseModel::SpacetimeFull,
                ],
            ),
        ];
        for (options, flag, takers) in &cases {
            for model in all {
                let mut c = TrainConfig::default();
                let r = model.apply_options(options, &mut c);
                if takers.contains(&model) {
                    r.unwrap_or_else(|e| panic!("{} refused {flag}: {e}", model.name()));
                    // The model is the one configured, whatever its settings.
                    assert_eq!(BaseModel::of(&c), model);
                } else {
                    let e = r.err().unwrap().to_string();
                    assert!(e.starts_with(flag) && e.contains(model.name()), "{e}");
                }
            }
        }
        // What was given lands where the model reads it.
        let mut c = TrainConfig::default();
        BaseModel::Surfels2d
            .apply_options(&cases[0].0, &mut c)
            .unwrap();
        assert_eq!(
            c.model_settings::<crate::train::passes::surfels::SurfelTraining>()
                .unwrap()
                .distortion_weight,
            1000.0
        );
        let mut c = TrainConfig::default();
        BaseModel::SpacetimeLite
            .apply_options(&cases[3].0, &mut c)
            .unwrap();
        assert_eq!(
            c.model_settings::<crate::train::passes::spacetime::SpacetimeTraining>()
                .unwrap()
                .omega_freeze,
            None
        );
        assert!(TrainConfig::default()
            .model_settings::<crate::train::passes::spacetime::SpacetimeTraining>()
            .is_none());
    }

    #[test]
    fn guided_from_with_sampling_off_is_refused() {
        let o = ModelOptions {
            guided_sampling: Some(false),
            guided_from: Some(10),
            ..Default::default()
        };
        let e = BaseModel::SpacetimeLite
            .apply_options(&o, &mut TrainConfig::default())
            .err()
            .unwrap()
            .to_string();
        assert!(e.contains("nothing would sample"), "{e}");
    }
}
