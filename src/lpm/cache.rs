//! The on-disk cache of correspondences.
//!
//! Format (little endian):
//! ```text
//! magic        8 bytes  "LPMCORR\0"
//! version      u32      CACHE_VERSION
//! scene_hash   u64      FNV-1a of view names, cameras, poses, keypoints and tracks
//! settings     u64      FNV-1a of the match settings
//! pairs        u32
//! per pair:    a u32, b u32, n u32, then n × (xa, ya, xb, yb) f32
//! checksum     u64      FNV-1a of every byte before it
//! ```
//! A file whose hashes differ from the current scene/settings is *stale*; one that fails to parse
//! or whose checksum does not match is *corrupt*. Both are rebuilt by the caller.

use super::correspondences::PairMatches;
use crate::scene::Scene;
use std::io::Write;
use std::path::Path;

pub const CACHE_MAGIC: &[u8; 8] = b"LPMCORR\0";
/// Bump when the format or anything that changes the matches without changing the settings
/// (detector, BRIEF pattern) changes.
pub const CACHE_VERSION: u32 = 1;

/// 64-bit FNV-1a, for cache keys and the checksum (not for security).
#[derive(Debug, Clone, Copy)]
pub struct Fnv(u64);

impl Default for Fnv {
    fn default() -> Self {
        Fnv(0xcbf2_9ce4_8422_2325)
    }
}

impl Fnv {
    pub fn bytes(&mut self, b: &[u8]) -> &mut Self {
        for &x in b {
            self.0 ^= x as u64;
            self.0 = self.0.wrapping_mul(0x0100_0000_01b3);
        }
        self
    }
    pub fn u64(&mut self, v: u64) -> &mut Self {
        self.bytes(&v.to_le_bytes())
    }
    pub fn f64(&mut self, v: f64) -> &mut Self {
        self.u64(v.to_bits())
    }
    pub fn str(&mut self, s: &str) -> &mut Self {
        self.u64(s.len() as u64).bytes(s.as_bytes())
    }
    pub fn finish(&self) -> u64 {
        self.0
    }
}

/// Hash of everything in the scene the correspondences depend on: view names, image paths,
/// cameras, poses, the train list, and (for track matches) keypoints and tracks. Pixel contents
/// are not hashed: replacing an image file under the same name and pose needs `match --rematch` (or
/// deleting the cache).
pub fn scene_hash(scene: &Scene) -> u64 {
    let mut h = Fnv::default();
    h.u64(scene.views.len() as u64);
    for v in &scene.views {
        h.str(&v.name).str(&v.image_path.to_string_lossy());
        let c = &v.camera;
        h.f64(c.fx)
            .f64(c.fy)
            .f64(c.cx)
            .f64(c.cy)
            .u64(c.width as u64)
            .u64(c.height as u64);
        for row in v.pose.rotation {
            for x in row {
                h.f64(x);
            }
        }
        for x in v.pose.translation {
            h.f64(x);
        }
        match &v.keypoints {
            None => {
                h.u64(u64::MAX);
            }
            Some(k) => {
                h.u64(k.xy.len() as u64);
                for (p, id) in k.xy.iter().zip(&k.point3d) {
                    h.f64(p[0]).f64(p[1]).u64(*id as u64);
                }
            }
        }
    }
    h.u64(scene.train.len() as u64);
    for &t in &scene.train {
        h.u64(t as u64);
    }
    match &scene.points {
        None => {
            h.u64(u64::MAX);
        }
        Some(p) => {
            h.u64(p.tracks.len() as u64);
            for t in &p.tracks {
                h.u64(t.len() as u64);
                for &(v, k) in t {
                    h.u64(((v as u64) << 32) | k as u64);
                }
            }
        }
    }
    h.finish()
}

/// Why a cache file was not used.
#[derive(Debug, Clone, PartialEq)]
pub enum CacheMiss {
    Missing,
    /// Written for another scene or other settings (or an older version).
    Stale(String),
    /// Unreadable: the message says where it broke.
    Corrupt(String),
}

/// Writes the cache atomically.
pub fn write_cache(
    path: &Path,
    scene_hash: u64,
    settings_hash: u64,
    pairs: &[PairMatches],
) -> anyhow::Result<()> {
    let mut buf = Vec::new();
    buf.extend_from_slice(CACHE_MAGIC);
    buf.extend_from_slice(&CACHE_VERSION.to_le_bytes());
    buf.extend_from_slice(&scene_hash.to_le_bytes());
    buf.extend_from_slice(&settings_hash.to_le_bytes());
    buf.extend_from_slice(&(pairs.len() as u32).to_le_bytes());
    for p in pairs {
        anyhow::ensure!(
            p.xy_a.len() == p.xy_b.len(),
            "pair ({}, {}): unequal match lists",
            p.a,
            p.b
        );
        for v in [p.a, p.b, p.xy_a.len() as u32] {
            buf.extend_from_slice(&v.to_le_bytes());
        }
        for (xa, xb) in p.xy_a.iter().zip(&p.xy_b) {
            for v in [xa[0], xa[1], xb[0], xb[1]] {
                buf.extend_from_slice(&v.to_le_bytes());
            }
        }
    }
    let sum = Fnv::default().bytes(&buf).finish();
    buf.extend_from_slice(&sum.to_le_bytes());
    crate::error::write_atomic(path, |f| {
        f.write_all(&buf)?;
        Ok(())
    })
}

struct Reader<'a> {
    b: &'a [u8],
    at: usize,
}

impl Reader<'_> {
    fn take(&mut self, n: usize, what: &str) -> Result<&[u8], String> {
        let end = self.at.checked_add(n).filter(|&e| e <= self.b.len());
        let Some(end) = end else {
            return Err(format!(
                "truncated at byte {} while reading {what}",
                self.at
            ));
        };
        let s = &self.b[self.at..end];
        self.at = end;
        Ok(s)
    }
    fn u32(&mut self, what: &str) -> Result<u32, String> {
        Ok(u32::from_le_bytes(
            self.take(4, what)?.try_into().unwrap_or_default(),
        ))
    }
    fn u64(&mut self, what: &str) -> Result<u64, String> {
        Ok(u64::from_le_bytes(
            self.take(8, what)?.try_into().unwrap_or_default(),
        ))
    }
    fn f32(&mut self, what: &str) -> Result<f32, String> {
        Ok(f32::from_le_bytes(
            self.take(4, what)?.try_into().unwrap_or_default(),
        ))
    }
}

/// Reads the cache; `Err` says why it cannot be used. `views` bounds the view indices.
pub fn read_cache(
    path: &Path,
    scene_hash: u64,
    settings_hash: u64,
    views: usize,
) -> Result<Vec<PairMatches>, CacheMiss> {
    let bytes = match std::fs::read(path) {
        Ok(b) => b,
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => return Err(CacheMiss::Missing),
        Err(e) => return Err(CacheMiss::Corrupt(format!("cannot read: {e}"))),
    };
    let corrupt = CacheMiss::Corrupt;
    if bytes.len() < 8 || &bytes[..8] != CACHE_MAGIC {
        return Err(corrupt(
            "not an lpmsplat correspondence cache (bad magic)".into(),
        ));
    }
    let mut r = Reader { b: &bytes, at: 8 };
    let version = r.u32("version").map_err(corrupt)?;
    if version != CACHE_VERSION {
        return Err(CacheMiss::Stale(format!(
            "version {version}, this build writes {CACHE_VERSION}"
        )));
    }
    if bytes.len() < 8 + 4 + 8 + 8 + 4 + 8 {
        return Err(corrupt("truncated header".into()));
    }
    let body = bytes.len() - 8;
    let stored_sum = u64::from_le_bytes(bytes[body..].try_into().unwrap_or_default());
    if Fnv::default().bytes(&bytes[..body]).finish() != stored_sum {
        return Err(corrupt(
            "checksum mismatch (file damaged or truncated)".into(),
        ));
    }
    // From here on the reader stops at the checksum: a pair whose fields run into it is
    // truncated, and `body - r.at` below cannot wrap around (it did, and a match count of
    // 2^31 then passed the size check and was allocated).
    r.b = &bytes[..body];
    let sh = r.u64("scene hash").map_err(corrupt)?;
    let st = r.u64("settings hash").map_err(corrupt)?;
    if sh != scene_hash {
        return Err(CacheMiss::Stale(
            "the scene changed (views, cameras, poses or tracks)".into(),
        ));
    }
    if st != settings_hash {
        return Err(CacheMiss::Stale("the match settings changed".into()));
    }
    let n = r.u32("pair count").map_err(corrupt)?;
    let mut pairs = Vec::new();
    for k in 0..n {
        let a = r.u32("pair view a").map_err(corrupt)?;
        let b = r.u32("pair view b").map_err(corrupt)?;
        let m = r.u32("match count").map_err(corrupt)? as usize;
        if a as usize >= views || b as usize >= views || a >= b {
            return Err(corrupt(format!(
                "pair {k}: views ({a}, {b}) invalid for a scene of {views} views"
            )));
        }
        if m.saturating_mul(16) > body - r.at {
            return Err(corrupt(format!(
                "pair {k}: {m} matches do not fit in the file"
            )));
        }
        let mut p = PairMatches {
            a,
            b,
            xy_a: Vec::with_capacity(m),
            xy_b: Vec::with_capacity(m),
        };
        for _ in 0..m {
            let v = [
                r.f32("match").map_err(corrupt)?,
                r.f32("match").map_err(corrupt)?,
                r.f32("match").map_err(corrupt)?,
                r.f32("match").map_err(corrupt)?,
            ];
            if !v.iter().all(|x| x.is_finite()) {
                return Err(corrupt(format!("pair {k}: non-finite coordinate")));
            }
            p.xy_a.push([v[0], v[1]]);
            p.xy_b.push([v[2], v[3]]);
        }
        pairs.push(p);
    }
    if r.at != body {
        return Err(corrupt(format!(
            "{} trailing bytes before the checksum",
            body - r.at
        )));
    }
    Ok(pairs)
}
