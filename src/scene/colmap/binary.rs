//! COLMAP's binary model files (little-endian, as written by `colmap model_converter`).

use std::io::Write;
use std::path::Path;

use anyhow::Context;

use super::{models, ColmapCamera, ColmapImage, ColmapPoint};
use crate::error::{write_atomic, InputError};

/// A cursor over a whole file that names the record being read when the bytes run out.
struct Cursor<'a> {
    file: &'a Path,
    bytes: &'a [u8],
    pos: usize,
    kind: &'static str,
    record: u64,
    count: u64,
}

impl<'a> Cursor<'a> {
    fn new(file: &'a Path, bytes: &'a [u8], kind: &'static str) -> Self {
        Cursor {
            file,
            bytes,
            pos: 0,
            kind,
            record: 0,
            count: 0,
        }
    }

    fn remaining(&self) -> usize {
        self.bytes.len() - self.pos
    }

    fn truncated(&self, what: &str, need: usize) -> InputError {
        let field = if self.count == 0 {
            // Still in the header: the record count itself, or one the file cannot hold.
            format!("{} {what}", self.kind)
        } else {
            format!(
                "{} record {} of {} ({what})",
                self.kind,
                self.record + 1,
                self.count
            )
        };
        InputError::new(
            self.file,
            field,
            format!(
                "truncated: {need} more bytes needed at byte offset {} but the file has {} bytes",
                self.pos,
                self.bytes.len()
            ),
            "the file is incomplete; export the model again (or use the .txt form)",
        )
    }

    fn take(&mut self, n: usize, what: &str) -> Result<&'a [u8], InputError> {
        if self.remaining() < n {
            return Err(self.truncated(what, n));
        }
        let s = &self.bytes[self.pos..self.pos + n];
        self.pos += n;
        Ok(s)
    }

    fn u8(&mut self, what: &str) -> Result<u8, InputError> {
        Ok(self.take(1, what)?[0])
    }
    fn u32(&mut self, what: &str) -> Result<u32, InputError> {
        Ok(u32::from_le_bytes(
            self.take(4, what)?.try_into().unwrap_or_default(),
        ))
    }
    fn i32(&mut self, what: &str) -> Result<i32, InputError> {
        Ok(i32::from_le_bytes(
            self.take(4, what)?.try_into().unwrap_or_default(),
        ))
    }
    fn u64(&mut self, what: &str) -> Result<u64, InputError> {
        Ok(u64::from_le_bytes(
            self.take(8, what)?.try_into().unwrap_or_default(),
        ))
    }
    fn i64(&mut self, what: &str) -> Result<i64, InputError> {
        Ok(i64::from_le_bytes(
            self.take(8, what)?.try_into().unwrap_or_default(),
        ))
    }
    fn f64(&mut self, what: &str) -> Result<f64, InputError> {
        Ok(f64::from_le_bytes(
            self.take(8, what)?.try_into().unwrap_or_default(),
        ))
    }
    fn f64s<const N: usize>(&mut self, what: &str) -> Result<[f64; N], InputError> {
        let mut out = [0.0; N];
        for v in &mut out {
            *v = self.f64(what)?;
        }
        Ok(out)
    }

    /// A count of `min_size`-byte items: refused early when the file cannot hold that many, so
    /// a corrupt count never turns into a huge allocation.
    fn count_of(&mut self, what: &str, min_size: usize) -> Result<usize, InputError> {
        let n = self.u64(what)?;
        let fits = (self.remaining() / min_size.max(1)) as u64;
        if n > fits {
            let need = n.saturating_mul(min_size as u64).min(usize::MAX as u64) as usize;
            return Err(self.truncated(&format!("{what} = {n}"), need));
        }
        Ok(n as usize)
    }

    fn start_records(&mut self, min_size: usize) -> Result<usize, InputError> {
        let n = self.count_of("record count", min_size)?;
        self.count = n as u64;
        Ok(n)
    }

    fn finish(&self) -> Result<(), InputError> {
        if self.remaining() != 0 {
            return Err(InputError::new(
                self.file,
                format!("{} count", self.kind),
                format!(
                    "{} bytes follow the last of the {} records the file announces",
                    self.remaining(),
                    self.count
                ),
                "the count or a record is corrupt; export the model again (or use the .txt form)",
            ));
        }
        Ok(())
    }
}

fn read_file(path: &Path) -> anyhow::Result<Vec<u8>> {
    std::fs::read(path)
        .with_context(|| format!("{}: cannot read (check permissions)", path.display()))
}

pub fn read_cameras(path: &Path) -> anyhow::Result<Vec<ColmapCamera>> {
    let bytes = read_file(path)?;
    let mut c = Cursor::new(path, &bytes, "camera");
    let n = c.start_records(24)?;
    let mut cameras = Vec::with_capacity(n);
    for record in 0..n {
        c.record = record as u64;
        let id = c.u32("camera_id")?;
        let model_id = c.i32("model_id")?;
        let width = c.u64("width")?;
        let height = c.u64("height")?;
        let np = models::num_params(model_id)
            .ok_or_else(|| models::unknown_model_id(path, id, model_id))?;
        let mut params = Vec::with_capacity(np);
        for _ in 0..np {
            params.push(c.f64("params")?);
        }
        cameras.push(ColmapCamera {
            id,
            model_id,
            width,
            height,
            params,
        });
    }
    c.finish()?;
    Ok(cameras)
}

pub fn read_images(path: &Path) -> anyhow::Result<Vec<ColmapImage>> {
    let bytes = read_file(path)?;
    let mut c = Cursor::new(path, &bytes, "image");
    let n = c.start_records(4 + 7 * 8 + 4 + 1 + 8)?;
    let mut images = Vec::with_capacity(n);
    for record in 0..n {
        c.record = record as u64;
        let id = c.u32("image_id")?;
        let qvec = c.f64s::<4>("qvec")?;
        let tvec = c.f64s::<3>("tvec")?;
        let camera_id = c.u32("camera_id")?;
        let name_len = c.bytes[c.pos..]
            .iter()
            .position(|&b| b == 0)
            .ok_or_else(|| c.truncated("name", c.remaining() + 1))?;
        let name_bytes = c.take(name_len + 1, "name")?;
        let name = std::str::from_utf8(&name_bytes[..name_len])
            .map_err(|_| {
                InputError::new(
                    path,
                    format!("image record {} of {n} (image_id {id}) name", record + 1),
                    "is not valid UTF-8",
                    "rename the image to a UTF-8 name in the model and on disk",
                )
            })?
            .to_string();
        let np = c.count_of("num_points2D", 24)?;
        let mut points2d = Vec::with_capacity(np);
        let mut point3d_ids = Vec::with_capacity(np);
        for _ in 0..np {
            let x = c.f64("points2D x")?;
            let y = c.f64("points2D y")?;
            point3d_ids.push(c.i64("points2D point3D_id")?);
            points2d.push([x, y]);
        }
        images.push(ColmapImage {
            id,
            qvec,
            tvec,
            camera_id,
            name,
            points2d,
            point3d_ids,
        });
    }
    c.finish()?;
    Ok(images)
}

pub fn read_points(path: &Path) -> anyhow::Result<Vec<ColmapPoint>> {
    let bytes = read_file(path)?;
    let mut c = Cursor::new(path, &bytes, "point3D");
    let n = c.start_records(8 + 24 + 3 + 8 + 8)?;
    let mut points = Vec::with_capacity(n);
    for record in 0..n {
        c.record = record as u64;
        let id = c.u64("point3D_id")?;
        let xyz = c.f64s::<3>("xyz")?;
        let rgb = [c.u8("rgb")?, c.u8("rgb")?, c.u8("rgb")?];
        let error = c.f64("error")?;
        let len = c.count_of("track_length", 8)?;
        let mut track = Vec::with_capacity(len);
        for _ in 0..len {
            let image_id = c.u32("track image_id")?;
            let idx = c.u32("track point2D_idx")?;
            track.push((image_id, idx));
        }
        points.push(ColmapPoint {
            id,
            xyz,
            rgb,
            error,
            track,
        });
    }
    c.finish()?;
    Ok(points)
}

fn put_f64s(buf: &mut Vec<u8>, vs: &[f64]) {
    for v in vs {
        buf.extend_from_slice(&v.to_le_bytes());
    }
}

fn save(path: &Path, buf: &[u8]) -> anyhow::Result<()> {
    write_atomic(path, |f| {
        f.write_all(buf)
            .with_context(|| format!("{}: write failed (disk full?)", path.display()))
    })
}

pub fn write_cameras(path: &Path, cameras: &[ColmapCamera]) -> anyhow::Result<()> {
    let mut buf = Vec::new();
    buf.extend_from_slice(&(cameras.len() as u64).to_le_bytes());
    for cam in cameras {
        buf.extend_from_slice(&cam.id.to_le_bytes());
        buf.extend_from_slice(&cam.model_id.to_le_bytes());
        buf.extend_from_slice(&cam.width.to_le_bytes());
        buf.extend_from_slice(&cam.height.to_le_bytes());
        put_f64s(&mut buf, &cam.params);
    }
    save(path, &buf)
}

pub fn write_images(path: &Path, images: &[ColmapImage]) -> anyhow::Result<()> {
    let mut buf = Vec::new();
    buf.extend_from_slice(&(images.len() as u64).to_le_bytes());
    for im in images {
        anyhow::ensure!(
            im.points2d.len() == im.point3d_ids.len(),
            "image {}: {} keypoints but {} point3D ids",
            im.id,
            im.points2d.len(),
            im.point3d_ids.len()
        );
        buf.extend_from_slice(&im.id.to_le_bytes());
        put_f64s(&mut buf, &im.qvec);
        put_f64s(&mut buf, &im.tvec);
        buf.extend_from_slice(&im.camera_id.to_le_bytes());
        buf.extend_from_slice(im.name.as_bytes());
        buf.push(0);
        buf.extend_from_slice(&(im.points2d.len() as u64).to_le_bytes());
        for (xy, id) in im.points2d.iter().zip(&im.point3d_ids) {
            put_f64s(&mut buf, xy);
            buf.extend_from_slice(&id.to_le_bytes());
        }
    }
    save(path, &buf)
}

pub fn write_points(path: &Path, points: &[ColmapPoint]) -> anyhow::Result<()> {
    let mut buf = Vec::new();
    buf.extend_from_slice(&(points.len() as u64).to_le_bytes());
    for p in points {
        buf.extend_from_slice(&p.id.to_le_bytes());
        put_f64s(&mut buf, &p.xyz);
        buf.extend_from_slice(&p.rgb);
        buf.extend_from_slice(&p.error.to_le_bytes());
        buf.extend_from_slice(&(p.track.len() as u64).to_le_bytes());
        for (image_id, idx) in &p.track {
            buf.extend_from_slice(&image_id.to_le_bytes());
            buf.extend_from_slice(&idx.to_le_bytes());
        }
    }
    save(path, &buf)
}
