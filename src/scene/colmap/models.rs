//! COLMAP's camera model table and the mapping to [`CameraModel`].

use std::path::Path;

use super::ColmapCamera;
use crate::error::InputError;
use crate::scene::CameraModel;

/// Every model COLMAP knows: (id, name, number of parameters). Knowing the ones we do not
/// support lets errors name them instead of printing a bare number.
pub const COLMAP_MODELS: [(i32, &str, usize); 11] = [
    (0, "SIMPLE_PINHOLE", 3),
    (1, "PINHOLE", 4),
    (2, "SIMPLE_RADIAL", 4),
    (3, "RADIAL", 5),
    (4, "OPENCV", 8),
    (5, "OPENCV_FISHEYE", 8),
    (6, "FULL_OPENCV", 12),
    (7, "FOV", 5),
    (8, "SIMPLE_RADIAL_FISHEYE", 4),
    (9, "RADIAL_FISHEYE", 5),
    (10, "THIN_PRISM_FISHEYE", 12),
];

/// The models this engine reads, for error messages.
pub const SUPPORTED_MODELS: &str = "SIMPLE_PINHOLE, PINHOLE, SIMPLE_RADIAL, RADIAL, OPENCV";

const FIX_MODEL: &str = "re-run COLMAP with one of the supported models (SIMPLE_PINHOLE, PINHOLE, SIMPLE_RADIAL, RADIAL, OPENCV), or undistort the images with `colmap image_undistorter` and point at its output";

pub fn name_of(model_id: i32) -> Option<&'static str> {
    COLMAP_MODELS.iter().find(|m| m.0 == model_id).map(|m| m.1)
}

pub fn id_of(name: &str) -> Option<i32> {
    COLMAP_MODELS.iter().find(|m| m.1 == name).map(|m| m.0)
}

pub fn num_params(model_id: i32) -> Option<usize> {
    COLMAP_MODELS.iter().find(|m| m.0 == model_id).map(|m| m.2)
}

/// The error for a model id COLMAP itself does not know (a corrupt or foreign file).
pub fn unknown_model_id(file: &Path, camera_id: u32, model_id: i32) -> InputError {
    InputError::new(
        file,
        format!("camera {camera_id} model"),
        format!("unknown camera model id {model_id}; supported models: {SUPPORTED_MODELS}"),
        FIX_MODEL,
    )
}

/// The error for a model name COLMAP itself does not know.
pub fn unknown_model_name(file: &Path, line: usize, camera_id: &str, name: &str) -> InputError {
    InputError::new(
        file,
        format!("line {line}: camera {camera_id} model"),
        format!("unknown camera model '{name}'; supported models: {SUPPORTED_MODELS}"),
        FIX_MODEL,
    )
}

/// COLMAP's model id and parameter vector for a [`CameraModel`].
pub fn to_params(model: &CameraModel) -> (i32, Vec<f64>) {
    match *model {
        CameraModel::SimplePinhole { f, cx, cy } => (0, vec![f, cx, cy]),
        CameraModel::Pinhole { fx, fy, cx, cy } => (1, vec![fx, fy, cx, cy]),
        CameraModel::SimpleRadial { f, cx, cy, k } => (2, vec![f, cx, cy, k]),
        CameraModel::Radial { f, cx, cy, k1, k2 } => (3, vec![f, cx, cy, k1, k2]),
        CameraModel::OpenCv {
            fx,
            fy,
            cx,
            cy,
            k1,
            k2,
            p1,
            p2,
        } => (4, vec![fx, fy, cx, cy, k1, k2, p1, p2]),
    }
}

/// The [`CameraModel`] of a camera record; `file` is the cameras file it came from.
pub fn to_camera_model(camera: &ColmapCamera, file: &Path) -> Result<CameraModel, InputError> {
    let p = &camera.params;
    let expected = num_params(camera.model_id)
        .ok_or_else(|| unknown_model_id(file, camera.id, camera.model_id))?;
    let name = name_of(camera.model_id).unwrap_or("?");
    if p.len() != expected {
        return Err(InputError::new(
            file,
            format!("camera {} params", camera.id),
            format!(
                "model {name} takes {expected} parameters, found {}",
                p.len()
            ),
            "write the parameters in COLMAP's order for that model",
        ));
    }
    let model = match camera.model_id {
        0 => CameraModel::SimplePinhole {
            f: p[0],
            cx: p[1],
            cy: p[2],
        },
        1 => CameraModel::Pinhole {
            fx: p[0],
            fy: p[1],
            cx: p[2],
            cy: p[3],
        },
        2 => CameraModel::SimpleRadial {
            f: p[0],
            cx: p[1],
            cy: p[2],
            k: p[3],
        },
        3 => CameraModel::Radial {
            f: p[0],
            cx: p[1],
            cy: p[2],
            k1: p[3],
            k2: p[4],
        },
        4 => CameraModel::OpenCv {
            fx: p[0],
            fy: p[1],
            cx: p[2],
            cy: p[3],
            k1: p[4],
            k2: p[5],
            p1: p[6],
            p2: p[7],
        },
        _ => {
            return Err(InputError::new(
                file,
                format!("camera {} model", camera.id),
                format!(
                    "camera model {name} is not supported; supported models: {SUPPORTED_MODELS}"
                ),
                FIX_MODEL,
            ))
        }
    };
    Ok(model)
}
