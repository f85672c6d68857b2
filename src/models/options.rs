//! The settings that belong to one base model or another (2DGS's regularisers, the spacetime
//! models' rules, the absolute-gradient test of the gradient-densified models), as the user
//! gave them. Each model takes the ones it knows ([`BaseModel::apply_options`]) and refuses
//! the others by the flag's name, so which model accepts what is written here, beside the
//! models, and not in the command line's parser.

use super::BaseModel;
use crate::train::config::{ChildTime, OmegaFreeze};
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
}

impl BaseModel {
    /// Whether the absolute-gradient test (`--densify-abs-grad`) combines with this model's
    /// densification statistic: the models densified by the mean gradient of 3D Gaussians.
    pub fn takes_abs_grad(&self) -> bool {
        self.model().takes_abs_grad()
    }

    /// Sets what this model changes in `config` ([`BaseModel::configure`]) with the model
    /// settings the user gave; a setting of another model is refused, naming its flag.
    pub fn apply_options(&self, o: &ModelOptions, config: &mut TrainConfig) -> anyhow::Result<()> {
        let name = self.name();
        if *self == BaseModel::Surfels2d {
            let mut t = config.surfels.unwrap_or_default();
            t.normal_weight = o.lambda_normal.unwrap_or(t.normal_weight);
            t.normal_from = o.normal_from.unwrap_or(t.normal_from);
            t.distortion_weight = o.lambda_dist.unwrap_or(t.distortion_weight);
            t.distortion_from = o.dist_from.unwrap_or(t.distortion_from);
            t.depth_ratio = o.depth_ratio.unwrap_or(t.depth_ratio);
            config.surfels = Some(t);
        } else {
            for (flag, given) in [
                ("--lambda-normal", o.lambda_normal.is_some()),
                ("--normal-from", o.normal_from.is_some()),
                ("--lambda-dist", o.lambda_dist.is_some()),
                ("--dist-from", o.dist_from.is_some()),
                ("--depth-ratio", o.depth_ratio.is_some()),
            ] {
                anyhow::ensure!(
                    !given,
                    "{flag} applies to --model 2dgs only (this run trains {name}). Fix: drop the \
                     flag or pass --model 2dgs"
                );
            }
        }
        self.configure(config);
        match (config.spacetime.as_mut(), o.child_time) {
            (Some(st), Some(ct)) => st.child_time = ct,
            (None, Some(_)) => anyhow::bail!(
                "--child-time applies to --model spacetime-lite or spacetime-full only (this run \
                 trains {name}). Fix: drop the flag"
            ),
            _ => {}
        }
        if o.guided_sampling.is_some() || o.guided_from.is_some() {
            let Some(st) = config.spacetime.as_mut() else {
                anyhow::bail!(
                    "--guided-sampling and --guided-from apply to --model spacetime-full or \
                     spacetime-lite only (this run trains {name}). Fix: drop the flag"
                );
            };
            if o.guided_sampling == Some(false) {
                anyhow::ensure!(
                    o.guided_from.is_none(),
                    "--guided-from with --guided-sampling off: nothing would sample. Fix: drop \
                     one of them"
                );
                st.guided = None;
            } else if let (Some(g), Some(from)) = (st.guided.as_mut(), o.guided_from) {
                g.from = from;
            }
        }
        if o.densify_abs_grad {
            anyhow::ensure!(
                self.takes_abs_grad(),
                "--densify-abs-grad applies to the models densified by the mean gradient: 3dgs, \
                 mip-splatting, spacetime-lite, spacetime-full (this run trains {name}, whose \
                 statistic it would not combine with). Fix: drop the flag"
            );
            config.density.abs_grad = true;
        }
        if let Some(freeze) = o.omega_freeze {
            let Some(st) = config.spacetime.as_mut() else {
                anyhow::bail!(
                    "--omega-freeze applies to the spacetime models only (this run trains \
                     {name}). Fix: drop the flag"
                );
            };
            st.omega_freeze = freeze.map(|from| OmegaFreeze {
                from,
                ..st.omega_freeze.unwrap_or_default()
            });
        }
        Ok(())
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
                "--guided-sampling and --guided-from",
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
        assert_eq!(c.surfels.unwrap().distortion_weight, 1000.0);
        let mut c = TrainConfig::default();
        BaseModel::SpacetimeLite
            .apply_options(&cases[3].0, &mut c)
            .unwrap();
        assert_eq!(c.spacetime.unwrap().omega_freeze, None);
        assert!(TrainConfig::default().spacetime.is_none());
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
