//! Training checkpoints: everything needed to continue a run exactly where it stopped.
//!
//! Binary, little-endian, versioned. Layout (format version 4; version 1, without the extra
//! groups, 2, without the absolute-gradient statistic, and 3, without the training frame, are
//! still read):
//!
//! ```text
//! magic "LPMSCKPT"  u32 version
//! fingerprint: u32 sh_degree, (version 2) u32 extra groups, per group (u32 name length, name
//!              bytes, u32 stride), u32 views, per view (u32 name length, name bytes, u32 width,
//!              u32 height), u32 train views, u32 per train view (index into the views),
//!              (version 4) the training frame: f64 origin x, y, z, f64 scale
//! u32 iteration  u32 adam_step  u64 epoch  u64 position in the epoch  u32 dropped frames
//! u64 intersection capacity
//! u64 count
//! parameters, Adam m, Adam v: 6 groups each (positions, log-scales, rotations, opacity
//!              logits, SH DC, SH rest) then the extra groups, each u64 length then f32 data
//!              (count × stride)
//! density statistics grad_accum, denom, max_radii, (version 3) abs_accum: u64 length then f32
//!              data (count each)
//! config: u64 length then the config's JSON (UTF-8)
//! u64 FNV-1a hash of every byte before it
//! ```
//!
//! The fingerprint ties a checkpoint to the scene it was trained on (the view names, their
//! sizes at the chosen resolution, the training split, the frame its Gaussians are held in,
//! [`crate::scene::frame`]) and to the SH degree; the hash catches
//! truncated and corrupt files before anything is uploaded. Files are written with
//! [`write_atomic`], so a crash while saving leaves the previous checkpoint intact.
//!
//! Resuming restores the Gaussians, both Adam moment sets, the density statistics, the
//! iteration and Adam step counters and the view schedule's position, so N iterations in one
//! run and N/2 + save + load + N/2 produce the same model (bit for bit where the device's
//! float atomics are; see `tests/train/end_to_end.rs`). Buffer capacities are not restored except the
//! intersection capacity (the one that changes results: a frame that overflows it is dropped).

use std::io::Write;
use std::path::Path;
use std::sync::Arc;

use anyhow::Context;

use super::passes::ModelTraining;
use super::trainer::{TrainConfig, Trainer};
use crate::error::{bad_input, write_atomic};
use crate::gpu::{GpuBuffer, GpuContext};
use crate::scene::image_source::TrainImages;
use crate::scene::Scene;
use crate::splats::gpu::{logical_group, GpuSplats, SplatShape};
use crate::splats::{ExtraGroup, ExtraValues, GaussianParams};

pub const MAGIC: &[u8; 8] = b"LPMSCKPT";
pub const FORMAT_VERSION: u32 = 4;

/// What ties a checkpoint to a scene and a model layout.
#[derive(Debug, Clone, PartialEq)]
pub struct SceneFingerprint {
    pub sh_degree: u32,
    /// The model's extra parameter groups (part of the model's shape; the configuration, which
    /// names the model, is compared separately).
    pub extra: Vec<ExtraGroup>,
    /// (name, width, height) of every view at the loaded resolution.
    pub views: Vec<(String, u32, u32)>,
    pub train: Vec<u32>,
    /// The training frame the checkpoint's Gaussians and moments are in; `None` for a file
    /// before format 4, trained in the scene files' own frame, which
    /// [`Checkpoint::into_frame`] moves into the scene's training frame on resuming.
    pub frame: Option<crate::scene::SceneFrame>,
}

impl SceneFingerprint {
    pub fn of(scene: &Scene, shape: &SplatShape) -> Self {
        Self {
            sh_degree: shape.sh_degree,
            extra: shape.extra.clone(),
            views: scene
                .views
                .iter()
                .map(|v| (v.name.clone(), v.camera.width, v.camera.height))
                .collect(),
            train: scene.train.iter().map(|&v| v as u32).collect(),
            frame: Some(scene.frame),
        }
    }

    /// The first difference from `other` (the scene being resumed), as (field, problem).
    fn difference(&self, scene: &Self) -> Option<(String, String)> {
        if self.sh_degree != scene.sh_degree {
            return Some((
                "sh_degree".into(),
                format!(
                    "the checkpoint has SH degree {}, this run asks for {}",
                    self.sh_degree, scene.sh_degree
                ),
            ));
        }
        if self.views.len() != scene.views.len() {
            return Some((
                "views".into(),
                format!(
                    "the checkpoint was trained on a scene of {} views, this scene has {}",
                    self.views.len(),
                    scene.views.len()
                ),
            ));
        }
        for (i, (a, b)) in self.views.iter().zip(&scene.views).enumerate() {
            if a.0 != b.0 {
                return Some((
                    format!("views[{i}].name"),
                    format!("the checkpoint has '{}', this scene has '{}'", a.0, b.0),
                ));
            }
            if (a.1, a.2) != (b.1, b.2) {
                return Some((
                    format!("views[{i}].size"),
                    format!(
                        "'{}' is {}×{} in the checkpoint and {}×{} here (another -r?)",
                        a.0, a.1, a.2, b.1, b.2
                    ),
                ));
            }
        }
        if self.train != scene.train {
            return Some((
                "train".into(),
                "the training split differs (another --test-split or holdout?)".into(),
            ));
        }
        if let (Some(a), Some(b)) = (&self.frame, &scene.frame) {
            let close = |x: f64, y: f64, unit: f64| (x - y).abs() <= 1e-9 * unit;
            if !(close(a.scale, b.scale, b.scale)
                && (0..3).all(|k| close(a.origin[k], b.origin[k], b.extent())))
            {
                return Some((
                    "frame".into(),
                    format!(
                        "the checkpoint's Gaussians were trained recentred on {:?} and scaled \
                         by {:e}; this scene is trained recentred on {:?} and scaled by {:e} \
                         (other camera poses?)",
                        a.origin, a.scale, b.origin, b.scale
                    ),
                ));
            }
        }
        None
    }
}

/// A checkpoint in host memory.
#[derive(Debug, Clone)]
pub struct Checkpoint {
    pub fingerprint: SceneFingerprint,
    pub iteration: u32,
    pub adam_step: u32,
    pub schedule_epoch: u64,
    pub schedule_next: u64,
    pub dropped_frames: u32,
    pub intersection_capacity: u64,
    pub count: u64,
    /// Parameters, Adam m, Adam v: every group each (`GpuSplats::groups` order), `count ×
    /// stride` floats.
    pub sets: [Vec<Vec<f32>>; 3],
    /// grad_accum, denom, max_radii, abs_accum (`count` floats each; abs_accum zeros when
    /// read from a version before 3).
    pub stats: [Vec<f32>; 4],
    pub config_json: String,
}

fn fnv1a(bytes: &[u8]) -> u64 {
    let mut h = 0xcbf2_9ce4_8422_2325u64;
    for &b in bytes {
        h ^= b as u64;
        h = h.wrapping_mul(0x0000_0100_0000_01b3);
    }
    h
}

struct Writer(Vec<u8>);
impl Writer {
    fn u32(&mut self, v: u32) {
        self.0.extend_from_slice(&v.to_le_bytes());
    }
    fn u64(&mut self, v: u64) {
        self.0.extend_from_slice(&v.to_le_bytes());
    }
    fn bytes(&mut self, b: &[u8]) {
        self.u64(b.len() as u64);
        self.0.extend_from_slice(b);
    }
    fn floats(&mut self, f: &[f32]) {
        self.u64(f.len() as u64);
        for v in f {
            self.0.extend_from_slice(&v.to_le_bytes());
        }
    }
}

/// Reads fields in order; running out of bytes is an error naming the field.
struct Reader<'a> {
    path: &'a Path,
    data: &'a [u8],
    at: usize,
}

impl Reader<'_> {
    fn take(&mut self, n: usize, field: &str) -> anyhow::Result<&[u8]> {
        if self.data.len() - self.at < n {
            return bad_input(
                self.path,
                field,
                format!(
                    "the file ends at byte {} but the field needs {n} bytes from byte {}",
                    self.data.len(),
                    self.at
                ),
                "the checkpoint is truncated or corrupt; use an intact checkpoint.bin or \
                 start a fresh run without --resume",
            );
        }
        let s = &self.data[self.at..self.at + n];
        self.at += n;
        Ok(s)
    }
    fn u32(&mut self, field: &str) -> anyhow::Result<u32> {
        Ok(u32::from_le_bytes(self.take(4, field)?.try_into().unwrap()))
    }
    fn u64(&mut self, field: &str) -> anyhow::Result<u64> {
        Ok(u64::from_le_bytes(self.take(8, field)?.try_into().unwrap()))
    }
    fn len(&mut self, field: &str, each: usize) -> anyhow::Result<usize> {
        let n = self.u64(field)?;
        let left = (self.data.len() - self.at) as u64;
        if n.checked_mul(each as u64).is_none_or(|b| b > left) {
            return bad_input(
                self.path,
                field,
                format!("a length of {n} exceeds the {left} bytes left in the file"),
                "the checkpoint is truncated or corrupt; use an intact checkpoint.bin or \
                 start a fresh run without --resume",
            );
        }
        Ok(n as usize)
    }
    fn string(&mut self, field: &str) -> anyhow::Result<String> {
        let n = self.len(field, 1)?;
        let b = self.take(n, field)?.to_vec();
        String::from_utf8(b).or_else(|_| {
            bad_input(
                self.path,
                field,
                "not UTF-8",
                "the checkpoint is corrupt; use an intact checkpoint.bin",
            )
        })
    }
    fn floats(&mut self, field: &str, expect: usize) -> anyhow::Result<Vec<f32>> {
        let n = self.len(field, 4)?;
        if n != expect {
            return bad_input(
                self.path,
                field,
                format!("{n} values where the Gaussian count asks for {expect}"),
                "the checkpoint is corrupt; use an intact checkpoint.bin",
            );
        }
        let b = self.take(n * 4, field)?;
        Ok(b.chunks_exact(4)
            .map(|c| f32::from_le_bytes(c.try_into().unwrap()))
            .collect())
    }
}

impl Checkpoint {
    pub fn to_bytes(&self) -> Vec<u8> {
        let mut w = Writer(Vec::new());
        w.0.extend_from_slice(MAGIC);
        w.u32(FORMAT_VERSION);
        let f = &self.fingerprint;
        w.u32(f.sh_degree);
        w.u32(f.extra.len() as u32);
        for g in &f.extra {
            w.bytes(g.name.as_bytes());
            w.u32(g.stride as u32);
        }
        w.u32(f.views.len() as u32);
        for (name, width, height) in &f.views {
            w.bytes(name.as_bytes());
            w.u32(*width);
            w.u32(*height);
        }
        w.u32(f.train.len() as u32);
        for &t in &f.train {
            w.u32(t);
        }
        let frame = f.frame.unwrap_or(crate::scene::SceneFrame::IDENTITY);
        for v in frame.origin.iter().chain([&frame.scale]) {
            w.u64(v.to_bits());
        }
        w.u32(self.iteration);
        w.u32(self.adam_step);
        w.u64(self.schedule_epoch);
        w.u64(self.schedule_next);
        w.u32(self.dropped_frames);
        w.u64(self.intersection_capacity);
        w.u64(self.count);
        for set in &self.sets {
            for g in set {
                w.floats(g);
            }
        }
        for s in &self.stats {
            w.floats(s);
        }
        w.bytes(self.config_json.as_bytes());
        let h = fnv1a(&w.0);
        w.u64(h);
        w.0
    }

    /// Parses a checkpoint; `path` is only used in error messages.
    pub fn from_bytes(path: &Path, data: &[u8]) -> anyhow::Result<Self> {
        let corrupt = "use an intact checkpoint.bin or start a fresh run without --resume";
        if data.len() < 12 || &data[..8] != MAGIC {
            return bad_input(
                path,
                "magic",
                "not an lpmsplat checkpoint (the file does not start with LPMSCKPT)",
                "pass the checkpoint.bin that `lpmsplat train` wrote",
            );
        }
        let version = u32::from_le_bytes(data[8..12].try_into().unwrap());
        if !(1..=FORMAT_VERSION).contains(&version) {
            return bad_input(
                path,
                "format version",
                format!(
                    "format version {version}; this build reads versions 1 to {FORMAT_VERSION}"
                ),
                "resume with the lpmsplat version that wrote it, or start a fresh run (its \
                 point_cloud.ply can seed one with --init-ply)",
            );
        }
        if data.len() < 20 {
            return bad_input(path, "header", "the file is truncated", corrupt);
        }
        let (body, tail) = data.split_at(data.len() - 8);
        let stored = u64::from_le_bytes(tail.try_into().unwrap());
        if fnv1a(body) != stored {
            return bad_input(
                path,
                "checksum",
                "the stored hash does not match the contents (truncated or corrupt file)",
                corrupt,
            );
        }
        let mut r = Reader {
            path,
            data: body,
            at: 12,
        };
        let sh_degree = r.u32("sh_degree")?;
        if sh_degree > 3 {
            return bad_input(path, "sh_degree", format!("{sh_degree} > 3"), corrupt);
        }
        let mut extra = Vec::new();
        if version >= 2 {
            let n = r.u32("extra groups")?;
            for i in 0..n {
                let name = r.string(&format!("extra[{i}].name"))?;
                let stride = r.u32(&format!("extra[{i}].stride"))? as usize;
                extra.push(ExtraGroup { name, stride });
            }
        }
        let nviews = r.u32("views")? as usize;
        let mut views = Vec::new();
        for i in 0..nviews {
            let name = r.string(&format!("views[{i}].name"))?;
            let w = r.u32(&format!("views[{i}].width"))?;
            let h = r.u32(&format!("views[{i}].height"))?;
            views.push((name, w, h));
        }
        let ntrain = r.u32("train")? as usize;
        let mut train = Vec::new();
        for i in 0..ntrain {
            train.push(r.u32(&format!("train[{i}]"))?);
        }
        let mut frame = None;
        if version >= 4 {
            let mut f = crate::scene::SceneFrame::IDENTITY;
            for k in 0..3 {
                f.origin[k] = f64::from_bits(r.u64(&format!("frame.origin[{k}]"))?);
            }
            f.scale = f64::from_bits(r.u64("frame.scale")?);
            if f.origin.iter().any(|v| !v.is_finite()) || !(f.scale > 0.0 && f.scale.is_finite()) {
                return bad_input(
                    path,
                    "frame",
                    format!(
                        "origin {:?}, scale {} is not a valid frame",
                        f.origin, f.scale
                    ),
                    corrupt,
                );
            }
            frame = Some(f);
        }
        let iteration = r.u32("iteration")?;
        let adam_step = r.u32("adam_step")?;
        let schedule_epoch = r.u64("schedule epoch")?;
        let schedule_next = r.u64("schedule position")?;
        let dropped_frames = r.u32("dropped frames")?;
        let intersection_capacity = r.u64("intersection capacity")?;
        let count = r.u64("count")?;
        let shape = SplatShape {
            sh_degree,
            extra: extra.clone(),
        };
        let mut sets: [Vec<Vec<f32>>; 3] = Default::default();
        for (s, set_name) in ["params", "adam m", "adam v"].iter().enumerate() {
            for (group, stride) in shape.strides() {
                let Some(expect) = usize::try_from(count)
                    .ok()
                    .and_then(|c| c.checked_mul(stride))
                else {
                    return bad_input(
                        path,
                        format!("{set_name}.{group}"),
                        format!("{count} Gaussians × {stride} floats overflows"),
                        corrupt,
                    );
                };
                sets[s].push(r.floats(&format!("{set_name}.{group}"), expect)?);
            }
        }
        let mut stats: [Vec<f32>; 4] = Default::default();
        for (k, name) in ["grad_accum", "denom", "max_radii"].iter().enumerate() {
            stats[k] = r.floats(&format!("density.{name}"), count as usize)?;
        }
        stats[3] = if version >= 3 {
            r.floats("density.abs_accum", count as usize)?
        } else {
            vec![0.0; count as usize]
        };
        // A NaN or infinity anywhere (a run that diverged before it was saved) would poison
        // the resumed run from its first step: refused here, naming the array and the entry.
        let arrays = sets
            .iter()
            .zip(["params", "adam m", "adam v"])
            .flat_map(|(set, s)| {
                set.iter()
                    .zip(shape.strides())
                    .map(move |(v, (g, _))| (format!("{s}.{g}"), v))
            })
            .chain(
                ["grad_accum", "denom", "max_radii", "abs_accum"]
                    .iter()
                    .zip(&stats)
                    .map(|(n, v)| (format!("density.{n}"), v)),
            );
        for (field, values) in arrays {
            if let Some(i) = values.iter().position(|v| !v.is_finite()) {
                return bad_input(
                    path,
                    format!("{field}[{i}]"),
                    format!("{} is not finite", values[i]),
                    "the run diverged before this checkpoint was saved: resume from an \
                     earlier checkpoint or start a fresh run",
                );
            }
        }
        let config_json = r.string("config")?;
        if r.at != body.len() {
            return bad_input(
                path,
                "end",
                format!("{} unexpected bytes after the config", body.len() - r.at),
                corrupt,
            );
        }
        Ok(Self {
            fingerprint: SceneFingerprint {
                sh_degree,
                extra,
                views,
                train,
                frame,
            },
            iteration,
            adam_step,
            schedule_epoch,
            schedule_next,
            dropped_frames,
            intersection_capacity,
            count,
            sets,
            stats,
            config_json,
        })
    }

    pub fn read(path: &Path) -> anyhow::Result<Self> {
        let data = std::fs::read(path).with_context(|| {
            format!(
                "{}: cannot read the checkpoint. Fix: check the --resume path",
                path.display()
            )
        })?;
        Self::from_bytes(path, &data)
    }

    /// Writes atomically (an existing checkpoint survives a failed write).
    pub fn write(&self, path: &Path) -> anyhow::Result<()> {
        let bytes = self.to_bytes();
        write_atomic(path, |f| Ok(f.write_all(&bytes)?))
    }

    /// The Gaussians of the checkpoint.
    /// Moves a checkpoint from before format 4, whose model and moments are in the scene files'
    /// own frame, into `to`, the training frame (`x' = k·x + b`, [`crate::scene::frame`]):
    /// positions and the length groups named in `length_extras` scale by `k` (their Adam
    /// moments, running means of gradients and of their squares, by `1/k` and `1/k²`, so
    /// that every Adam step is the old one scaled by `k`), log-scales shift by `ln k`
    /// (the first two only with `keep_third_scale`, a surfel's unused axis; their moments
    /// stay), and nothing else has a length. A checkpoint that has a frame is left alone.
    pub fn into_frame(
        &mut self,
        to: &crate::scene::SceneFrame,
        keep_third_scale: bool,
        length_extras: &[&str],
    ) {
        if self.fingerprint.frame.is_some() {
            return;
        }
        let (k, b) = to.stored_to_train([0.0; 3]);
        let [params, m, v] = &mut self.sets;
        for (i, x) in params[0].iter_mut().enumerate() {
            *x = (*x as f64 * k + b[i % 3]) as f32;
        }
        let ln_k = k.ln();
        for (i, l) in params[1].iter_mut().enumerate() {
            if !(keep_third_scale && i % 3 == 2) {
                *l = (*l as f64 + ln_k) as f32;
            }
        }
        let mut lengths = vec![0];
        for (g, group) in self.fingerprint.extra.iter().enumerate() {
            if length_extras.contains(&group.name.as_str()) {
                lengths.push(6 + g);
                for x in &mut params[6 + g] {
                    *x = (*x as f64 * k) as f32;
                }
            }
        }
        for g in lengths {
            m[g].iter_mut().for_each(|x| *x = (*x as f64 / k) as f32);
            v[g].iter_mut()
                .for_each(|x| *x = (*x as f64 / (k * k)) as f32);
        }
        self.fingerprint.frame = Some(*to);
    }

    pub fn params(&self) -> GaussianParams {
        let s = &self.sets[0];
        let mut p = GaussianParams::empty(self.fingerprint.sh_degree);
        p.positions = bytemuck::cast_slice(&s[0]).to_vec();
        p.log_scales = bytemuck::cast_slice(&s[1]).to_vec();
        p.rotations = bytemuck::cast_slice(&s[2]).to_vec();
        p.opacity_logits = s[3].clone();
        p.sh_dc = bytemuck::cast_slice(&s[4]).to_vec();
        p.sh_rest = s[5].clone();
        p.extra = self
            .fingerprint
            .extra
            .iter()
            .zip(&s[6..])
            .map(|(group, values)| ExtraValues {
                group: group.clone(),
                values: values.clone(),
            })
            .collect();
        p
    }
}

/// The logical groups ([`SplatShape::strides`]: SH rest as one group) of the first `count`
/// Gaussians: the checkpoint's layout, whatever the GPU's storage.
fn read_groups(splats: &GpuSplats) -> anyhow::Result<Vec<Vec<f32>>> {
    let n = splats.count;
    let mut out = Vec::new();
    for (k, (buf, stride)) in splats.groups().iter().enumerate() {
        match logical_group(k) {
            REST_GROUP if out.len() > REST_GROUP => {}
            REST_GROUP => out.push(splats.read_sh_rest()?),
            _ => out.push(buf.read_range(0, n * stride)?),
        }
    }
    Ok(out)
}

/// Uploads the logical groups of [`read_groups`] (as many Gaussians as the positions hold).
fn upload_groups(splats: &GpuSplats, data: &[Vec<f32>]) -> anyhow::Result<()> {
    let n = data[0].len() / 3;
    for (k, (buf, _)) in splats.groups().iter().enumerate() {
        match logical_group(k) {
            REST_GROUP if k > REST_GROUP => {}
            REST_GROUP => splats.write_sh_rest(&data[REST_GROUP], n)?,
            g => buf.upload(&data[g])?,
        }
    }
    Ok(())
}

/// The SH rest group's index among the logical groups.
const REST_GROUP: usize = 5;

/// Keys of two config JSONs that differ (ignoring `iterations`, which a resumed run may raise).
fn config_differences(saved: &serde_json::Value, now: &serde_json::Value) -> Vec<String> {
    fn walk(prefix: &str, a: &serde_json::Value, b: &serde_json::Value, out: &mut Vec<String>) {
        match (a, b) {
            (serde_json::Value::Object(x), serde_json::Value::Object(y)) => {
                let mut keys: Vec<&String> = x.keys().chain(y.keys()).collect();
                keys.sort();
                keys.dedup();
                for k in keys {
                    let name = if prefix.is_empty() {
                        k.clone()
                    } else {
                        format!("{prefix}.{k}")
                    };
                    if name == "iterations" {
                        continue;
                    }
                    match (x.get(k), y.get(k)) {
                        (Some(a), Some(b)) => walk(&name, a, b, out),
                        (a, b) => out.push(format!(
                            "{name} (checkpoint {}, now {})",
                            a.map_or("absent".into(), |v| v.to_string()),
                            b.map_or("absent".into(), |v| v.to_string())
                        )),
                    }
                }
            }
            _ if a != b => out.push(format!("{prefix} (checkpoint {a}, now {b})")),
            _ => {}
        }
    }
    let mut out = Vec::new();
    walk("", saved, now, &mut out);
    out
}

impl Trainer {
    /// The complete training state (waits for nothing: call between iterations).
    pub fn checkpoint(&self, scene: &Scene) -> anyhow::Result<Checkpoint> {
        self.assert_nothing_prepared("checkpoint");
        let (epoch, next) = self.views.position();
        let stats = self.density.stats();
        let n = self.state.count();
        Ok(Checkpoint {
            fingerprint: SceneFingerprint::of(scene, &self.state.shape()),
            iteration: self.iteration,
            adam_step: self.adam_step,
            schedule_epoch: epoch,
            schedule_next: next as u64,
            dropped_frames: self.dropped_frames,
            intersection_capacity: self.intersection_capacity() as u64,
            count: n as u64,
            sets: [
                read_groups(&self.state.params)?,
                read_groups(&self.state.m)?,
                read_groups(&self.state.v)?,
            ],
            stats: [
                stats.grad_accum.read_range(0, n)?,
                stats.denom.read_range(0, n)?,
                stats.max_radii.read_range(0, n)?,
                stats.abs_accum.read_range(0, n)?,
            ],
            config_json: {
                let mut c = self.config.to_json();
                // The density strategy is part of the run's settings: a resumed run must keep
                // it, with the same settings (an ADC run must not gain LPM, nor lose it).
                c["strategy"] = self.strategy().settings_json();
                // The base model's own rules' state (guided sampling's chosen cameras), so a
                // resumed run goes on where it stopped; not compared on resume.
                if !self.model_rules.is_empty() {
                    c["model_rules"] = self
                        .model_rules
                        .iter()
                        .map(|r| (r.name().to_string(), r.state_json()))
                        .collect::<serde_json::Map<_, _>>()
                        .into();
                }
                // The base model's own parameters (the full SpacetimeGaussians' decoder weights
                // and their Adam moments); not compared on resume.
                if let Some(state) = self.model_state()? {
                    c["model_state"] = state;
                }
                c.to_string()
            },
        })
    }

    /// After [`Trainer::restore`] and [`Trainer::set_strategy`]: checks that the strategy and
    /// its settings are those of the run that wrote the checkpoint at `path`. (Strategies keep
    /// no other state between steps: LPM draws its random choices per iteration, so a resumed
    /// run repeats them.)
    pub fn check_resumed_strategy(&self, path: &Path) -> anyhow::Result<()> {
        let Some(saved) = &self.resumed_strategy else {
            return Ok(());
        };
        let now = self.strategy().settings_json();
        // A strategy's settings are one object named after it ({"lpm": {...}}); null is ADC.
        let describe = |v: &serde_json::Value| match v.as_object() {
            Some(o) => o.keys().cloned().collect::<Vec<_>>().join("+"),
            None => "adc".to_string(),
        };
        let diffs = if describe(saved) != describe(&now) {
            vec![format!(
                "density strategy (checkpoint {}, now {})",
                describe(saved),
                describe(&now)
            )]
        } else {
            config_differences(saved, &now)
        };
        if diffs.is_empty() {
            return Ok(());
        }
        bad_input(
            path,
            "config.strategy",
            format!(
                "the run was trained with another density strategy or other settings: {}",
                diffs.join("; ")
            ),
            "resume with the density flags of the original run (--lpm and its options, \
             --model), or start a fresh run without --resume",
        )
    }

    /// Writes the training state to `path` atomically.
    pub fn save_checkpoint(&self, scene: &Scene, path: &Path) -> anyhow::Result<()> {
        self.checkpoint(scene)?.write(path)
    }

    /// A trainer continuing the run saved in `checkpoint` (read from `path`, named in errors)
    /// on `scene`, which must be the scene it was trained on, with the same configuration
    /// (only `iterations` may differ), of `model` (`Trainer::resume`, in `models/`, picks it
    /// from the config).
    pub fn resume_with_model(
        ctx: &Arc<GpuContext>,
        scene: &Scene,
        train_images: impl Into<TrainImages>,
        config: TrainConfig,
        path: &Path,
        model: &dyn ModelTraining,
    ) -> anyhow::Result<Self> {
        let ck = Checkpoint::read(path)?;
        Self::restore_with_model(ctx, scene, train_images, config, &ck, path, model)
    }

    /// As [`Trainer::resume_with_model`] from a checkpoint already in memory.
    pub fn restore_with_model(
        ctx: &Arc<GpuContext>,
        scene: &Scene,
        train_images: impl Into<TrainImages>,
        config: TrainConfig,
        ck: &Checkpoint,
        path: &Path,
        model: &dyn ModelTraining,
    ) -> anyhow::Result<Self> {
        // The extra groups come with the model, which the configuration comparison below checks.
        let here = SceneFingerprint::of(
            scene,
            &SplatShape {
                sh_degree: config.sh_degree,
                extra: ck.fingerprint.extra.clone(),
            },
        );
        // A checkpoint from before scenes were trained in a normalised frame, moved into it.
        let mut moved;
        let ck = if ck.fingerprint.frame.is_none() {
            moved = ck.clone();
            moved.into_frame(
                &scene.frame,
                model.fixed_third_scale(),
                model.length_groups(),
            );
            &moved
        } else {
            ck
        };
        if let Some((field, problem)) = ck.fingerprint.difference(&here) {
            return bad_input(
                path,
                field,
                format!("{problem}: the checkpoint belongs to another scene or setting"),
                format!(
                    "resume with the scene, -r and --sh-degree it was trained with, or start \
                     a fresh run without --resume (scene given: {})",
                    scene.root.display()
                ),
            );
        }
        let saved: serde_json::Value = serde_json::from_str(&ck.config_json).or_else(|e| {
            bad_input(
                path,
                "config",
                format!("not valid JSON ({e})"),
                "the checkpoint is corrupt; use an intact checkpoint.bin",
            )
        })?;
        let mut saved = saved;
        // Checked by `check_resumed_strategy` once the strategy is set. Checkpoints written
        // before strategies were plug-ins keep LPM's settings bare under "lpm".
        let saved_strategy = saved.as_object_mut().and_then(|o| {
            o.remove("strategy").or_else(|| {
                o.remove("lpm").map(|v| {
                    if v.is_null() {
                        v
                    } else {
                        serde_json::json!({ "lpm": v })
                    }
                })
            })
        });
        let rule_states = saved
            .as_object_mut()
            .and_then(|o| o.remove("model_rules"))
            .unwrap_or(serde_json::Value::Null);
        let model_state = saved.as_object_mut().and_then(|o| o.remove("model_state"));
        // A checkpoint written before the config had a model section (December 2026) keeps
        // the model's settings under their old top-level keys and names no model.
        let now = match saved.get("model") {
            Some(_) => config.to_json(),
            None => config.to_legacy_json(),
        };
        let diffs = config_differences(&saved, &now);
        if !diffs.is_empty() {
            return bad_input(
                path,
                "config",
                format!(
                    "the run was trained with other settings: {}",
                    diffs.join("; ")
                ),
                "resume with the flags of the original run (only --iterations may change), or \
                 start a fresh run without --resume",
            );
        }
        if ck.count == 0 {
            return bad_input(
                path,
                "count",
                "no Gaussians",
                "use an intact checkpoint.bin",
            );
        }
        let params = ck.params();
        params.validate().with_context(|| {
            format!(
                "{}: params: the saved Gaussians are invalid. Fix: use an intact checkpoint.bin",
                path.display()
            )
        })?;
        let mut t = Trainer::set_up(ctx, scene, train_images, &params, config, model, false)?;
        for rule in t.model_rules.iter_mut() {
            if let Some(state) = rule_states.get(rule.name()) {
                rule.restore_state(state)
                    .with_context(|| path.display().to_string())?;
            }
        }
        if let Some(state) = &model_state {
            t.passes
                .restore_model_state(state)
                .with_context(|| format!("{}: config.model_state", path.display()))?;
        }
        upload_groups(&t.state.m, &ck.sets[1])?;
        upload_groups(&t.state.v, &ck.sets[2])?;
        let stats = t.density.stats();
        upload_stat(&stats.grad_accum, &ck.stats[0])?;
        upload_stat(&stats.denom, &ck.stats[1])?;
        upload_stat(&stats.max_radii, &ck.stats[2])?;
        upload_stat(&stats.abs_accum, &ck.stats[3])?;
        t.iteration = ck.iteration;
        t.resumed_strategy = saved_strategy;
        t.adam_step = ck.adam_step;
        t.dropped_frames = ck.dropped_frames;
        t.views
            .restore(ck.schedule_epoch, ck.schedule_next as usize);
        t.reserve_intersections(ck.intersection_capacity as usize)?;
        Ok(t)
    }
}

fn upload_stat(buf: &GpuBuffer<f32>, data: &[f32]) -> anyhow::Result<()> {
    buf.upload(data)
}
