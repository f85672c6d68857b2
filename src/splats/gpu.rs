//! The Gaussian parameters as GPU buffers, one buffer per parameter group (the groups Adam gives
//! separate learning rates), sized for growth: `capacity` ≥ `count`, so density control can add
//! Gaussians without reallocating every step.
//!
//! Layout (flat f32 arrays, Gaussian `i` at `i * stride`): positions stride 3, log-scales 3,
//! rotations 4 (w, x, y, z), opacity logits 1, SH DC 3, SH rest `3 * ((d+1)² − 1)` in five
//! column planes of at most 9 floats ([`sh_planes`]: no buffer is wider than 36 bytes a
//! Gaussian, so the storage binding limit does not cap the model before device memory does),
//! then the model's extra groups ([`ExtraGroup`]) in their order.

use super::sh_planes::{self, PLANES};
use super::{ExtraGroup, ExtraValues, GaussianParams};
use crate::gpu::{Bindable, BufferKind, GpuBuffer, GpuContext};
use anyhow::bail;
use std::sync::Arc;

pub struct GpuSplats {
    pub count: usize,
    pub capacity: usize,
    pub sh_degree: u32,
    pub positions: GpuBuffer<f32>,
    pub log_scales: GpuBuffer<f32>,
    pub rotations: GpuBuffer<f32>,
    pub opacity_logits: GpuBuffer<f32>,
    pub sh_dc: GpuBuffer<f32>,
    /// The SH rest coefficients in column planes ([`sh_planes`]).
    pub sh_rest: [GpuBuffer<f32>; PLANES],
    /// The model's extra groups, one buffer each, described by `extra_groups`.
    pub extra: Vec<GpuBuffer<f32>>,
    pub extra_groups: Vec<ExtraGroup>,
}

/// What a set of Gaussian buffers holds per Gaussian: the SH degree and the extra groups. Sets
/// that move together (parameters, gradients, Adam moments) have one shape.
#[derive(Debug, Clone, PartialEq, Eq, Default)]
pub struct SplatShape {
    pub sh_degree: u32,
    pub extra: Vec<ExtraGroup>,
}

impl SplatShape {
    /// The 3DGS groups only.
    pub fn plain(sh_degree: u32) -> Self {
        Self {
            sh_degree,
            extra: Vec::new(),
        }
    }

    /// `(name, floats per Gaussian)` of every logical group (SH rest as one group of
    /// `3 * ((d+1)² − 1)`; the checkpoint layout and the learning-rate order).
    pub fn strides(&self) -> Vec<(String, usize)> {
        let rest = GaussianParams::empty(self.sh_degree).rest_stride();
        let base = [
            ("positions", 3),
            ("log_scales", 3),
            ("rotations", 4),
            ("opacity_logits", 1),
            ("sh_dc", 3),
            ("sh_rest", rest),
        ];
        base.iter()
            .map(|&(n, s)| (n.to_string(), s))
            .chain(self.extra.iter().map(|g| (g.name.clone(), g.stride)))
            .collect()
    }

    /// `(name, floats per Gaussian)` of every stored buffer, in [`GpuSplats::groups`] order:
    /// the logical groups with SH rest as its planes `sh_rest[0..PLANES]`.
    pub fn storage_strides(&self) -> Vec<(String, usize)> {
        let r = GaussianParams::empty(self.sh_degree).rest_coeffs();
        let mut out = self.strides();
        out.splice(
            REST..REST + 1,
            (0..PLANES).map(|p| (format!("sh_rest[{p}]"), sh_planes::plane_stride(r, p))),
        );
        out
    }
}

/// Stored buffers of every model before its extra groups: the five 3DGS groups before SH rest
/// and the SH rest planes.
pub const FIXED_GROUPS: usize = REST + PLANES;

/// Index of the SH rest group among the logical groups (positions, log-scales, rotations,
/// opacity logits, SH DC, SH rest, extras).
const REST: usize = 5;

/// The SH rest plane stored buffer `k` of [`GpuSplats::groups`] is, if it is one.
pub fn sh_rest_plane(k: usize) -> Option<usize> {
    (REST..REST + PLANES).contains(&k).then(|| k - REST)
}

/// The logical group (learning rate, checkpoint group) of stored buffer `k` of
/// [`GpuSplats::groups`].
pub fn logical_group(k: usize) -> usize {
    if k < REST {
        k
    } else if k < REST + PLANES {
        REST
    } else {
        k - (PLANES - 1)
    }
}

/// Capacity for `count` Gaussians with room to grow: 1.125× (at least 1024 more), the geometric
/// growth density control relies on.
pub fn grown_capacity(count: usize) -> usize {
    (count + count / 8).max(count + 1024)
}

/// The names kernels give a set's parameter buffers (their GLSL block members), in the
/// order of [`GpuSplats::bindings`]: the SH rest planes are `sh_rest0`, `sh_rest1`, ….
pub const PARAM_BINDINGS: [&str; 5 + PLANES] = [
    "positions",
    "log_scales",
    "rotations",
    "opacity_logits",
    "sh_dc",
    "sh_rest0",
    "sh_rest1",
    "sh_rest2",
    "sh_rest3",
    "sh_rest4",
];

/// The names of the same buffers of a gradient set (`g_positions`, …, `g_sh_rest4`).
pub const GRAD_BINDINGS: [&str; 5 + PLANES] = [
    "g_positions",
    "g_log_scales",
    "g_rotations",
    "g_opacity_logits",
    "g_sh_dc",
    "g_sh_rest0",
    "g_sh_rest1",
    "g_sh_rest2",
    "g_sh_rest3",
    "g_sh_rest4",
];

impl GpuSplats {
    /// The fixed groups' buffers named as a kernel binds them (`names`: [`PARAM_BINDINGS`] for
    /// parameters, [`GRAD_BINDINGS`] for their gradients), for
    /// [`Recorder::dispatch_named`](crate::gpu::Recorder::dispatch_named).
    pub fn bindings<'a>(
        &'a self,
        names: &[&'static str; 5 + PLANES],
    ) -> [(&'static str, &'a dyn Bindable); 5 + PLANES] {
        let b: [&'a dyn Bindable; 5 + PLANES] = [
            &self.positions,
            &self.log_scales,
            &self.rotations,
            &self.opacity_logits,
            &self.sh_dc,
            &self.sh_rest[0],
            &self.sh_rest[1],
            &self.sh_rest[2],
            &self.sh_rest[3],
            &self.sh_rest[4],
        ];
        std::array::from_fn(|k| (names[k], b[k]))
    }

    /// Uploads `params` (validated first: NaN or inf never reaches the GPU) into buffers of
    /// `capacity` Gaussians (at least `params.len()`).
    pub fn upload(
        ctx: &Arc<GpuContext>,
        params: &GaussianParams,
        capacity: usize,
    ) -> anyhow::Result<Self> {
        params.validate()?;
        let n = params.len();
        if capacity < n {
            bail!("GPU capacity {capacity} is smaller than the {n} Gaussians to upload");
        }
        let r = params.rest_coeffs();
        let make = |name: &str, stride: usize, data: &[f32]| -> anyhow::Result<GpuBuffer<f32>> {
            let b = GpuBuffer::new(ctx, name, capacity * stride, BufferKind::DeviceLocal)?;
            b.upload(data)?;
            Ok(b)
        };
        let planes = sh_planes::split(&params.sh_rest, n, r);
        Ok(Self {
            count: n,
            capacity,
            sh_degree: params.sh_degree,
            positions: make("positions", 3, bytemuck::cast_slice(&params.positions))?,
            log_scales: make("log_scales", 3, bytemuck::cast_slice(&params.log_scales))?,
            rotations: make("rotations", 4, bytemuck::cast_slice(&params.rotations))?,
            opacity_logits: make("opacity_logits", 1, &params.opacity_logits)?,
            sh_dc: make("sh_dc", 3, bytemuck::cast_slice(&params.sh_dc))?,
            sh_rest: each_plane(|p| {
                make(
                    &format!("sh_rest[{p}]"),
                    sh_planes::plane_stride(r, p),
                    &planes[p],
                )
            })?,
            extra: params
                .extra
                .iter()
                .map(|e| make(&e.group.name, e.group.stride, &e.values))
                .collect::<anyhow::Result<_>>()?,
            extra_groups: params.extra.iter().map(|e| e.group.clone()).collect(),
        })
    }

    /// What this set holds per Gaussian.
    pub fn shape(&self) -> SplatShape {
        SplatShape {
            sh_degree: self.sh_degree,
            extra: self.extra_groups.clone(),
        }
    }

    /// Buffers of the 3DGS layout at `sh_degree` filled with zeros (see [`Self::zeroed_shape`]).
    pub fn zeroed(
        ctx: &Arc<GpuContext>,
        prefix: &str,
        sh_degree: u32,
        count: usize,
        capacity: usize,
    ) -> anyhow::Result<Self> {
        Self::zeroed_shape(ctx, prefix, &SplatShape::plain(sh_degree), count, capacity)
    }

    /// Buffers of `shape` filled with zeros on the host side (for gradients and Adam moments:
    /// they mirror the parameters group by group). Names get `prefix`.
    pub fn zeroed_shape(
        ctx: &Arc<GpuContext>,
        prefix: &str,
        shape: &SplatShape,
        count: usize,
        capacity: usize,
    ) -> anyhow::Result<Self> {
        let mut s = Self::allocate_shape(ctx, prefix, shape, capacity)?;
        for (b, _) in s.groups() {
            b.upload(&vec![0.0; b.len()])?;
        }
        s.count = count;
        Ok(s)
    }

    /// Buffers of `shape` for `capacity` Gaussians, count 0, contents undefined (for a
    /// destination every row of which is written before it is read).
    pub fn allocate_shape(
        ctx: &Arc<GpuContext>,
        prefix: &str,
        shape: &SplatShape,
        capacity: usize,
    ) -> anyhow::Result<Self> {
        let buf = |name: &str, stride: usize| {
            GpuBuffer::new(
                ctx,
                &format!("{prefix}{name}"),
                (capacity * stride).max(1),
                BufferKind::DeviceLocal,
            )
        };
        let r = GaussianParams::empty(shape.sh_degree).rest_coeffs();
        Ok(Self {
            count: 0,
            capacity,
            sh_degree: shape.sh_degree,
            positions: buf("positions", 3)?,
            log_scales: buf("log_scales", 3)?,
            rotations: buf("rotations", 4)?,
            opacity_logits: buf("opacity_logits", 1)?,
            sh_dc: buf("sh_dc", 3)?,
            sh_rest: each_plane(|p| buf(&format!("sh_rest[{p}]"), sh_planes::plane_stride(r, p)))?,
            extra: shape
                .extra
                .iter()
                .map(|g| buf(&g.name, g.stride))
                .collect::<anyhow::Result<_>>()?,
            extra_groups: shape.extra.clone(),
        })
    }

    /// Every stored parameter buffer with its per-Gaussian stride (floats): positions,
    /// log-scales, rotations, opacity logits, SH DC, the three SH rest planes (indices 0–7, the
    /// same for every model), then the model's extra groups. [`logical_group`] maps an index to
    /// its learning-rate group.
    pub fn groups(&self) -> Vec<(&GpuBuffer<f32>, usize)> {
        let r = GaussianParams::empty(self.sh_degree).rest_coeffs();
        let mut g = vec![
            (&self.positions, 3),
            (&self.log_scales, 3),
            (&self.rotations, 4),
            (&self.opacity_logits, 1),
            (&self.sh_dc, 3),
        ];
        g.extend(
            self.sh_rest
                .iter()
                .enumerate()
                .map(|(p, b)| (b, sh_planes::plane_stride(r, p))),
        );
        g.extend(
            self.extra
                .iter()
                .zip(&self.extra_groups)
                .map(|(b, e)| (b, e.stride)),
        );
        g
    }

    /// Every buffer with its floats per Gaussian, mutable (in the order of [`Self::groups`],
    /// whose widths it takes).
    pub fn groups_mut(&mut self) -> Vec<(&mut GpuBuffer<f32>, usize)> {
        let widths: Vec<usize> = self.groups().iter().map(|g| g.1).collect();
        let mut buffers = vec![
            &mut self.positions,
            &mut self.log_scales,
            &mut self.rotations,
            &mut self.opacity_logits,
            &mut self.sh_dc,
        ];
        buffers.extend(self.sh_rest.iter_mut());
        buffers.extend(self.extra.iter_mut());
        debug_assert_eq!(buffers.len(), widths.len());
        buffers.into_iter().zip(widths).collect()
    }

    /// The buffer of the extra group called `name`.
    pub fn extra_group(&self, name: &str) -> Option<&GpuBuffer<f32>> {
        self.extra_groups
            .iter()
            .position(|g| g.name == name)
            .map(|k| &self.extra[k])
    }

    /// Reads the first `count` Gaussians back.
    pub fn download(&self) -> anyhow::Result<GaussianParams> {
        let n = self.count;
        let mut p = GaussianParams::empty(self.sh_degree);
        p.positions = bytemuck::cast_slice(&self.positions.read_range(0, n * 3)?).to_vec();
        p.log_scales = bytemuck::cast_slice(&self.log_scales.read_range(0, n * 3)?).to_vec();
        p.rotations = bytemuck::cast_slice(&self.rotations.read_range(0, n * 4)?).to_vec();
        p.opacity_logits = self.opacity_logits.read_range(0, n)?;
        p.sh_dc = bytemuck::cast_slice(&self.sh_dc.read_range(0, n * 3)?).to_vec();
        p.sh_rest = self.read_sh_rest()?;
        p.extra = self
            .extra
            .iter()
            .zip(&self.extra_groups)
            .map(|(b, g)| {
                Ok(ExtraValues {
                    group: g.clone(),
                    values: b.read_range(0, n * g.stride)?,
                })
            })
            .collect::<anyhow::Result<_>>()?;
        Ok(p)
    }

    /// The first `count` Gaussians' SH rest coefficients in the logical layout.
    pub fn read_sh_rest(&self) -> anyhow::Result<Vec<f32>> {
        let (n, r) = (
            self.count,
            GaussianParams::empty(self.sh_degree).rest_coeffs(),
        );
        let planes = self
            .sh_rest
            .iter()
            .enumerate()
            .map(|(p, b)| b.read_range(0, n * sh_planes::plane_stride(r, p)))
            .collect::<anyhow::Result<Vec<_>>>()?;
        let refs: Vec<&[f32]> = planes.iter().map(Vec::as_slice).collect();
        Ok(sh_planes::merge(&refs, n, r))
    }

    /// Writes `n` Gaussians' SH rest coefficients given in the logical layout at the start of
    /// the planes.
    pub fn write_sh_rest(&self, rest: &[f32], n: usize) -> anyhow::Result<()> {
        let r = GaussianParams::empty(self.sh_degree).rest_coeffs();
        for (b, plane) in self.sh_rest.iter().zip(sh_planes::split(rest, n, r)) {
            b.upload(&plane)?;
        }
        Ok(())
    }
}

/// The planes built by `f(p)`, stopping at the first error.
fn each_plane<T>(mut f: impl FnMut(usize) -> anyhow::Result<T>) -> anyhow::Result<[T; PLANES]> {
    let planes = (0..PLANES)
        .map(&mut f)
        .collect::<anyhow::Result<Vec<T>>>()?;
    Ok(planes
        .try_into()
        .unwrap_or_else(|_| unreachable!("PLANES planes were built")))
}
