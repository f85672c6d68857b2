//! Scenes: cameras, poses, images, SfM points and their tracks, train/test split, extent.
//!
//! A scene folder holds either a COLMAP model (`sparse/0/` or `sparse/`, binary or text) with
//! `images/`, or `transforms*.json` files (NeRF-synthetic or nerfstudio / instant-ngp form).
//! Every view is presented to the rest of the engine as an undistorted [`PinholeCamera`] at the
//! training resolution plus a world-to-camera [`Pose`] in the COLMAP/OpenCV convention.

pub mod camera;
pub mod colmap;
pub mod frame;
pub mod image_source;
pub mod images;
pub mod loss_masks;
pub mod orbit;
pub mod split;
pub mod transforms;
pub mod undistort;
pub mod video;

use std::path::{Path, PathBuf};

pub use camera::{CameraModel, PinholeCamera, Pose};
pub use frame::SceneFrame;
pub use images::Image;

/// 2D keypoints of one view, in the pixels of the view's undistorted, resized [`PinholeCamera`].
#[derive(Debug, Clone, PartialEq, Default)]
pub struct Keypoints {
    /// Keypoint positions (x, y) in pixels, pixel centres at +0.5.
    pub xy: Vec<[f64; 2]>,
    /// The SfM point each keypoint observes, or -1.
    pub point3d: Vec<i64>,
}

/// SfM points with colours and tracks.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct SfmPoints {
    /// COLMAP point3D ids.
    pub ids: Vec<u64>,
    pub positions: Vec<[f64; 3]>,
    pub colors: Vec<[u8; 3]>,
    /// Mean reprojection error per point.
    pub errors: Vec<f64>,
    /// Per point: (index into `Scene::views`, keypoint index in that view).
    pub tracks: Vec<Vec<(u32, u32)>>,
}

impl SfmPoints {
    pub fn len(&self) -> usize {
        self.positions.len()
    }
    pub fn is_empty(&self) -> bool {
        self.positions.is_empty()
    }
}

/// One camera view of the scene.
#[derive(Debug, Clone, PartialEq)]
pub struct View {
    /// File name as listed by the scene (e.g. `DSC_0001.JPG`, `./train/r_0`).
    pub name: String,
    /// The name's file stem: output images are written as `<stem>.png`.
    pub stem: String,
    /// The image file on disk.
    pub image_path: PathBuf,
    /// The lens model of the source image, in source pixels.
    pub source_model: CameraModel,
    pub source_width: u32,
    pub source_height: u32,
    /// The undistorted pinhole camera at the training resolution.
    pub camera: PinholeCamera,
    /// World-to-camera transform.
    pub pose: Pose,
    /// COLMAP image id when the scene came from COLMAP.
    pub colmap_image_id: Option<u32>,
    /// COLMAP 2D keypoints with their point3D ids (mapped to `camera`'s pixels).
    pub keypoints: Option<Keypoints>,
}

/// Where a scene came from.
#[derive(Debug, Clone, PartialEq)]
pub enum SceneFormat {
    /// A COLMAP sparse model; `binary` says which form was read.
    Colmap { sparse_dir: PathBuf, binary: bool },
    /// `transforms_{train,val,test}.json` with `camera_angle_x`.
    NerfSynthetic,
    /// A single `transforms.json` with `fl_x`/`fl_y`/`cx`/`cy`/`w`/`h`.
    Nerfstudio,
    /// Frames of a multi-view video ([`video::VideoScene::to_scene`], `frame_scene`).
    Video,
}

/// Which COLMAP form to read when both exist.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum ColmapForm {
    /// Binary when `cameras.bin` exists, else text.
    #[default]
    Auto,
    Binary,
    Text,
}

/// Which split to use as the test set for NeRF-synthetic scenes.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum NerfTestSplit {
    /// `transforms_test.json` when present, else `transforms_val.json`.
    #[default]
    TestOrVal,
    Val,
    Test,
}

/// How to load a scene.
#[derive(Debug, Clone, PartialEq)]
pub struct LoadOptions {
    /// `-r N`: divide image sizes by N (rounded). `None`: keep, but cap the width at `max_width`.
    pub resolution_factor: Option<u32>,
    /// Width cap applied when no factor is given (1600 in the Inria reference).
    pub max_width: u32,
    pub colmap_form: ColmapForm,
    pub nerf_test_split: NerfTestSplit,
    /// Hold out every N-th image (index % N == 0) when the scene has no explicit split.
    pub holdout_every: usize,
    /// When false, every view is a training view (no test set).
    pub eval_split: bool,
    /// Video scenes: the segment of frames.
    pub frames: video::FrameRange,
    /// Video scenes: the segment of the model the frames are loaded for (from its PLY), which
    /// gives them their times and must hold them; `None`: the loaded segment itself.
    pub time_base: Option<video::Segment>,
}

impl Default for LoadOptions {
    fn default() -> Self {
        Self {
            resolution_factor: None,
            max_width: 1600,
            colmap_form: ColmapForm::Auto,
            nerf_test_split: NerfTestSplit::TestOrVal,
            holdout_every: 8,
            eval_split: true,
            frames: video::FrameRange::default(),
            time_base: None,
        }
    }
}

/// The largest camera or point coordinate a scene may hold ([`Scene::check_coordinates`]).
pub const MAX_COORDINATE: f64 = 1e12;

/// Half side of the reference's random-initialisation box for NeRF-synthetic scenes.
pub const NERF_SYNTHETIC_INIT_HALF_SIDE: f64 = 1.3;

/// A loaded scene (metadata only; pixels are read by [`images::load_images`]).
#[derive(Debug, Clone, PartialEq)]
pub struct Scene {
    pub root: PathBuf,
    pub format: SceneFormat,
    /// All views, sorted by name.
    pub views: Vec<View>,
    /// Indices into `views`.
    pub train: Vec<usize>,
    pub test: Vec<usize>,
    /// SfM points (COLMAP, or `points3D.ply`-style data when present).
    pub points: Option<SfmPoints>,
    /// Mean of the training camera centres.
    pub center: [f64; 3],
    /// 1.1 × the largest distance of a training camera centre from `center`.
    pub extent: f64,
    /// The background the dataset assumes (white for NeRF-synthetic), when it has one.
    pub background: Option<[f32; 3]>,
    /// True when images carry an alpha channel to composite on the background.
    pub has_alpha: bool,
    /// The time of every view, for a scene made of a video's frames
    /// ([`video::VideoScene::to_scene`]); `None` for a still scene.
    pub view_times: Option<Vec<f64>>,
    /// For a video scene, the segment whose frame `start + k` has time `k / frames`: the
    /// loaded frames, or the segment of the model they are loaded for
    /// ([`LoadOptions::time_base`]). A video model's PLY records it.
    pub time_base: Option<video::Segment>,
    /// The similarity from the files' frame to the one the scene is held in: poses, points,
    /// `center` and `extent` above are in the training frame ([`frame`]); identity for a scene
    /// built by hand.
    pub frame: SceneFrame,
}

impl Scene {
    /// The box random initial points are drawn in, for scenes without SfM points: its centre
    /// and half side.
    ///
    /// NeRF-synthetic scenes use the reference's box, ±1.3 around the origin, where their
    /// objects are by construction. Other scenes centre the box where the training cameras'
    /// optical axes converge, with half side half the cameras' radius; the cameras' mean is a
    /// poor centre for a capture from one side (the lego cameras' mean is 2.3 units above the
    /// object, and a box there left the object without a single initial point), so it is only
    /// the fallback when the axes do not converge within the cameras' extent. A forward-facing
    /// rig, whose axes meet in front of it beyond its extent, gets a box there as wide as its
    /// mean view at that depth.
    pub fn random_init_box(&self) -> ([f64; 3], f64) {
        if self.format == SceneFormat::NerfSynthetic {
            // The reference's box is in the dataset's own frame.
            return (
                self.frame.to_train([0.0; 3]),
                self.frame.length_to_train(NERF_SYNTHETIC_INIT_HALF_SIDE),
            );
        }
        let half = self.extent / 1.1 * 0.5;
        let Some(p) = split::axes_convergence_point(&self.views, &self.train) else {
            return (self.center, half);
        };
        let dist =
            |a: [f64; 3], b: [f64; 3]| (0..3).map(|k| (a[k] - b[k]).powi(2)).sum::<f64>().sqrt();
        if dist(p, self.center) <= self.extent {
            return (p, half);
        }
        // A forward-facing rig (Neural 3D Video's cameras): the cameras stand close together
        // relative to the depth they look at, so the point their axes meet lies beyond their
        // radius, and a box of that radius would hold a sliver of what they see. Such a point
        // in front of every camera, within ten radii, centres a box as wide as the mean view
        // at that depth.
        let train: Vec<&View> = self.train_views().collect();
        let in_front = train.iter().all(|v| v.pose.transform(p)[2] > 0.0);
        if !in_front || dist(p, self.center) > 10.0 * self.extent || train.is_empty() {
            return (self.center, half);
        }
        let seen: f64 = train
            .iter()
            .map(|v| {
                let (fx, fy) = v.camera.fov();
                dist(v.pose.center(), p) * (0.5 * fx.max(fy)).tan()
            })
            .sum::<f64>()
            / train.len() as f64;
        (p, seen.max(half))
    }

    /// Loads the scene in `root`, detecting its format, in the training frame ([`frame`]).
    pub fn load(root: &Path, opts: &LoadOptions) -> anyhow::Result<Scene> {
        let scene = Self::load_in_file_frame(root, opts)?;
        scene.check_coordinates()?;
        Ok(scene.into_training_frame())
    }

    /// Refuses camera centres and SfM points past [`MAX_COORDINATE`] from the origin: finite,
    /// but no survey or georeferenced frame reaches them (Earth-centred coordinates in
    /// millimetres stay below 10¹⁰), and their squares and the scene's extent overflow or lose
    /// every digit of the scene itself.
    pub fn check_coordinates(&self) -> anyhow::Result<()> {
        let far = |p: &[f64; 3]| p.iter().any(|v| v.is_nan() || v.abs() > MAX_COORDINATE);
        let fix = "the reconstruction diverged or the file is corrupt: export the model again, or \
                   remove the record";
        if let Some(v) = self.views.iter().find(|v| far(&v.pose.center())) {
            return crate::error::bad_input(
                &self.root,
                format!("view {} pose", v.name),
                format!(
                    "puts its camera at {:?}, beyond {MAX_COORDINATE:e} units from the origin",
                    v.pose.center()
                ),
                fix,
            );
        }
        if let Some(points) = &self.points {
            if let Some(i) = points.positions.iter().position(far) {
                return crate::error::bad_input(
                    &self.root,
                    format!("SfM point {}", points.ids.get(i).map_or(i as u64, |&id| id)),
                    format!(
                        "lies at {:?}, beyond {MAX_COORDINATE:e} units from the origin",
                        points.positions[i]
                    ),
                    fix,
                );
            }
        }
        Ok(())
    }

    /// Moves a scene loaded in its files' frame into the training frame ([`frame`]): the
    /// frame is fitted to every view's camera centre, and the poses, points, centre and
    /// extent are mapped through it.
    pub fn into_training_frame(mut self) -> Scene {
        let centres: Vec<[f64; 3]> = self.views.iter().map(|v| v.pose.center()).collect();
        let fitted = SceneFrame::fit(&centres, self.points.as_ref());
        for v in &mut self.views {
            v.pose = fitted.pose_to_train(&v.pose);
        }
        if let Some(p) = &mut self.points {
            fitted.points_to_train(p);
        }
        (self.center, self.extent) = split::camera_extent(&self.views, &self.train);
        // Composed with a frame the scene may already have been given.
        self.frame = SceneFrame {
            origin: self.frame.to_user(fitted.origin),
            scale: self.frame.scale * fitted.scale,
        };
        self
    }

    /// Loads the scene in `root` as its files give it (their frame, no normalisation).
    pub fn load_in_file_frame(root: &Path, opts: &LoadOptions) -> anyhow::Result<Scene> {
        if !root.exists() {
            return crate::error::bad_input(
                root,
                "scene folder",
                "does not exist",
                "pass a folder holding sparse/0 (COLMAP) and images/, or transforms*.json",
            );
        }
        if video::VideoScene::detect(root).is_some() {
            return Ok(video::VideoScene::load(root, opts, opts.frames)?.to_scene());
        }
        if let Some(sparse) = colmap::find_sparse_dir(root) {
            return colmap::load_scene(root, &sparse, opts);
        }
        if root.join("transforms_train.json").exists() || root.join("transforms.json").exists() {
            return transforms::load_scene(root, opts);
        }
        crate::error::bad_input(
            root,
            "scene folder",
            "holds neither a COLMAP model (sparse/0/cameras.bin|txt or sparse/cameras.bin|txt), transforms*.json, nor a video scene (poses_bounds.npy or train_meta.json)",
            scene_nearby(root),
        )
    }

    /// The times of `views` when the scene is a video's frames (f32, as the renderers take
    /// them); `None` for a still scene.
    pub fn times_of(&self, views: &[usize]) -> Option<Vec<f32>> {
        let t = self.view_times.as_ref()?;
        Some(views.iter().map(|&v| t[v] as f32).collect())
    }

    pub fn train_views(&self) -> impl Iterator<Item = &View> {
        self.train.iter().map(|&i| &self.views[i])
    }

    pub fn test_views(&self) -> impl Iterator<Item = &View> {
        self.test.iter().map(|&i| &self.views[i])
    }
}

/// Whether `dir` holds a scene [`Scene::load`] recognises (by its files, without loading it).
fn holds_scene(dir: &Path) -> bool {
    dir.is_dir()
        && (video::VideoScene::detect(dir).is_some()
            || colmap::find_sparse_dir(dir).is_some()
            || dir.join("transforms_train.json").exists()
            || dir.join("transforms.json").exists())
}

/// The fix for a path that holds no scene: the scene folder it lies in (a file of a scene, its
/// sparse/0 or images/ folder), or the scenes it holds (a folder of scenes).
fn scene_nearby(path: &Path) -> String {
    // Absolute, so that `sparse/0` given from inside the scene finds it too.
    let abs = path.canonicalize().unwrap_or_else(|_| path.to_path_buf());
    if let Some(up) = abs.ancestors().skip(1).take(3).find(|a| holds_scene(a)) {
        return format!(
            "point at the scene's top folder, {}, which holds this path",
            up.display()
        );
    }
    let mut inside: Vec<String> = std::fs::read_dir(path)
        .into_iter()
        .flatten()
        .flatten()
        .filter(|e| holds_scene(&e.path()))
        .map(|e| e.file_name().to_string_lossy().into_owned())
        .collect();
    inside.sort();
    match inside.len() {
        0 => "point at the scene's top folder".to_string(),
        n => format!(
            "this folder holds {n} scene{}: point at one of them ({}{})",
            if n == 1 { "" } else { "s" },
            inside[..n.min(6)].join(", "),
            if n > 6 { ", …" } else { "" }
        ),
    }
}

/// The training resolution for a source image of `width` × `height`: Inria's rule.
pub fn target_size(width: u32, height: u32, opts: &LoadOptions) -> (u32, u32) {
    let scale = match opts.resolution_factor {
        Some(r) if r > 1 => 1.0 / r as f64,
        Some(_) => 1.0,
        None if width > opts.max_width => opts.max_width as f64 / width as f64,
        None => 1.0,
    };
    let w = ((width as f64 * scale).round() as u32).max(1);
    let h = ((height as f64 * scale).round() as u32).max(1);
    (w, h)
}
