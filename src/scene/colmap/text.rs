//! COLMAP's text model files: one record per line (two per image), `#` comments.

use std::fmt::Write as _;
use std::io::Write as _;
use std::path::Path;
use std::str::FromStr;

use anyhow::Context;

use super::{models, ColmapCamera, ColmapImage, ColmapPoint};
use crate::error::{write_atomic, InputError};

fn read_text(path: &Path) -> anyhow::Result<String> {
    let bytes = std::fs::read(path)
        .with_context(|| format!("{}: cannot read (check permissions)", path.display()))?;
    String::from_utf8(bytes).map_err(|e| {
        InputError::new(
            path,
            format!("byte {}", e.utf8_error().valid_up_to()),
            "is not UTF-8 text",
            "is this a binary file named .txt? Export the model again with `colmap model_converter --output_type TXT`",
        )
        .into()
    })
}

/// Data lines with their 1-based line numbers (comments dropped, blank lines kept: an image
/// without keypoints has a blank second line).
fn data_lines(text: &str) -> impl Iterator<Item = (usize, &str)> {
    text.lines()
        .enumerate()
        .map(|(i, l)| (i + 1, l.trim()))
        .filter(|(_, l)| !l.starts_with('#'))
}

/// Tokens of one line, parsed with errors that name the line and the field.
struct Fields<'a> {
    file: &'a Path,
    line: usize,
    tokens: std::str::SplitWhitespace<'a>,
}

impl<'a> Fields<'a> {
    fn new(file: &'a Path, line: usize, text: &'a str) -> Self {
        Fields {
            file,
            line,
            tokens: text.split_whitespace(),
        }
    }

    fn error(&self, field: &str, problem: String) -> InputError {
        InputError::new(
            self.file,
            format!("line {}: {field}", self.line),
            problem,
            "fix the line (see the column list in the file's header comment) or export the model again",
        )
    }

    fn next<T: FromStr>(&mut self, field: &str) -> Result<T, InputError> {
        match self.tokens.next() {
            None => Err(self.error(field, "missing (the line ends early)".into())),
            Some(tok) => self.parse(tok, field),
        }
    }

    fn parse<T: FromStr>(&self, tok: &str, field: &str) -> Result<T, InputError> {
        tok.parse().map_err(|_| {
            self.error(
                field,
                format!("'{tok}' is not a valid {}", std::any::type_name::<T>()),
            )
        })
    }

    fn array<T: FromStr + Default + Copy, const N: usize>(
        &mut self,
        field: &str,
    ) -> Result<[T; N], InputError> {
        let mut out = [T::default(); N];
        for v in &mut out {
            *v = self.next(field)?;
        }
        Ok(out)
    }

    fn rest(&mut self) -> Vec<&'a str> {
        self.tokens.by_ref().collect()
    }

    fn end(&mut self) -> Result<(), InputError> {
        match self.tokens.next() {
            Some(tok) => Err(self.error("end of line", format!("unexpected extra value '{tok}'"))),
            None => Ok(()),
        }
    }
}

pub fn read_cameras(path: &Path) -> anyhow::Result<Vec<ColmapCamera>> {
    let text = read_text(path)?;
    let mut cameras = Vec::new();
    for (line, l) in data_lines(&text).filter(|(_, l)| !l.is_empty()) {
        let mut f = Fields::new(path, line, l);
        let id: u32 = f.next("CAMERA_ID")?;
        let name: String = f.next("MODEL")?;
        let model_id = models::id_of(&name)
            .ok_or_else(|| models::unknown_model_name(path, line, &id.to_string(), &name))?;
        let width = f.next("WIDTH")?;
        let height = f.next("HEIGHT")?;
        let expected = models::num_params(model_id).unwrap_or(0);
        let mut params = Vec::with_capacity(expected);
        for k in 0..expected {
            params.push(f.next(&format!("PARAMS[{k}] of {name}"))?);
        }
        f.end().map_err(|_| {
            f.error(
                "PARAMS",
                format!("model {name} takes {expected} parameters, the line has more"),
            )
        })?;
        cameras.push(ColmapCamera {
            id,
            model_id,
            width,
            height,
            params,
        });
    }
    Ok(cameras)
}

pub fn read_images(path: &Path) -> anyhow::Result<Vec<ColmapImage>> {
    let text = read_text(path)?;
    let mut images = Vec::new();
    let mut lines = data_lines(&text);
    while let Some((line, l)) = lines.next() {
        if l.is_empty() {
            continue;
        }
        let mut f = Fields::new(path, line, l);
        let id: u32 = f.next("IMAGE_ID")?;
        let qvec: [f64; 4] = f.array("QW QX QY QZ")?;
        let tvec: [f64; 3] = f.array("TX TY TZ")?;
        let camera_id: u32 = f.next("CAMERA_ID")?;
        let name = f.rest().join(" ");
        if name.is_empty() {
            return Err(f
                .error("NAME", "missing (the line ends early)".into())
                .into());
        }
        // The keypoint line; a file that ends right after the pose line has no keypoints.
        let (kline, kl) = lines.next().unwrap_or((line + 1, ""));
        let tokens: Vec<&str> = kl.split_whitespace().collect();
        if !tokens.len().is_multiple_of(3) {
            return Err(InputError::new(
                path,
                format!("line {kline}: POINTS2D of image {id}"),
                format!("has {} values, not a multiple of 3 (X, Y, POINT3D_ID)", tokens.len()),
                "every image takes two lines: the pose line, then the keypoint line (possibly empty)",
            )
            .into());
        }
        let mut f = Fields::new(path, kline, kl);
        let n = tokens.len() / 3;
        let mut points2d = Vec::with_capacity(n);
        let mut point3d_ids = Vec::with_capacity(n);
        for k in 0..n {
            points2d.push(f.array(&format!("POINTS2D[{k}] X Y"))?);
            point3d_ids.push(f.next(&format!("POINTS2D[{k}] POINT3D_ID"))?);
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
    Ok(images)
}

pub fn read_points(path: &Path) -> anyhow::Result<Vec<ColmapPoint>> {
    let text = read_text(path)?;
    let mut points = Vec::new();
    for (line, l) in data_lines(&text).filter(|(_, l)| !l.is_empty()) {
        let mut f = Fields::new(path, line, l);
        let id = f.next("POINT3D_ID")?;
        let xyz = f.array("X Y Z")?;
        let rgb = f.array("R G B")?;
        let error = f.next("ERROR")?;
        let rest = f.rest();
        if !rest.len().is_multiple_of(2) {
            return Err(InputError::new(
                path,
                format!("line {line}: TRACK of point3D {id}"),
                format!(
                    "has {} values, not a multiple of 2 (IMAGE_ID, POINT2D_IDX)",
                    rest.len()
                ),
                "fix the line or export the model again",
            )
            .into());
        }
        let mut track = Vec::with_capacity(rest.len() / 2);
        for (k, pair) in rest.chunks_exact(2).enumerate() {
            let image_id = f.parse(pair[0], &format!("TRACK[{k}] IMAGE_ID"))?;
            let idx = f.parse(pair[1], &format!("TRACK[{k}] POINT2D_IDX"))?;
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
    Ok(points)
}

fn save(path: &Path, text: &str) -> anyhow::Result<()> {
    write_atomic(path, |f| {
        f.write_all(text.as_bytes())
            .with_context(|| format!("{}: write failed (disk full?)", path.display()))
    })
}

// `{}` on f64 prints the shortest text that parses back to the same bits, which is what makes
// a text model read back identical to the binary one.

pub fn write_cameras(path: &Path, cameras: &[ColmapCamera]) -> anyhow::Result<()> {
    let mut s = String::new();
    s.push_str("# Camera list with one line of data per camera:\n#   CAMERA_ID, MODEL, WIDTH, HEIGHT, PARAMS[]\n");
    let _ = writeln!(s, "# Number of cameras: {}", cameras.len());
    for c in cameras {
        let name = models::name_of(c.model_id)
            .map(str::to_string)
            .unwrap_or_else(|| format!("UNKNOWN_MODEL_{}", c.model_id));
        let _ = write!(s, "{} {} {} {}", c.id, name, c.width, c.height);
        for p in &c.params {
            let _ = write!(s, " {p}");
        }
        s.push('\n');
    }
    save(path, &s)
}

pub fn write_images(path: &Path, images: &[ColmapImage]) -> anyhow::Result<()> {
    let mut s = String::new();
    s.push_str("# Image list with two lines of data per image:\n#   IMAGE_ID, QW, QX, QY, QZ, TX, TY, TZ, CAMERA_ID, NAME\n#   POINTS2D[] as (X, Y, POINT3D_ID)\n");
    let _ = writeln!(s, "# Number of images: {}", images.len());
    for im in images {
        anyhow::ensure!(
            im.points2d.len() == im.point3d_ids.len(),
            "image {}: {} keypoints but {} point3D ids",
            im.id,
            im.points2d.len(),
            im.point3d_ids.len()
        );
        let [qw, qx, qy, qz] = im.qvec;
        let [tx, ty, tz] = im.tvec;
        let _ = writeln!(
            s,
            "{} {qw} {qx} {qy} {qz} {tx} {ty} {tz} {} {}",
            im.id, im.camera_id, im.name
        );
        for (k, (xy, id)) in im.points2d.iter().zip(&im.point3d_ids).enumerate() {
            if k > 0 {
                s.push(' ');
            }
            let _ = write!(s, "{} {} {id}", xy[0], xy[1]);
        }
        s.push('\n');
    }
    save(path, &s)
}

pub fn write_points(path: &Path, points: &[ColmapPoint]) -> anyhow::Result<()> {
    let mut s = String::new();
    s.push_str("# 3D point list with one line of data per point:\n#   POINT3D_ID, X, Y, Z, R, G, B, ERROR, TRACK[] as (IMAGE_ID, POINT2D_IDX)\n");
    let _ = writeln!(s, "# Number of points: {}", points.len());
    for p in points {
        let [x, y, z] = p.xyz;
        let [r, g, b] = p.rgb;
        let _ = write!(s, "{} {x} {y} {z} {r} {g} {b} {}", p.id, p.error);
        for (image_id, idx) in &p.track {
            let _ = write!(s, " {image_id} {idx}");
        }
        s.push('\n');
    }
    save(path, &s)
}
