//! Appending Gaussians to a training model: LPM's points at empty zones and a base model's own
//! point additions (SpacetimeGaussians' guided error sampling) share this.

use crate::gpu::{BufferKind, GpuBuffer};
use crate::splats::gpu::{grown_capacity, FIXED_GROUPS};
use crate::splats::SH_C0;
pub use crate::train::strategy::NewGaussian;
use crate::train::strategy::{DensityContext, Primitive};

/// Log-scales and rotation (w, x, y, z) of a new point. A 3D Gaussian is isotropic (identity
/// rotation). A surfel added at a zone centre faces the camera whose error created it (our
/// decision; nothing in the LPM or 2DGS sources says which way, docs/algorithms/base-models.md §1.6): its
/// normal, the rotation's third column, points from the centre to that camera, so the view
/// that asked for detail sees the disc face on; the third log-scale is the unused one.
pub fn new_point_shape(primitive: Primitive, row: &NewGaussian) -> ([f32; 3], [f32; 4]) {
    let l = row.scale.ln();
    match primitive {
        Primitive::Gaussian => ([l; 3], [1.0, 0.0, 0.0, 0.0]),
        Primitive::Surfel => {
            let d: [f64; 3] = [0, 1, 2].map(|k| (row.camera_center[k] - row.position[k]) as f64);
            let len = (d[0] * d[0] + d[1] * d[1] + d[2] * d[2]).sqrt();
            // The rotation taking e_z to n: q ∝ (1 + n_z, e_z × n) = (1 + n_z, −n_y, n_x, 0);
            // for n = −e_z (or a camera at the centre), half a turn about x.
            let q = if len > 0.0 && d[2] / len > -1.0 + 1e-9 {
                let n = d.map(|v| v / len);
                let q = [1.0 + n[2], -n[1], n[0], 0.0];
                let qn = (q.iter().map(|v| v * v).sum::<f64>()).sqrt();
                q.map(|v| (v / qn) as f32)
            } else {
                [0.0, 1.0, 0.0, 0.0]
            };
            ([l, l, crate::train::passes::surfels::UNUSED_LOG_SCALE], q)
        }
    }
}

/// Appends `rows` after the current Gaussians (rows `count..count + n`), growing the
/// state and the density statistics when the capacity is short (the trainer grows its own
/// buffers after the strategy's call). Their
/// Adam moments and density statistics are zero. Under a Gaussian budget
/// ([`DensityConfig::ceiling`](super::DensityConfig::ceiling)) only the first rows that fit are
/// appended. Returns how many
/// were. `t.rec` must be begun and empty; it is left so.
pub fn append_gaussians(t: &mut DensityContext, rows: &[NewGaussian]) -> anyhow::Result<usize> {
    append_with_extras(t, rows, None)
}

/// As [`append_gaussians`], with the extra groups' values given per row (`extras[g]` holds
/// group `g`'s values of every row, row after row) instead of the model's one new row.
pub fn append_with_extras(
    t: &mut DensityContext,
    rows: &[NewGaussian],
    extras: Option<&[Vec<f32>]>,
) -> anyhow::Result<usize> {
    let n = t.state.count();
    let room = t
        .density
        .config
        .ceiling()
        .map_or(rows.len(), |cap| cap.saturating_sub(n));
    let m = stage_rows(t, &rows[..rows.len().min(room)], extras, rows.len())?;
    t.state.set_count(n + m);
    Ok(m)
}

/// Writes `rows` (at most `all` given, the extras' columns sized for `all`) into the rows just
/// after the current Gaussians (`count..count + rows.len()`), with zero Adam moments, growing
/// the state and the density statistics when the capacity is short; the count is unchanged, so
/// the rows are staged for the caller to take in (as [`append_with_extras`] does) or to copy
/// elsewhere (MCMC's dead Gaussians moved onto surface samples). Returns how many were written.
/// `t.rec` must be begun and empty; it is left so.
pub fn stage_rows(
    t: &mut DensityContext,
    rows: &[NewGaussian],
    extras: Option<&[Vec<f32>]>,
    all: usize,
) -> anyhow::Result<usize> {
    let n = t.state.count();
    if rows.is_empty() {
        return Ok(0);
    }
    let ctx = t.ctx.clone();
    let new = n + rows.len();
    if new > t.state.capacity() {
        let cap = grown_capacity(new);
        // One buffer at a time, the rows kept (see `SplatState::grow`).
        t.state.grow(&ctx, t.rec, cap)?;
        t.rec.begin()?;
        t.density.ensure_capacity(cap)?;
    }
    let m = rows.len();
    let strides: Vec<usize> = t.state.params.groups().iter().map(|g| g.1).collect();
    // Stored buffers before the extra groups (SH rest as its planes).
    let fixed = FIXED_GROUPS;
    anyhow::ensure!(
        t.new_extras.len() == strides.len() - fixed
            && t.new_extras
                .iter()
                .zip(&strides[fixed..])
                .all(|(e, &s)| e.len() == s),
        "adding Gaussians: the model gives new Gaussians {} extra rows for its {} extra groups",
        t.new_extras.len(),
        strides.len() - fixed
    );
    if let Some(x) = extras {
        anyhow::ensure!(
            x.len() == strides.len() - fixed
                && x.iter()
                    .zip(&strides[fixed..])
                    .all(|(e, &s)| e.len() == s * all),
            "adding Gaussians: extra values given for {} groups, not one column per extra group \
             and row",
            x.len()
        );
    }
    let logit = |p: f64| (p / (1.0 - p)).ln() as f32;
    let mut data: Vec<Vec<f32>> = vec![Vec::new(); strides.len()];
    for r in rows {
        anyhow::ensure!(
            r.position.iter().all(|v| v.is_finite()) && r.scale > 0.0 && r.scale.is_finite(),
            "refusing to add a Gaussian at {:?} with scale {}",
            r.position,
            r.scale
        );
        let (log_scales, rotation) = new_point_shape(t.primitive, r);
        data[0].extend(r.position);
        data[1].extend(log_scales);
        data[2].extend(rotation);
        data[3].push(logit(r.opacity));
        data[4].extend(r.color.map(|c| match t.raw_colour {
            true => c,
            false => ((c as f64 - 0.5) / SH_C0) as f32,
        }));
        for (d, &s) in data[5..fixed].iter_mut().zip(&strides[5..fixed]) {
            d.extend(std::iter::repeat_n(0.0, s));
        }
        if extras.is_none() {
            for (d, e) in data[fixed..].iter_mut().zip(&t.new_extras) {
                d.extend(e);
            }
        }
    }
    if let Some(x) = extras {
        for ((d, e), &s) in data[fixed..].iter_mut().zip(x).zip(&strides[fixed..]) {
            d.extend(&e[..s * m]);
        }
    }
    let staging: Vec<Option<GpuBuffer<f32>>> = data
        .iter()
        .map(|d| {
            if d.is_empty() {
                return Ok(None);
            }
            let b = GpuBuffer::new(&ctx, "lpm new rows", d.len(), BufferKind::Upload)?;
            b.upload(d)?;
            Ok(Some(b))
        })
        .collect::<anyhow::Result<_>>()?;
    let zeros_len = m * strides.iter().max().copied().unwrap_or(1).max(1);
    let zeros = GpuBuffer::new(&ctx, "lpm zero moments", zeros_len, BufferKind::Upload)?;
    zeros.upload(&vec![0.0f32; zeros_len])?;
    {
        let (p, mm, v) = (
            t.state.params.groups(),
            t.state.m.groups(),
            t.state.v.groups(),
        );
        for (k, &s) in strides.iter().enumerate() {
            if s == 0 {
                continue;
            }
            if let Some(b) = &staging[k] {
                t.rec.copy_region(b, 0, p[k].0, n * s, m * s);
            }
            t.rec.copy_region(&zeros, 0, mm[k].0, n * s, m * s);
            t.rec.copy_region(&zeros, 0, v[k].0, n * s, m * s);
        }
    }
    t.rec.submit_and_wait()?;
    t.rec.begin()?;
    Ok(m)
}
