//! COLMAP sparse models (`cameras`, `images`, `points3D`) in binary and text form.
//!
//! Reading happens in two layers: [`binary`] and [`text`] parse a file into the raw
//! [`ColmapModel`] (COLMAP's own records, nothing interpreted), and `load` checks that model
//! against itself and the images on disk and turns it into a [`Scene`]. Both forms go through the
//! same second layer, which is why a `.bin` and a `.txt` copy of a model give identical scenes.

pub mod binary;
mod load;
pub mod models;
pub mod text;

use std::path::{Path, PathBuf};

use super::{CameraModel, LoadOptions, Scene};
use crate::error::bad_input;

pub use load::build_scene;
pub use models::SUPPORTED_MODELS;

/// One record of `cameras.{bin,txt}`, as COLMAP stores it.
#[derive(Debug, Clone, PartialEq)]
pub struct ColmapCamera {
    pub id: u32,
    /// COLMAP's numeric model id (see [`models::COLMAP_MODELS`]).
    pub model_id: i32,
    pub width: u64,
    pub height: u64,
    pub params: Vec<f64>,
}

impl ColmapCamera {
    /// The record for a [`CameraModel`] (parameters in COLMAP's order).
    pub fn from_model(id: u32, model: &CameraModel, width: u64, height: u64) -> ColmapCamera {
        let (model_id, params) = models::to_params(model);
        ColmapCamera {
            id,
            model_id,
            width,
            height,
            params,
        }
    }
}

/// One record of `images.{bin,txt}`: a posed image and its 2D keypoints.
#[derive(Debug, Clone, PartialEq)]
pub struct ColmapImage {
    pub id: u32,
    /// World-to-camera rotation as a quaternion (w, x, y, z).
    pub qvec: [f64; 4],
    /// World-to-camera translation.
    pub tvec: [f64; 3],
    pub camera_id: u32,
    /// Path of the image relative to the scene's `images/` folder.
    pub name: String,
    /// Keypoints in source pixels (pixel centres at +0.5).
    pub points2d: Vec<[f64; 2]>,
    /// The point3D each keypoint observes, or -1.
    pub point3d_ids: Vec<i64>,
}

/// One record of `points3D.{bin,txt}`.
#[derive(Debug, Clone, PartialEq)]
pub struct ColmapPoint {
    pub id: u64,
    pub xyz: [f64; 3],
    pub rgb: [u8; 3],
    pub error: f64,
    /// (image id, index into that image's keypoints).
    pub track: Vec<(u32, u32)>,
}

/// A whole sparse model, records in file order.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct ColmapModel {
    pub cameras: Vec<ColmapCamera>,
    pub images: Vec<ColmapImage>,
    pub points: Vec<ColmapPoint>,
}

impl ColmapModel {
    /// The same reconstruction in another world frame, `x' = scale · rotate(x) + offset`
    /// (`rotation` a quaternion (w, x, y, z), normalised here): points move with the world,
    /// poses follow so that every keypoint projects where it did (camera space is scaled with
    /// the world; `R' = R·Qᵀ`, `t' = scale·t − R'·offset`). What a georeferenced or
    /// survey-unit export of the same model is; tests and `examples/reframe_colmap.rs` use it.
    pub fn reframed(&self, scale: f64, rotation: [f64; 4], offset: [f64; 3]) -> ColmapModel {
        let n = rotation.iter().map(|v| v * v).sum::<f64>().sqrt();
        let q = rotation.map(|v| v / n);
        let rot = super::Pose::from_qvec_tvec(q, [0.0; 3]);
        let mut out = self.clone();
        for p in &mut out.points {
            let r = rot.transform(p.xyz);
            p.xyz = [0, 1, 2].map(|k| scale * r[k] + offset[k]);
        }
        // The conjugate of the world rotation, composed on the right of each camera's.
        let qc = [q[0], -q[1], -q[2], -q[3]];
        for im in &mut out.images {
            let a = im.qvec;
            let b = qc;
            im.qvec = [
                a[0] * b[0] - a[1] * b[1] - a[2] * b[2] - a[3] * b[3],
                a[0] * b[1] + a[1] * b[0] + a[2] * b[3] - a[3] * b[2],
                a[0] * b[2] - a[1] * b[3] + a[2] * b[0] + a[3] * b[1],
                a[0] * b[3] + a[1] * b[2] - a[2] * b[1] + a[3] * b[0],
            ];
            let r = super::Pose::from_qvec_tvec(im.qvec, [0.0; 3]);
            let ro = r.transform(offset);
            im.tvec = [0, 1, 2].map(|k| scale * im.tvec[k] - ro[k]);
        }
        out
    }
}

/// The three files of a model in one form.
#[derive(Debug, Clone, PartialEq)]
pub struct ModelFiles {
    pub cameras: PathBuf,
    pub images: PathBuf,
    pub points: PathBuf,
}

impl ModelFiles {
    pub fn new(sparse_dir: &Path, binary: bool) -> ModelFiles {
        let ext = if binary { "bin" } else { "txt" };
        ModelFiles {
            cameras: sparse_dir.join(format!("cameras.{ext}")),
            images: sparse_dir.join(format!("images.{ext}")),
            points: sparse_dir.join(format!("points3D.{ext}")),
        }
    }
}

/// `root/sparse/0` or `root/sparse` when it holds `cameras.bin` or `cameras.txt`.
pub fn find_sparse_dir(root: &Path) -> Option<PathBuf> {
    [root.join("sparse").join("0"), root.join("sparse")]
        .into_iter()
        .find(|d| d.join("cameras.bin").exists() || d.join("cameras.txt").exists())
}

/// Whether [`super::ColmapForm`] picks the binary form in `sparse_dir`.
pub fn use_binary(sparse_dir: &Path, form: super::ColmapForm) -> bool {
    match form {
        super::ColmapForm::Auto => sparse_dir.join("cameras.bin").exists(),
        super::ColmapForm::Binary => true,
        super::ColmapForm::Text => false,
    }
}

/// Reads the raw model in `sparse_dir` in the given form. Checks only the files' syntax.
pub fn read_model(sparse_dir: &Path, binary: bool) -> anyhow::Result<ColmapModel> {
    let files = ModelFiles::new(sparse_dir, binary);
    let (form, other) = if binary {
        ("binary", "text (.txt)")
    } else {
        ("text", "binary (.bin)")
    };
    for (path, what) in [
        (&files.cameras, "cameras"),
        (&files.images, "images"),
        (&files.points, "points3D"),
    ] {
        if !path.is_file() {
            return bad_input(
                path,
                format!("{what} file"),
                format!("missing: a COLMAP {form} model needs cameras, images and points3D files side by side"),
                format!(
                    "export the whole model from COLMAP into {} (or select the {other} form if that is complete)",
                    sparse_dir.display()
                ),
            );
        }
    }
    if binary {
        Ok(ColmapModel {
            cameras: binary::read_cameras(&files.cameras)?,
            images: binary::read_images(&files.images)?,
            points: binary::read_points(&files.points)?,
        })
    } else {
        Ok(ColmapModel {
            cameras: text::read_cameras(&files.cameras)?,
            images: text::read_images(&files.images)?,
            points: text::read_points(&files.points)?,
        })
    }
}

/// Writes `cameras.bin`, `images.bin` and `points3D.bin` into `sparse_dir` (created if needed).
pub fn write_binary(sparse_dir: &Path, model: &ColmapModel) -> anyhow::Result<()> {
    std::fs::create_dir_all(sparse_dir)?;
    let files = ModelFiles::new(sparse_dir, true);
    binary::write_cameras(&files.cameras, &model.cameras)?;
    binary::write_images(&files.images, &model.images)?;
    binary::write_points(&files.points, &model.points)
}

/// Writes `cameras.txt`, `images.txt` and `points3D.txt` into `sparse_dir` (created if needed).
/// Numbers are written in their shortest exact form, so reading them back is lossless.
pub fn write_text(sparse_dir: &Path, model: &ColmapModel) -> anyhow::Result<()> {
    std::fs::create_dir_all(sparse_dir)?;
    let files = ModelFiles::new(sparse_dir, false);
    text::write_cameras(&files.cameras, &model.cameras)?;
    text::write_images(&files.images, &model.images)?;
    text::write_points(&files.points, &model.points)
}

/// Loads the COLMAP scene in `root` whose model lives in `sparse`.
pub fn load_scene(root: &Path, sparse: &Path, opts: &LoadOptions) -> anyhow::Result<Scene> {
    let binary = use_binary(sparse, opts.colmap_form);
    let model = read_model(sparse, binary)?;
    build_scene(root, sparse, binary, &model, opts)
}
