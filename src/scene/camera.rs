//! Cameras in the engine's convention.
//!
//! Convention (COLMAP / OpenCV): camera looks down +z, x right, y down. A world point `p` maps to
//! camera space as `R p + t` (`Pose` is world-to-camera). Pixel coordinates: `u = fx x/z + cx`,
//! `v = fy y/z + cy`, with the centre of pixel (i, j) at (i + 0.5, j + 0.5).

/// A lens model as found in a COLMAP `cameras` file or a transforms.json, in pixels of the
/// source image. Parameters follow COLMAP's order.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum CameraModel {
    SimplePinhole {
        f: f64,
        cx: f64,
        cy: f64,
    },
    Pinhole {
        fx: f64,
        fy: f64,
        cx: f64,
        cy: f64,
    },
    SimpleRadial {
        f: f64,
        cx: f64,
        cy: f64,
        k: f64,
    },
    Radial {
        f: f64,
        cx: f64,
        cy: f64,
        k1: f64,
        k2: f64,
    },
    OpenCv {
        fx: f64,
        fy: f64,
        cx: f64,
        cy: f64,
        k1: f64,
        k2: f64,
        p1: f64,
        p2: f64,
    },
}

impl CameraModel {
    /// COLMAP's model name.
    pub fn name(&self) -> &'static str {
        match self {
            CameraModel::SimplePinhole { .. } => "SIMPLE_PINHOLE",
            CameraModel::Pinhole { .. } => "PINHOLE",
            CameraModel::SimpleRadial { .. } => "SIMPLE_RADIAL",
            CameraModel::Radial { .. } => "RADIAL",
            CameraModel::OpenCv { .. } => "OPENCV",
        }
    }

    /// Focal lengths and principal point (fx, fy, cx, cy).
    pub fn pinhole_part(&self) -> (f64, f64, f64, f64) {
        match *self {
            CameraModel::SimplePinhole { f, cx, cy }
            | CameraModel::SimpleRadial { f, cx, cy, .. }
            | CameraModel::Radial { f, cx, cy, .. } => (f, f, cx, cy),
            CameraModel::Pinhole { fx, fy, cx, cy }
            | CameraModel::OpenCv { fx, fy, cx, cy, .. } => (fx, fy, cx, cy),
        }
    }

    /// True when the model has non-zero distortion parameters.
    pub fn is_distorted(&self) -> bool {
        match *self {
            CameraModel::SimplePinhole { .. } | CameraModel::Pinhole { .. } => false,
            CameraModel::SimpleRadial { k, .. } => k != 0.0,
            CameraModel::Radial { k1, k2, .. } => k1 != 0.0 || k2 != 0.0,
            CameraModel::OpenCv { k1, k2, p1, p2, .. } => {
                k1 != 0.0 || k2 != 0.0 || p1 != 0.0 || p2 != 0.0
            }
        }
    }

    /// Applies the model's distortion to normalised image coordinates (x/z, y/z), COLMAP's way.
    pub fn distort_normalized(&self, x: f64, y: f64) -> (f64, f64) {
        match *self {
            CameraModel::SimplePinhole { .. } | CameraModel::Pinhole { .. } => (x, y),
            CameraModel::SimpleRadial { k, .. } => {
                let r2 = x * x + y * y;
                let s = 1.0 + k * r2;
                (x * s, y * s)
            }
            CameraModel::Radial { k1, k2, .. } => {
                let r2 = x * x + y * y;
                let s = 1.0 + k1 * r2 + k2 * r2 * r2;
                (x * s, y * s)
            }
            CameraModel::OpenCv { k1, k2, p1, p2, .. } => {
                let (xx, yy, xy) = (x * x, y * y, x * y);
                let r2 = xx + yy;
                let radial = 1.0 + k1 * r2 + k2 * r2 * r2;
                (
                    x * radial + 2.0 * p1 * xy + p2 * (r2 + 2.0 * xx),
                    y * radial + 2.0 * p2 * xy + p1 * (r2 + 2.0 * yy),
                )
            }
        }
    }

    /// Scales the model for an image resized by `sx`, `sy` (new size / old size).
    pub fn scaled(&self, sx: f64, sy: f64) -> CameraModel {
        let mut m = *self;
        match &mut m {
            CameraModel::SimplePinhole { f, cx, cy }
            | CameraModel::SimpleRadial { f, cx, cy, .. }
            | CameraModel::Radial { f, cx, cy, .. } => {
                // One focal length: the mean keeps it honest when sx and sy differ by rounding.
                *f *= 0.5 * (sx + sy);
                *cx *= sx;
                *cy *= sy;
            }
            CameraModel::Pinhole { fx, fy, cx, cy }
            | CameraModel::OpenCv { fx, fy, cx, cy, .. } => {
                *fx *= sx;
                *fy *= sy;
                *cx *= sx;
                *cy *= sy;
            }
        }
        m
    }
}

/// An undistorted pinhole camera in pixels: what the renderer and trainer use.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct PinholeCamera {
    pub fx: f64,
    pub fy: f64,
    pub cx: f64,
    pub cy: f64,
    pub width: u32,
    pub height: u32,
}

impl PinholeCamera {
    /// The same camera for an image resized to `width` × `height`.
    pub fn resized(&self, width: u32, height: u32) -> PinholeCamera {
        let sx = width as f64 / self.width as f64;
        let sy = height as f64 / self.height as f64;
        PinholeCamera {
            fx: self.fx * sx,
            fy: self.fy * sy,
            cx: self.cx * sx,
            cy: self.cy * sy,
            width,
            height,
        }
    }

    /// Horizontal and vertical field of view in radians (for a centred principal point).
    pub fn fov(&self) -> (f64, f64) {
        (
            2.0 * (self.width as f64 / (2.0 * self.fx)).atan(),
            2.0 * (self.height as f64 / (2.0 * self.fy)).atan(),
        )
    }

    /// Projects a camera-space point to pixel coordinates.
    pub fn project(&self, p: [f64; 3]) -> [f64; 2] {
        [
            self.fx * p[0] / p[2] + self.cx,
            self.fy * p[1] / p[2] + self.cy,
        ]
    }
}

/// World-to-camera rigid transform: `x_cam = rotation * x_world + translation`.
/// `rotation` is row-major.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Pose {
    pub rotation: [[f64; 3]; 3],
    pub translation: [f64; 3],
}

/// The rotation matrix of a unit quaternion (w, x, y, z), in f64: COLMAP's poses here, and the
/// f64 oracles' Gaussian rotations (`crate::reference::project::quat_to_rotation`).
pub fn rotation_of_unit_quaternion(q: [f64; 4]) -> [[f64; 3]; 3] {
    let [w, x, y, z] = q;
    [
        [
            1.0 - 2.0 * (y * y + z * z),
            2.0 * (x * y - w * z),
            2.0 * (x * z + w * y),
        ],
        [
            2.0 * (x * y + w * z),
            1.0 - 2.0 * (x * x + z * z),
            2.0 * (y * z - w * x),
        ],
        [
            2.0 * (x * z - w * y),
            2.0 * (y * z + w * x),
            1.0 - 2.0 * (x * x + y * y),
        ],
    ]
}

/// The unit quaternion (w, x, y, z, w ≥ 0) of a rotation matrix, the inverse of
/// [`rotation_of_unit_quaternion`]: what a COLMAP file stores for a pose built as a matrix.
/// Shepperd's choice of the largest diagonal term keeps it accurate near every rotation.
pub fn unit_quaternion_of_rotation(r: [[f64; 3]; 3]) -> [f64; 4] {
    let trace = r[0][0] + r[1][1] + r[2][2];
    let q = if trace > r[0][0].max(r[1][1]).max(r[2][2]) {
        let s = 2.0 * (1.0 + trace).sqrt();
        [
            s / 4.0,
            (r[2][1] - r[1][2]) / s,
            (r[0][2] - r[2][0]) / s,
            (r[1][0] - r[0][1]) / s,
        ]
    } else if r[0][0] >= r[1][1] && r[0][0] >= r[2][2] {
        let s = 2.0 * (1.0 + r[0][0] - r[1][1] - r[2][2]).sqrt();
        [
            (r[2][1] - r[1][2]) / s,
            s / 4.0,
            (r[0][1] + r[1][0]) / s,
            (r[0][2] + r[2][0]) / s,
        ]
    } else if r[1][1] >= r[2][2] {
        let s = 2.0 * (1.0 + r[1][1] - r[0][0] - r[2][2]).sqrt();
        [
            (r[0][2] - r[2][0]) / s,
            (r[0][1] + r[1][0]) / s,
            s / 4.0,
            (r[1][2] + r[2][1]) / s,
        ]
    } else {
        let s = 2.0 * (1.0 + r[2][2] - r[0][0] - r[1][1]).sqrt();
        [
            (r[1][0] - r[0][1]) / s,
            (r[0][2] + r[2][0]) / s,
            (r[1][2] + r[2][1]) / s,
            s / 4.0,
        ]
    };
    let n = q.iter().map(|v| v * v).sum::<f64>().sqrt();
    let sign = if q[0] < 0.0 { -1.0 } else { 1.0 };
    q.map(|v| sign * v / n)
}

impl Pose {
    pub const IDENTITY: Pose = Pose {
        rotation: [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]],
        translation: [0.0; 3],
    };

    /// From COLMAP's quaternion (w, x, y, z) and translation. The quaternion is normalised.
    pub fn from_qvec_tvec(q: [f64; 4], t: [f64; 3]) -> Pose {
        let n = (q[0] * q[0] + q[1] * q[1] + q[2] * q[2] + q[3] * q[3]).sqrt();
        let (w, x, y, z) = if n > 0.0 {
            (q[0] / n, q[1] / n, q[2] / n, q[3] / n)
        } else {
            (1.0, 0.0, 0.0, 0.0)
        };
        Pose {
            rotation: rotation_of_unit_quaternion([w, x, y, z]),
            translation: t,
        }
    }

    /// Applies the transform to a world point.
    pub fn transform(&self, p: [f64; 3]) -> [f64; 3] {
        let r = &self.rotation;
        let t = &self.translation;
        [
            r[0][0] * p[0] + r[0][1] * p[1] + r[0][2] * p[2] + t[0],
            r[1][0] * p[0] + r[1][1] * p[1] + r[1][2] * p[2] + t[1],
            r[2][0] * p[0] + r[2][1] * p[1] + r[2][2] * p[2] + t[2],
        ]
    }

    /// Maps a camera-space point back to world space: `Rᵀ (p − t)`.
    pub fn inverse_transform(&self, p: [f64; 3]) -> [f64; 3] {
        let r = &self.rotation;
        let d = [0, 1, 2].map(|k| p[k] - self.translation[k]);
        [0, 1, 2].map(|c| r[0][c] * d[0] + r[1][c] * d[1] + r[2][c] * d[2])
    }

    /// Camera centre in world coordinates: `-Rᵀ t`.
    pub fn center(&self) -> [f64; 3] {
        let r = &self.rotation;
        let t = &self.translation;
        [
            -(r[0][0] * t[0] + r[1][0] * t[1] + r[2][0] * t[2]),
            -(r[0][1] * t[0] + r[1][1] * t[1] + r[2][1] * t[2]),
            -(r[0][2] * t[0] + r[1][2] * t[1] + r[2][2] * t[2]),
        ]
    }

    /// Optical axis (camera +z) in world coordinates: the third row of R.
    pub fn optical_axis(&self) -> [f64; 3] {
        self.rotation[2]
    }

    /// From a camera-to-world matrix in the OpenGL/Blender convention (x right, y up, camera
    /// looks down −z), as in transforms.json. Flips y and z to reach the engine's convention.
    pub fn from_opengl_camera_to_world(m: [[f64; 4]; 4]) -> Pose {
        // c2w in OpenCV axes: columns 1 and 2 negated.
        let mut r_c2w = [[0.0; 3]; 3];
        for (i, row) in r_c2w.iter_mut().enumerate() {
            *row = [m[i][0], -m[i][1], -m[i][2]];
        }
        let c = [m[0][3], m[1][3], m[2][3]];
        // w2c = [Rᵀ | −Rᵀ c]
        let mut rotation = [[0.0; 3]; 3];
        for (i, row) in rotation.iter_mut().enumerate() {
            for (j, v) in row.iter_mut().enumerate() {
                *v = r_c2w[j][i];
            }
        }
        let translation = [
            -(rotation[0][0] * c[0] + rotation[0][1] * c[1] + rotation[0][2] * c[2]),
            -(rotation[1][0] * c[0] + rotation[1][1] * c[1] + rotation[1][2] * c[2]),
            -(rotation[2][0] * c[0] + rotation[2][1] * c[1] + rotation[2][2] * c[2]),
        ];
        Pose {
            rotation,
            translation,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::{Rng, SeedableRng};

    #[test]
    fn a_rotation_matrix_gives_back_its_quaternion() {
        let mut rng = rand_pcg::Pcg64::seed_from_u64(7);
        // Random rotations, and half-turns about each axis and a diagonal (trace −1, where a
        // quaternion from the trace alone loses every digit).
        let mut qs: Vec<[f64; 4]> = (0..1000)
            .map(|_| [0; 4].map(|_| rng.gen_range(-1.0..1.0)))
            .collect();
        qs.extend([
            [0.0, 1.0, 0.0, 0.0],
            [0.0, 0.0, 1.0, 0.0],
            [0.0, 0.0, 0.0, 1.0],
            [1e-9, 0.6, 0.0, 0.8],
            [1.0, 0.0, 0.0, 0.0],
        ]);
        for q in qs {
            let n = q.iter().map(|v| v * v).sum::<f64>().sqrt();
            let sign = if q[0] < 0.0 { -1.0 } else { 1.0 };
            let q = q.map(|v| sign * v / n);
            let back = unit_quaternion_of_rotation(rotation_of_unit_quaternion(q));
            for k in 0..4 {
                assert!((back[k] - q[k]).abs() < 1e-12, "{q:?} → {back:?}");
            }
        }
    }
}
