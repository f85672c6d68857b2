//! The Neural 3D Video layout: `poses_bounds.npy` beside one folder of frames per camera.
//!
//! `poses_bounds.npy` has one row of 17 numbers per camera, in the order of the sorted video
//! names (`cam00.mp4`, `cam01.mp4`, …): a 3×5 matrix in row-major order whose first four
//! columns are LLFF's camera-to-world `[down | right | back | centre]` and whose fifth is
//! `(height, width, focal)` of the source video, then the near and far bounds (unused). The
//! frames are images named by their frame number inside `camNN/` (SpacetimeGaussians'
//! `pre_n3d.py` writes `cam00/0.png`, `cam00/1.png`, …) or `camNN/images/`. When the frames were
//! extracted downscaled, the focal length is scaled to their size. The principal point is the
//! image centre, as in SpacetimeGaussians' conversion. The first camera by name is held out for
//! testing (SpacetimeGaussians' and LPM's protocol).

use std::path::{Path, PathBuf};

use super::{finish, npy, pinhole, segment, FrameRange, VideoCamera, VideoLayout, VideoScene};
use crate::error::bad_input;
use crate::scene::{LoadOptions, Pose};

const FRAME_EXTENSIONS: [&str; 3] = ["png", "jpg", "jpeg"];

pub fn load(root: &Path, opts: &LoadOptions, range: FrameRange) -> anyhow::Result<VideoScene> {
    let npy_path = root.join("poses_bounds.npy");
    let poses = npy::read_array2(&npy_path)?;
    if poses.cols != 17 {
        return bad_input(
            &npy_path,
            "shape",
            format!("has {} columns where LLFF poses_bounds has 17", poses.cols),
            "use the poses_bounds.npy that came with the Neural 3D Video scene",
        );
    }
    let names = camera_names(root)?;
    if names.len() != poses.rows {
        return bad_input(
            &npy_path,
            "rows",
            format!(
                "has {} cameras but {} camera folders/videos (cam*) were found",
                poses.rows,
                names.len()
            ),
            "extract every camera's frames into camNN/ beside poses_bounds.npy",
        );
    }
    let mut cameras = Vec::new();
    let mut available = usize::MAX;
    let mut frame_lists = Vec::new();
    for name in &names {
        let frames = frame_files(root, name)?;
        available = available.min(frames.len());
        frame_lists.push(frames);
    }
    let (start, count) = segment(root, available, range)?;
    for (i, (name, frames)) in names.iter().zip(frame_lists).enumerate() {
        let row = poses.row(i);
        let m = |r: usize, c: usize| row[r * 5 + c];
        let (h, w, focal) = (m(0, 4), m(1, 4), m(2, 4));
        if !(h >= 1.0 && w >= 1.0 && focal > 0.0 && row.iter().all(|v| v.is_finite())) {
            return bad_input(
                &npy_path,
                format!("row {i} ({name})"),
                format!("has height {h}, width {w}, focal {focal} or a non-finite entry"),
                "use the poses_bounds.npy that came with the scene",
            );
        }
        let first = &frames[start];
        let (iw, ih) = image::image_dimensions(first).map_err(|e| {
            crate::error::InputError::new(
                first,
                "image header",
                format!("cannot be read ({e})"),
                "re-extract the frame (PNG or JPEG)",
            )
        })?;
        let scale = iw as f64 / w;
        if ((ih as f64 / h) - scale).abs() > 0.01 * scale {
            return bad_input(
                first,
                "image size",
                format!("is {iw}x{ih}, not {w}x{h} or a uniform downscale of it"),
                "extract frames at the video's size or a uniform fraction of it",
            );
        }
        // LLFF's columns are [down, right, back]; OpenCV's camera axes are [right, down, forward].
        let c2w = [
            [m(0, 1), m(0, 0), -m(0, 2), m(0, 3)],
            [m(1, 1), m(1, 0), -m(1, 2), m(1, 3)],
            [m(2, 1), m(2, 0), -m(2, 2), m(2, 3)],
        ];
        if let Some(problem) = rotation_problem(&c2w) {
            return bad_input(
                &npy_path,
                format!("row {i} ({name}) rotation"),
                problem,
                "use the poses_bounds.npy that came with the scene (its rotations are \
                 orthonormal), or export the poses again",
            );
        }
        let pose = pose_from_opencv_c2w(c2w);
        let f = focal * scale;
        let (source_model, camera) =
            pinhole([f, f, iw as f64 / 2.0, ih as f64 / 2.0], iw, ih, opts);
        cameras.push(VideoCamera {
            name: name.clone(),
            source_model,
            source_width: iw,
            source_height: ih,
            camera,
            pose,
            frames: frames[start..start + count].to_vec(),
            masks: None,
        });
    }
    let test = vec![names[0].clone()];
    finish(root, VideoLayout::NeuralVideo, cameras, &test, start, count)
}

/// What is wrong with a camera-to-world matrix's rotation part, if anything: a rotation has
/// orthonormal columns (within 1e-3: files store 6–9 digits) and determinant +1; a singular
/// matrix (all zeros: a failed registration), a reflection or a scaled or sheared one gives
/// the camera no orientation.
fn rotation_problem(c2w: &[[f64; 4]; 3]) -> Option<String> {
    let mut worst = 0.0f64;
    for i in 0..3 {
        for j in 0..3 {
            let dot: f64 = (0..3).map(|k| c2w[k][i] * c2w[k][j]).sum();
            worst = worst.max((dot - if i == j { 1.0 } else { 0.0 }).abs());
        }
    }
    let r = |i: usize, j: usize| c2w[i][j];
    let det = r(0, 0) * (r(1, 1) * r(2, 2) - r(1, 2) * r(2, 1))
        - r(0, 1) * (r(1, 0) * r(2, 2) - r(1, 2) * r(2, 0))
        + r(0, 2) * (r(1, 0) * r(2, 1) - r(1, 1) * r(2, 0));
    if worst.is_nan() || worst > 1e-3 {
        Some(format!(
            "is not a rotation (columns off orthonormal by {worst:.3e}; determinant {det:.3e})"
        ))
    } else if det < 0.0 {
        Some(format!(
            "is a reflection (determinant {det:.3e}), not a rotation"
        ))
    } else {
        None
    }
}

/// The world-to-camera pose of an OpenCV-axes camera-to-world matrix. The rotation is used as
/// stored (LLFF files hold it orthonormal to float precision).
fn pose_from_opencv_c2w(c2w: [[f64; 4]; 3]) -> Pose {
    let mut rotation = [[0.0; 3]; 3];
    for (r, row) in rotation.iter_mut().enumerate() {
        for (c, v) in row.iter_mut().enumerate() {
            *v = c2w[c][r];
        }
    }
    let centre = [c2w[0][3], c2w[1][3], c2w[2][3]];
    let translation = [0, 1, 2].map(|r| -(0..3).map(|c| rotation[r][c] * centre[c]).sum::<f64>());
    Pose {
        rotation,
        translation,
    }
}

/// The cameras' names in the order of `poses_bounds.npy`'s rows: the sorted `cam*` videos when
/// they are present, else the sorted `cam*` frame folders.
fn camera_names(root: &Path) -> anyhow::Result<Vec<String>> {
    let entries = std::fs::read_dir(root).map_err(|e| {
        crate::error::InputError::new(
            root,
            "folder",
            format!("cannot be listed ({e})"),
            "check the path",
        )
    })?;
    let mut videos = Vec::new();
    let mut folders = Vec::new();
    for e in entries.flatten() {
        let path = e.path();
        let name = e.file_name().to_string_lossy().to_string();
        if !name.starts_with("cam") {
            continue;
        }
        if path.is_dir() {
            folders.push(name);
        } else if path
            .extension()
            .is_some_and(|x| x.eq_ignore_ascii_case("mp4"))
        {
            videos.push(path.file_stem().unwrap().to_string_lossy().to_string());
        }
    }
    videos.sort();
    folders.sort();
    let names = if videos.is_empty() { folders } else { videos };
    if names.is_empty() {
        return bad_input(
            root,
            "camera folders",
            "none named cam* were found beside poses_bounds.npy",
            "extract each camera's video into camNN/ (frame images named by their number)",
        );
    }
    Ok(names)
}

/// A camera's frame images sorted by frame number.
fn frame_files(root: &Path, name: &str) -> anyhow::Result<Vec<PathBuf>> {
    let dir = root.join(name);
    let dir = if dir.join("images").is_dir() {
        dir.join("images")
    } else {
        dir
    };
    let Ok(entries) = std::fs::read_dir(&dir) else {
        return bad_input(
            &dir,
            "frames",
            "the folder is missing",
            format!(
                "extract {name}'s video into {} (e.g. ffmpeg -i {name}.mp4 {name}/%d.png)",
                dir.display()
            ),
        );
    };
    let mut frames: Vec<(u64, PathBuf)> = entries
        .flatten()
        .map(|e| e.path())
        .filter(|p| {
            p.extension().is_some_and(|x| {
                FRAME_EXTENSIONS.contains(&x.to_string_lossy().to_ascii_lowercase().as_str())
            })
        })
        .filter_map(|p| {
            let n = p.file_stem()?.to_str()?.parse::<u64>().ok()?;
            Some((n, p))
        })
        .collect();
    frames.sort();
    if frames.is_empty() {
        return bad_input(
            &dir,
            "frames",
            "holds no images named by frame number (0.png, 1.png, … or 0000.jpg, …)",
            format!("extract {name}'s video there (e.g. ffmpeg -i {name}.mp4 {name}/%d.png)"),
        );
    }
    if let Some(w) = frames.windows(2).find(|w| w[0].0 == w[1].0) {
        return bad_input(
            &w[1].1,
            "frame number",
            format!("{} appears twice in {}", w[0].0, dir.display()),
            "keep one image per frame number",
        );
    }
    Ok(frames.into_iter().map(|(_, p)| p).collect())
}
