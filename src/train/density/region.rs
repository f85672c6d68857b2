//! Where density control may grow a model ([`GrowthRegion`], `train --grow-within FILE`): a
//! Gaussian whose centre lies outside is never cloned nor split (it is still pruned, and it
//! still trains). A block of a partitioned scene (`partition --grow-within-region`) then grows
//! only its own region: the rest of the scene it starts from (the coarse model's backdrop) stays
//! as it came, instead of being regrown Gaussian by Gaussian in every block that sees it.

use std::path::Path;

use crate::error::InputError;
use crate::scene::SceneFrame;

/// One band of a region: the points whose coordinate along `axis` lies in `[lo, hi)`
/// (`lo = −∞` or `hi = +∞` leaves that side open).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct RegionBand {
    /// A unit vector.
    pub axis: [f64; 3],
    pub lo: f64,
    pub hi: f64,
}

/// The intersection of two bands (a rectangle on a plane, infinite along its normal: a block's
/// region on the ground), in the frame of the positions it is tested against.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct GrowthRegion {
    pub bands: [RegionBand; 2],
}

fn dot(a: [f64; 3], b: [f64; 3]) -> f64 {
    a[0] * b[0] + a[1] * b[1] + a[2] * b[2]
}

impl GrowthRegion {
    /// Whether the region holds `p`.
    pub fn contains(&self, p: [f64; 3]) -> bool {
        self.bands.iter().all(|b| {
            let c = dot(b.axis, p);
            c >= b.lo && c < b.hi
        })
    }

    /// The same region for positions in a scene's training frame (`train = scale · (user −
    /// origin)`), given in the user's frame: every bound moves with the frame.
    pub fn in_training_frame(&self, frame: &SceneFrame) -> GrowthRegion {
        let mut r = *self;
        for b in r.bands.iter_mut() {
            let shift = dot(b.axis, frame.origin);
            b.lo = frame.scale * (b.lo - shift);
            b.hi = frame.scale * (b.hi - shift);
        }
        r
    }

    /// The bands as the decision kernel takes them: per band the axis, lo and hi in f32.
    pub fn kernel_words(&self) -> [f32; 10] {
        let mut w = [0.0; 10];
        for (k, b) in self.bands.iter().enumerate() {
            w[5 * k..5 * k + 3].copy_from_slice(&b.axis.map(|v| v as f32));
            w[5 * k + 3] = b.lo as f32;
            w[5 * k + 4] = b.hi as f32;
        }
        w
    }

    /// `{"bands": [{"axis": [x, y, z], "lo": a, "hi": b}, …]}`, an open side `null`.
    pub fn to_json(&self) -> serde_json::Value {
        let bound = |v: f64| {
            if v.is_finite() {
                serde_json::json!(v)
            } else {
                serde_json::Value::Null
            }
        };
        serde_json::json!({
            "bands": self.bands.iter().map(|b| serde_json::json!({
                "axis": b.axis, "lo": bound(b.lo), "hi": bound(b.hi),
            })).collect::<Vec<_>>(),
        })
    }

    /// Reads [`GrowthRegion::to_json`]'s layout from `path`; a file that does not hold two
    /// bands of a unit axis and `lo < hi` is refused naming the field.
    pub fn read(path: &Path) -> anyhow::Result<GrowthRegion> {
        let bad = |field: String, problem: String| -> anyhow::Error {
            InputError::new(
                path,
                field,
                problem,
                "write it as {\"bands\": [{\"axis\": [x, y, z], \"lo\": a, \"hi\": b}, {…}]} \
                 (two bands, unit axes, lo < hi, null for an open side), or let `partition \
                 --grow-within-region` write it",
            )
            .into()
        };
        let text = std::fs::read_to_string(path)
            .map_err(|e| bad("file".into(), format!("cannot be read ({e})")))?;
        let j: serde_json::Value = serde_json::from_str(&text)
            .map_err(|e| bad("file".into(), format!("is not JSON ({e})")))?;
        let bands = j["bands"]
            .as_array()
            .filter(|b| b.len() == 2)
            .ok_or_else(|| bad("bands".into(), "is not a list of two bands".into()))?;
        let mut out = [RegionBand {
            axis: [0.0; 3],
            lo: f64::NEG_INFINITY,
            hi: f64::INFINITY,
        }; 2];
        for (k, (b, o)) in bands.iter().zip(out.iter_mut()).enumerate() {
            let field = |name: &str| format!("bands[{k}].{name}");
            let axis: Vec<f64> = b["axis"]
                .as_array()
                .map(|a| a.iter().filter_map(|v| v.as_f64()).collect())
                .unwrap_or_default();
            let norm = axis.iter().map(|v| v * v).sum::<f64>().sqrt();
            if axis.len() != 3 || (norm - 1.0).abs() > 1e-6 {
                return Err(bad(
                    field("axis"),
                    format!("{} is not a unit vector of three numbers", b["axis"]),
                ));
            }
            o.axis = [axis[0], axis[1], axis[2]];
            let bound = |name: &str, open: f64| match &b[name] {
                serde_json::Value::Null => Ok(open),
                v => v
                    .as_f64()
                    .filter(|x| x.is_finite())
                    .ok_or_else(|| bad(field(name), format!("{v} is not a finite number"))),
            };
            o.lo = bound("lo", f64::NEG_INFINITY)?;
            o.hi = bound("hi", f64::INFINITY)?;
            if o.lo >= o.hi {
                return Err(bad(
                    field("hi"),
                    format!("{} is not above lo {}: the band is empty", o.hi, o.lo),
                ));
            }
        }
        Ok(GrowthRegion { bands: out })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_region_round_trips_moves_with_the_frame_and_refuses_bad_files() {
        let r = GrowthRegion {
            bands: [
                RegionBand {
                    axis: [1.0, 0.0, 0.0],
                    lo: f64::NEG_INFINITY,
                    hi: 2.0,
                },
                RegionBand {
                    axis: [0.0, 0.6, 0.8],
                    lo: -1.0,
                    hi: 3.0,
                },
            ],
        };
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("region.json");
        std::fs::write(&path, r.to_json().to_string()).unwrap();
        assert_eq!(GrowthRegion::read(&path).unwrap(), r);
        // A point and its image in a training frame are in both regions or in neither.
        let frame = SceneFrame {
            origin: [5.0, -2.0, 1.0],
            scale: 0.25,
        };
        let moved = r.in_training_frame(&frame);
        for p in [
            [1.0, 1.0, 1.0],
            [2.5, 1.0, 1.0],
            [0.0, -3.0, 0.0],
            [1.9, 2.0, 1.5],
        ] {
            let t = [0, 1, 2].map(|k| frame.scale * (p[k] - frame.origin[k]));
            assert_eq!(r.contains(p), moved.contains(t), "{p:?}");
        }
        assert!(r.contains([1.0, 1.0, 1.0]) && !r.contains([2.5, 1.0, 1.0]));
        for (text, field) in [
            ("not json", "file"),
            ("{}", "bands"),
            (r#"{"bands": [{"axis": [1, 0, 0]}]}"#, "bands"),
            (
                r#"{"bands": [{"axis": [2, 0, 0]}, {"axis": [0, 1, 0]}]}"#,
                "bands[0].axis",
            ),
            (
                r#"{"bands": [{"axis": [1, 0, 0], "lo": 3, "hi": 1}, {"axis": [0, 1, 0]}]}"#,
                "bands[0].hi",
            ),
            (
                r#"{"bands": [{"axis": [1, 0, 0]}, {"axis": [0, 1, 0], "lo": "x"}]}"#,
                "bands[1].lo",
            ),
        ] {
            std::fs::write(&path, text).unwrap();
            let e = GrowthRegion::read(&path).unwrap_err();
            let i = e.downcast_ref::<InputError>().expect("an input error");
            assert_eq!(i.field, field, "{text}");
            assert!(e.to_string().contains("Fix"), "{e}");
        }
        let e = GrowthRegion::read(&dir.path().join("missing.json")).unwrap_err();
        assert!(e.to_string().contains("missing.json"), "{e}");
    }
}
