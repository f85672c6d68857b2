//! Zone membership and the LPM opacity reset on the CPU (docs/algorithms/lpm.md steps 7–8): the oracle of the GPU
//! passes in [`crate::lpm::gpu`], written to give the same bits.
//!
//! * Membership reproduces `glsl/lpm/zone_membership.comp` operation for operation in f32 (IEEE
//!   add, sub and mul only, same order, no fused multiply-add), so every flag and count is equal,
//!   including points exactly on a zone's boundary: "inside" includes the boundary (`≤`) on both
//!   sides, and both sides round the same products the same way. The geometry is documented in the
//!   shader and on [`ZoneTest`].
//! * The opacity threshold is an order statistic, selected exactly on both sides, and compared in
//!   the total order of [`float_key`].

use crate::lpm::record::{ZoneRecord, ZONE_BOX, ZONE_NO_RESET, ZONE_SHAPE_MASK, ZONE_SLAB};
use crate::lpm::reset_settings::{
    OpacityResetSettings, OpacityResetStats, FLAG_INSIDE, FLAG_IN_BALL, FLAG_IN_FRONT,
    SHARE_DENOMINATOR,
};

/// One zone prepared for the tests, with the shader's per-zone precomputation.
///
/// Inside: sphere `|x − c|² ≤ r²`, box `|x_k − c_k| ≤ h_k` per axis, slab: inside the in-front
/// cone below and `|a| − f ≤ |v| ≤ |a| + f` (far face: `U = V − A − F ≤ 0 ∨ U² ≤ 4AF`; near
/// face: `A ≤ F ∨ W ≤ 0 ∨ 4FV ≥ W²`). In ball: `|x − c|² ≤ ρ²`
/// with ρ the zone's `cone_radius`. In front (the cone from the zone's `camera_center` o to the
/// ball (c, r = ρ), ending at the near side of the ball (c, f) with f the `front_radius`): with
/// v = x − o, a = c − o, V = v·v, A = a·a, D = v·a, R = r², F = f²: `D ≥ 0`,
/// `D²(A + R) ≥ A²V` (angle(v, a) ≤ atan(r/|a|)), and `|v| ≤ |a| − f` as
/// `W = A − V − F ≥ 0 ∧ 4FV ≤ W²` when A > F, else `V ≤ A` (|v| ≤ |a|).
/// Points at the apex (V = 0) and zones centred on their camera (A = 0) have no defined angle and
/// give "not in front".
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ZoneTest {
    center: [f32; 3],
    r2: f32,
    half: [f32; 3],
    is_box: bool,
    is_slab: bool,
    /// Whether the opacity reset sees the zone (not [`ZONE_NO_RESET`]).
    resets: bool,
    apex: [f32; 3],
    axis: [f32; 3],
    a2: f32,
    /// cone_radius².
    c2: f32,
    /// front_radius².
    f2: f32,
}

impl ZoneTest {
    pub fn new(z: &ZoneRecord) -> ZoneTest {
        let c = z.center;
        let o = z.camera_center;
        let axis = [c[0] - o[0], c[1] - o[1], c[2] - o[2]];
        ZoneTest {
            center: c,
            r2: z.radius * z.radius,
            half: z.half_extents,
            is_box: z.shape & ZONE_SHAPE_MASK == ZONE_BOX,
            is_slab: z.shape & ZONE_SHAPE_MASK == ZONE_SLAB,
            resets: z.shape & ZONE_NO_RESET == 0,
            apex: o,
            axis,
            a2: axis[0] * axis[0] + axis[1] * axis[1] + axis[2] * axis[2],
            c2: z.cone_radius * z.cone_radius,
            f2: z.front_radius * z.front_radius,
        }
    }

    /// In the ball of the zone's cone radius around its centre (never for a [`ZONE_NO_RESET`]
    /// zone).
    pub fn in_ball(&self, x: [f32; 3]) -> bool {
        if !self.resets {
            return false;
        }
        let c = self.center;
        let (dx, dy, dz) = (x[0] - c[0], x[1] - c[1], x[2] - c[2]);
        dx * dx + dy * dy + dz * dz <= self.c2
    }

    pub fn contains(&self, x: [f32; 3]) -> bool {
        let c = self.center;
        if self.is_slab {
            return self.in_slab(x);
        }
        if self.is_box {
            return (0..3).all(|k| (x[k] - c[k]).abs() <= self.half[k]);
        }
        let (dx, dy, dz) = (x[0] - c[0], x[1] - c[1], x[2] - c[2]);
        dx * dx + dy * dy + dz * dz <= self.r2
    }

    /// `V = |x − o|²` when x is inside the cone from the apex o through the ball (c, cone
    /// radius): `D ≥ 0` and `D²(A + R) ≥ A²V`; `None` outside it, at the apex and for a zone
    /// centred on its apex.
    fn in_cone(&self, x: [f32; 3]) -> Option<f32> {
        let o = self.apex;
        let a = self.axis;
        let (big_a, big_r) = (self.a2, self.c2);
        let (vx, vy, vz) = (x[0] - o[0], x[1] - o[1], x[2] - o[2]);
        let v = vx * vx + vy * vy + vz * vz;
        let d = vx * a[0] + vy * a[1] + vz * a[2];
        if !(v > 0.0 && big_a > 0.0 && d >= 0.0) {
            return None;
        }
        // Negated like the shader, so a NaN (overflow of inf·0) gives "outside" on both sides.
        #[allow(clippy::neg_cmp_op_on_partial_ord)]
        if !((d * d) * (big_a + big_r) >= (big_a * big_a) * v) {
            return None;
        }
        Some(v)
    }

    /// The in-front cone cut to the band of distances from the apex (a slab's inside).
    fn in_slab(&self, x: [f32; 3]) -> bool {
        let Some(v) = self.in_cone(x) else {
            return false;
        };
        let (big_a, big_f) = (self.a2, self.f2);
        let u = (v - big_a) - big_f;
        if !(u <= 0.0 || u * u <= (4.0 * big_a) * big_f) {
            return false;
        }
        if big_a <= big_f {
            return true;
        }
        let w = (big_a - v) - big_f;
        w <= 0.0 || (4.0 * big_f) * v >= w * w
    }

    /// In front of the zone (never for a [`ZONE_NO_RESET`] zone).
    pub fn in_front(&self, x: [f32; 3]) -> bool {
        if !self.resets {
            return false;
        }
        let Some(v) = self.in_cone(x) else {
            return false;
        };
        let big_a = self.a2;
        let big_f = self.f2;
        if big_a > big_f {
            let w = (big_a - v) - big_f;
            return w >= 0.0 && (4.0 * big_f) * v <= w * w;
        }
        v <= big_a
    }
}

/// Flags of every Gaussian and the number of centres inside each zone.
#[derive(Debug, Clone, PartialEq, Eq, Default)]
pub struct Membership {
    /// One per Gaussian: [`FLAG_INSIDE`] | [`FLAG_IN_FRONT`] | [`FLAG_IN_BALL`].
    pub flags: Vec<u32>,
    /// One per zone: centres inside it (a centre inside two zones counts in both).
    pub inside_counts: Vec<u32>,
}

/// Membership of `positions` (xyz per Gaussian) against `zones`.
pub fn membership(positions: &[f32], zones: &[ZoneRecord]) -> Membership {
    let tests: Vec<ZoneTest> = zones.iter().map(ZoneTest::new).collect();
    let mut inside_counts = vec![0u32; zones.len()];
    let flags = positions
        .chunks_exact(3)
        .map(|p| {
            let x = [p[0], p[1], p[2]];
            let mut f = 0;
            for (t, n) in tests.iter().zip(inside_counts.iter_mut()) {
                if t.contains(x) {
                    f |= FLAG_INSIDE;
                    *n += 1;
                }
                if f & FLAG_IN_FRONT == 0 && t.in_front(x) {
                    f |= FLAG_IN_FRONT;
                }
                if f & FLAG_IN_BALL == 0 && t.in_ball(x) {
                    f |= FLAG_IN_BALL;
                }
            }
            f
        })
        .collect();
    Membership {
        flags,
        inside_counts,
    }
}

/// A u32 whose unsigned order is `f32::total_cmp`'s (the GPU's `float_key`).
pub fn float_key(x: f32) -> u32 {
    let b = x.to_bits();
    if b & 0x8000_0000 != 0 {
        !b
    } else {
        b | 0x8000_0000
    }
}

/// The inverse of [`float_key`].
pub fn key_to_f32(k: u32) -> f32 {
    f32::from_bits(if k & 0x8000_0000 != 0 {
        k & 0x7FFF_FFFF
    } else {
        !k
    })
}

/// The reset threshold as a float key: the k-th largest key among the Gaussians inside zones.
pub fn opacity_threshold_key(
    logits: &[f32],
    flags: &[u32],
    s: &OpacityResetSettings,
) -> anyhow::Result<(u32, Option<u32>)> {
    let top = s.top_basis_points()? as u64;
    let mut keys: Vec<u32> = logits
        .iter()
        .zip(flags)
        .filter(|(_, &f)| f & s.threshold_set != 0)
        .map(|(&l, _)| float_key(l))
        .collect();
    let n = keys.len() as u64;
    let k = n * top / SHARE_DENOMINATOR as u64;
    if k == 0 {
        return Ok((n as u32, None));
    }
    let rank = (n - k) as usize;
    let (_, &mut t, _) = keys.select_nth_unstable(rank);
    Ok((n as u32, Some(t)))
}

/// Resets, in place, the opacity logit of every Gaussian in front of a zone whose logit is at or
/// above the threshold (compared as float keys). `flags` and `logits` have one entry per Gaussian.
pub fn apply_opacity_reset(
    logits: &mut [f32],
    flags: &[u32],
    s: &OpacityResetSettings,
) -> anyhow::Result<OpacityResetStats> {
    anyhow::ensure!(
        logits.len() == flags.len(),
        "LPM opacity reset: {} opacity logits but {} membership flags (one each per Gaussian)",
        logits.len(),
        flags.len()
    );
    let value = s.reset_logit()?;
    let (inside, key) = opacity_threshold_key(logits, flags, s)?;
    let mut stats = OpacityResetStats {
        inside,
        threshold_logit: key.map(key_to_f32),
        reset: 0,
    };
    if let Some(t) = key {
        for (l, &f) in logits.iter_mut().zip(flags) {
            if f & FLAG_IN_FRONT != 0 && float_key(*l) >= t {
                *l = value;
                stats.reset += 1;
            }
        }
    }
    Ok(stats)
}
