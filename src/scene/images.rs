//! Image loading (parallel), undistortion, resizing, compositing and PNG output.
//!
//! Pixel values are the values stored in the file scaled to [0, 1] — sRGB-encoded, not
//! linearised — as every 3DGS implementation trains and evaluates on them. Colour is kept
//! straight (not premultiplied by alpha); resizing premultiplies internally so that a resized
//! image composited on a background equals the composite resized.

use super::{undistort, Scene, View};
use crate::error::{bad_input, write_atomic};
use anyhow::Context;
use rayon::prelude::*;
use std::path::Path;

/// An RGB(A) image with f32 channels in [0, 1], row-major, pixel (x, y) at `(y * width + x)`.
#[derive(Debug, Clone, PartialEq)]
pub struct Image {
    pub width: u32,
    pub height: u32,
    /// 3 floats per pixel, straight (not premultiplied) colour.
    pub rgb: Vec<f32>,
    /// 1 float per pixel when the source had alpha.
    pub alpha: Option<Vec<f32>>,
}

impl Image {
    /// A black, opaque (no alpha channel) image.
    pub fn new(width: u32, height: u32) -> Image {
        Image {
            width,
            height,
            rgb: vec![0.0; 3 * width as usize * height as usize],
            alpha: None,
        }
    }

    /// Number of pixels.
    pub fn len(&self) -> usize {
        self.width as usize * self.height as usize
    }

    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }

    /// The colour of pixel (x, y).
    pub fn pixel(&self, x: u32, y: u32) -> [f32; 3] {
        let i = 3 * (y as usize * self.width as usize + x as usize);
        [self.rgb[i], self.rgb[i + 1], self.rgb[i + 2]]
    }

    /// The alpha of pixel (x, y): 1 when the image has no alpha channel.
    pub fn alpha_at(&self, x: u32, y: u32) -> f32 {
        self.alpha
            .as_ref()
            .map_or(1.0, |a| a[y as usize * self.width as usize + x as usize])
    }

    /// Sets the colour of pixel (x, y).
    pub fn set_pixel(&mut self, x: u32, y: u32, c: [f32; 3]) {
        let i = 3 * (y as usize * self.width as usize + x as usize);
        self.rgb[i..i + 3].copy_from_slice(&c);
    }
}

/// Decodes a PNG or JPEG (the format is guessed from the content) into [0, 1] floats, keeping
/// alpha when the file has it.
pub fn decode_image(path: &Path) -> anyhow::Result<Image> {
    let bytes = std::fs::read(path).map_err(|e| {
        crate::error::InputError::new(
            path,
            "image file",
            format!("cannot be read: {e}"),
            "check that the file exists and is readable",
        )
    })?;
    check_complete(path, &bytes)?;
    let decoded = image::ImageReader::new(std::io::Cursor::new(&bytes))
        .with_guessed_format()
        .map_err(anyhow::Error::from)
        .and_then(|r| r.decode().map_err(anyhow::Error::from));
    let img = match decoded {
        Ok(img) => img,
        Err(e) => {
            return bad_input(
                path,
                "image data",
                format!("cannot be decoded: {e}"),
                "replace it with a valid PNG or JPEG (is the file truncated?)",
            )
        }
    };
    let (width, height) = (img.width(), img.height());
    if img.color().has_alpha() {
        let rgba = img.to_rgba32f().into_raw();
        let mut rgb = Vec::with_capacity(3 * rgba.len() / 4);
        let mut alpha = Vec::with_capacity(rgba.len() / 4);
        for px in rgba.chunks_exact(4) {
            rgb.extend_from_slice(&px[..3]);
            alpha.push(px[3]);
        }
        Ok(Image {
            width,
            height,
            rgb,
            alpha: Some(alpha),
        })
    } else {
        Ok(Image {
            width,
            height,
            rgb: img.to_rgb32f().into_raw(),
            alpha: None,
        })
    }
}

/// Refuses an image file that ends before its data does (an interrupted copy or download),
/// which decoders fill in silently: a JPEG must hold an end-of-image marker (`FF D9`) after
/// its last start-of-scan (`FF DA`; inside the entropy-coded data a `FF` byte is always
/// followed by `00` or a restart marker, so neither pair occurs there, and an EXIF
/// thumbnail's own end marker comes before the main image's scan), and a PNG must end its
/// chunks with `IEND` (whose CRC is fixed). Other formats are left to their decoder. Bytes
/// after the end marker (a camera's trailer, a second picture) are accepted.
pub fn check_complete(path: &Path, bytes: &[u8]) -> anyhow::Result<()> {
    let last = |pair: [u8; 2]| bytes.windows(2).rposition(|w| w == pair);
    if bytes.starts_with(&[0xFF, 0xD8]) {
        let sos = last([0xFF, 0xDA]);
        let eoi = last([0xFF, 0xD9]);
        let complete = match (sos, eoi) {
            (Some(s), Some(e)) => e > s,
            _ => false,
        };
        if !complete {
            return bad_input(
                path,
                "JPEG data",
                format!(
                    "ends after {} bytes without the end-of-image marker (FF D9): the file is \
                     truncated",
                    bytes.len()
                ),
                "copy the image again from its source",
            );
        }
    } else if bytes.starts_with(b"\x89PNG\r\n\x1a\n") {
        const IEND: [u8; 12] = [0, 0, 0, 0, b'I', b'E', b'N', b'D', 0xAE, 0x42, 0x60, 0x82];
        if !bytes.windows(12).rev().take(1 << 16).any(|w| w == IEND) {
            return bad_input(
                path,
                "PNG data",
                format!(
                    "ends after {} bytes without its IEND chunk: the file is truncated",
                    bytes.len()
                ),
                "copy the image again from its source",
            );
        }
    }
    Ok(())
}

/// Reads `path` and checks it with [`check_complete`] (without decoding it).
pub fn check_file_complete(path: &Path) -> anyhow::Result<()> {
    let bytes = std::fs::read(path).map_err(|e| {
        crate::error::InputError::new(
            path,
            "image file",
            format!("cannot be read: {e}"),
            "check that the file exists and is readable",
        )
    })?;
    check_complete(path, &bytes)
}

/// The training image of one view: decoded, checked against the size the scene declares,
/// undistorted when the lens model is distorted, resized to the view's camera.
pub fn load_view_image(view: &View) -> anyhow::Result<Image> {
    let img = decode_image(&view.image_path)?;
    if (img.width, img.height) != (view.source_width, view.source_height) {
        return bad_input(
            &view.image_path,
            "image size",
            format!(
                "is {}x{} but the scene's camera for view {} says {}x{}",
                img.width, img.height, view.name, view.source_width, view.source_height
            ),
            "use the images the scene was reconstructed from, or fix the camera's size",
        );
    }
    let img = if view.source_model.is_distorted() {
        undistort::undistort_image(&view.source_model, &img)
    } else {
        img
    };
    Ok(resize_area(&img, view.camera.width, view.camera.height))
}

/// Loads the images of `scene.views[i]` for each `i` in `indices`, in parallel, in that order.
pub fn load_images(scene: &Scene, indices: &[usize]) -> anyhow::Result<Vec<Image>> {
    if let Some(&bad) = indices.iter().find(|&&i| i >= scene.views.len()) {
        anyhow::bail!(
            "view index {bad} is out of range: the scene has {} views",
            scene.views.len()
        );
    }
    indices
        .par_iter()
        .map(|&i| {
            load_view_image(&scene.views[i])
                .with_context(|| format!("loading view {}", scene.views[i].name))
        })
        .collect()
}

/// Resizes by area averaging: each output pixel is the mean of the source area it covers
/// (fractional coverage weighted), which for an integer factor is the exact box filter. Colour is
/// averaged premultiplied by alpha, then divided back.
pub fn resize_area(src: &Image, width: u32, height: u32) -> Image {
    if (width, height) == (src.width, src.height) {
        return src.clone();
    }
    if src.is_empty() || width == 0 || height == 0 {
        let mut out = Image::new(width, height);
        out.alpha = src.alpha.as_ref().map(|_| vec![0.0; out.len()]);
        return out;
    }
    let channels = if src.alpha.is_some() { 4 } else { 3 };
    let (sw, sh) = (src.width as usize, src.height as usize);
    let (dw, dh) = (width as usize, height as usize);

    let tx = area_taps(sw, dw);
    let ty = area_taps(sh, dh);
    // Horizontal pass, premultiplying as it reads: sh rows of dw pixels, interleaved, in f64.
    let mut mid = vec![0.0f64; channels * dw * sh];
    mid.par_chunks_mut(channels * dw)
        .enumerate()
        .for_each(|(y, row)| {
            for (x, (start, weights)) in tx.iter().enumerate() {
                let out = &mut row[channels * x..channels * (x + 1)];
                for (k, &w) in weights.iter().enumerate() {
                    let p = y * sw + start + k;
                    let a = src.alpha.as_ref().map_or(1.0, |a| a[p] as f64);
                    for (o, &c) in out.iter_mut().zip(&src.rgb[3 * p..3 * p + 3]) {
                        *o += w * a * c as f64;
                    }
                    if channels == 4 {
                        out[3] += w * a;
                    }
                }
            }
        });
    // Vertical pass.
    let mut dst = vec![0.0f64; channels * dw * dh];
    dst.par_chunks_mut(channels * dw)
        .enumerate()
        .for_each(|(y, row)| {
            let (start, weights) = &ty[y];
            for (k, &w) in weights.iter().enumerate() {
                let m = &mid[channels * dw * (start + k)..channels * dw * (start + k + 1)];
                for (o, s) in row.iter_mut().zip(m) {
                    *o += w * s;
                }
            }
        });

    let mut out = Image::new(width, height);
    let mut alpha = (channels == 4).then(|| vec![0.0f32; dw * dh]);
    for (p, px) in dst.chunks_exact(channels).enumerate() {
        let a = if channels == 4 { px[3] } else { 1.0 };
        let inv = if a > 0.0 { 1.0 / a } else { 0.0 };
        for (d, &s) in out.rgb[3 * p..3 * p + 3].iter_mut().zip(px) {
            *d = (s * inv).clamp(0.0, 1.0) as f32;
        }
        if let Some(al) = alpha.as_mut() {
            al[p] = a.clamp(0.0, 1.0) as f32;
        }
    }
    out.alpha = alpha;
    out
}

/// Per output index: the first source index and the weights of the source pixels from there,
/// summing to 1. Output pixel i covers source [i·s, (i+1)·s) with s = src / dst.
fn area_taps(src: usize, dst: usize) -> Vec<(usize, Vec<f64>)> {
    let scale = src as f64 / dst as f64;
    (0..dst)
        .map(|i| {
            let lo = i as f64 * scale;
            let hi = ((i + 1) as f64 * scale).min(src as f64);
            let first = (lo.floor() as usize).min(src - 1);
            let last = (hi.ceil() as usize).clamp(first + 1, src);
            let mut weights: Vec<f64> = (first..last)
                .map(|j| (hi.min(j as f64 + 1.0) - lo.max(j as f64)).max(0.0))
                .collect();
            // lo < hi, so the first tap has positive coverage and the sum is positive.
            let sum: f64 = weights.iter().sum();
            weights.iter_mut().for_each(|w| *w /= sum);
            (first, weights)
        })
        .collect()
}

/// `rgb·a + bg·(1 − a)` per pixel: the image over a solid background, without alpha. An image
/// without alpha is returned unchanged.
pub fn composite_on_background(img: &Image, bg: [f32; 3]) -> Image {
    let Some(alpha) = &img.alpha else {
        return img.clone();
    };
    let mut rgb = img.rgb.clone();
    for (px, &a) in rgb.chunks_exact_mut(3).zip(alpha) {
        for c in 0..3 {
            px[c] = px[c] * a + bg[c] * (1.0 - a);
        }
    }
    Image {
        width: img.width,
        height: img.height,
        rgb,
        alpha: None,
    }
}

/// Writes an 8-bit PNG (RGBA when the image has alpha): values are clamped to [0, 1] and rounded
/// to the nearest of 256 levels, stored as they are (no gamma conversion). Atomic: a failure
/// leaves any existing file untouched.
pub fn save_png(path: &Path, img: &Image) -> anyhow::Result<()> {
    use image::ImageEncoder;
    let n = img.len();
    if img.rgb.len() != 3 * n || img.alpha.as_ref().is_some_and(|a| a.len() != n) {
        anyhow::bail!(
            "{}: cannot save a {}x{} image whose buffers hold {} colour and {:?} alpha values",
            path.display(),
            img.width,
            img.height,
            img.rgb.len(),
            img.alpha.as_ref().map(Vec::len)
        );
    }
    let to_u8 = |v: f32| (v.clamp(0.0, 1.0) * 255.0).round() as u8;
    let (bytes, color) = match &img.alpha {
        Some(alpha) => {
            let mut b = Vec::with_capacity(4 * n);
            for (px, &a) in img.rgb.chunks_exact(3).zip(alpha) {
                b.extend(px.iter().map(|&v| to_u8(v)));
                b.push(to_u8(a));
            }
            (b, image::ExtendedColorType::Rgba8)
        }
        None => (
            img.rgb.iter().map(|&v| to_u8(v)).collect(),
            image::ExtendedColorType::Rgb8,
        ),
    };
    let mut encoded = Vec::new();
    image::codecs::png::PngEncoder::new(&mut encoded)
        .write_image(&bytes, img.width, img.height, color)
        .with_context(|| {
            format!(
                "{}: cannot encode a {}x{} PNG",
                path.display(),
                img.width,
                img.height
            )
        })?;
    write_atomic(path, |f| {
        use std::io::Write;
        f.write_all(&encoded)
            .with_context(|| format!("{}: write failed (disk full?)", path.display()))
    })
}

/// Writes a PFM (portable float map): `channels` 1 ("Pf") or 3 ("PF") float32 values per pixel,
/// row-major top to bottom in `data`; stored little-endian bottom row first, as the format
/// says. Atomic like [`save_png`].
pub fn save_pfm(
    path: &Path,
    width: u32,
    height: u32,
    channels: usize,
    data: &[f32],
) -> anyhow::Result<()> {
    anyhow::ensure!(
        (channels == 1 || channels == 3)
            && data.len() == width as usize * height as usize * channels,
        "{}: a PFM needs 1 or 3 channels and {}×{}×channels values, not {} with {channels}",
        path.display(),
        width,
        height,
        data.len()
    );
    let mut bytes = format!(
        "{}\n{width} {height}\n-1.0\n",
        if channels == 3 { "PF" } else { "Pf" }
    )
    .into_bytes();
    let row = width as usize * channels;
    for y in (0..height as usize).rev() {
        for v in &data[y * row..(y + 1) * row] {
            bytes.extend_from_slice(&v.to_le_bytes());
        }
    }
    write_atomic(path, |f| {
        use std::io::Write;
        Ok(f.write_all(&bytes)?)
    })
    .with_context(|| format!("{}: writing the PFM failed", path.display()))
}

/// Reads a PFM written by [`save_pfm`] (either byte order): `(width, height, channels, data)`
/// with rows top to bottom.
pub fn read_pfm(path: &Path) -> anyhow::Result<(u32, u32, usize, Vec<f32>)> {
    let bytes = std::fs::read(path).with_context(|| format!("{}: cannot read", path.display()))?;
    let bad = || {
        anyhow::anyhow!(
            "{}: not a PFM file (header PF/Pf, size, scale)",
            path.display()
        )
    };
    let mut fields = Vec::new();
    let mut at = 0;
    while fields.len() < 4 {
        while at < bytes.len() && bytes[at].is_ascii_whitespace() {
            at += 1;
        }
        let start = at;
        while at < bytes.len() && !bytes[at].is_ascii_whitespace() {
            at += 1;
        }
        anyhow::ensure!(at > start, bad());
        fields.push(
            std::str::from_utf8(&bytes[start..at])
                .map_err(|_| bad())?
                .to_string(),
        );
    }
    at += 1;
    let channels = match fields[0].as_str() {
        "PF" => 3,
        "Pf" => 1,
        _ => return Err(bad()),
    };
    let w: u32 = fields[1].parse().map_err(|_| bad())?;
    let h: u32 = fields[2].parse().map_err(|_| bad())?;
    let scale: f32 = fields[3].parse().map_err(|_| bad())?;
    let n = w as usize * h as usize * channels;
    anyhow::ensure!(
        bytes.len() >= at + 4 * n,
        "{}: truncated PFM",
        path.display()
    );
    let row = w as usize * channels;
    let mut data = vec![0.0f32; n];
    for (k, chunk) in bytes[at..at + 4 * n].chunks_exact(4).enumerate() {
        let b = [chunk[0], chunk[1], chunk[2], chunk[3]];
        let v = if scale < 0.0 {
            f32::from_le_bytes(b)
        } else {
            f32::from_be_bytes(b)
        };
        let (y, x) = (k / row, k % row);
        data[(h as usize - 1 - y) * row + x] = v;
    }
    Ok((w, h, channels, data))
}
