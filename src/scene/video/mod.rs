//! Synchronised multi-view video: fixed cameras, each filming the same frames.
//!
//! Two layouts are read:
//! - **Neural 3D Video** ([`n3v`]): `poses_bounds.npy` (LLFF poses, one row per camera) beside
//!   one folder of extracted frames per camera (`cam00/0.png`, … as SpacetimeGaussians'
//!   `pre_n3d.py` writes them). The first camera by name is the test camera.
//! - **Dynamic 3D Gaussians / CMU Panoptic** ([`panoptic`]): `train_meta.json` and
//!   `test_meta.json` with per-frame intrinsics, world-to-camera matrices and file names under
//!   `ims/`, foreground masks under `seg/`.
//!
//! Training works on a segment of frames (SpacetimeGaussians trains 50-frame segments); frame
//! `k` of a segment of `F` frames has time `t = k / F`, the official normalisation. A model
//! trained on a segment carries it in its PLY ([`Segment::comment`]), so that `render` and
//! `eval` load that segment by default and give any part of it the times it had in training
//! ([`LoadOptions::time_base`](super::LoadOptions::time_base)). Only paths are held here:
//! pixels are read per frame when they are needed.

pub mod n3v;
pub mod npy;
pub mod panoptic;

use std::path::{Path, PathBuf};

use super::{split, CameraModel, LoadOptions, PinholeCamera, Pose, Scene, SceneFormat, View};

/// SpacetimeGaussians' segment length: the frames one model covers by default.
pub const SEGMENT_FRAMES: usize = 50;

/// Which frames of the video to train on.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct FrameRange {
    /// First frame (index into each camera's sorted frames).
    pub start: usize,
    /// Number of frames; `None`: [`SEGMENT_FRAMES`], or fewer when the video is shorter.
    pub count: Option<usize>,
}

impl std::str::FromStr for FrameRange {
    type Err = String;
    /// `START..END` (END exclusive) or `START..` (a default-length segment from START).
    fn from_str(s: &str) -> Result<Self, String> {
        let (a, b) = s
            .split_once("..")
            .ok_or_else(|| format!("'{s}' is not START..END (e.g. 0..50)"))?;
        let start: usize = a
            .trim()
            .parse()
            .map_err(|_| format!("'{a}' in '{s}' is not a frame number"))?;
        let count = if b.trim().is_empty() {
            None
        } else {
            let end: usize = b
                .trim()
                .parse()
                .map_err(|_| format!("'{b}' in '{s}' is not a frame number"))?;
            if end <= start {
                return Err(format!("'{s}' is empty: END must be larger than START"));
            }
            Some(end - start)
        };
        Ok(Self { start, count })
    }
}

/// A segment of frames as loaded: the first frame and how many. The segment a model was trained
/// on is its time base: frame `start + k` has time `k / frames`.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Segment {
    pub start: usize,
    pub frames: usize,
}

/// The start of the PLY comment that records a video model's training segment.
const SEGMENT_COMMENT: &str = "lpmsplat video segment";

impl Segment {
    /// One past the last frame.
    pub fn end(&self) -> usize {
        self.start + self.frames
    }

    /// The same frames as a `--frames` range.
    pub fn range(&self) -> FrameRange {
        FrameRange {
            start: self.start,
            count: Some(self.frames),
        }
    }

    /// The PLY comment that records this segment as a model's time base:
    /// `lpmsplat video segment START..END`.
    pub fn comment(&self) -> String {
        format!("{SEGMENT_COMMENT} {}..{}", self.start, self.end())
    }

    /// The segment recorded in a PLY's comments (`path` names the file in errors); `None` when
    /// no comment records one (a still model, or a video model written before models recorded
    /// their segment).
    pub fn from_comments(path: &Path, comments: &[String]) -> anyhow::Result<Option<Segment>> {
        let Some(text) = comments
            .iter()
            .find_map(|c| c.strip_prefix(SEGMENT_COMMENT))
        else {
            return Ok(None);
        };
        match text.trim().parse::<FrameRange>() {
            Ok(FrameRange {
                start,
                count: Some(frames),
            }) => Ok(Some(Segment { start, frames })),
            _ => crate::error::bad_input(
                path,
                format!("header comment `{SEGMENT_COMMENT}{text}`"),
                "is not a segment START..END",
                "fix the comment to the frames the model was trained on (e.g. `lpmsplat video \
                 segment 0..50`) or delete the line",
            ),
        }
    }
}

/// Which layout a video scene came in.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum VideoLayout {
    NeuralVideo,
    Panoptic,
}

/// One fixed camera of a video scene.
#[derive(Debug, Clone, PartialEq)]
pub struct VideoCamera {
    /// `cam00`, `cam01`, … (sorted names are the camera order).
    pub name: String,
    /// The source images' pinhole intrinsics, in source pixels.
    pub source_model: CameraModel,
    pub source_width: u32,
    pub source_height: u32,
    /// The pinhole camera at the training resolution.
    pub camera: PinholeCamera,
    pub pose: Pose,
    /// The segment's frame images, in time order.
    pub frames: Vec<PathBuf>,
    /// Foreground masks per frame, when the scene has them for this camera.
    pub masks: Option<Vec<PathBuf>>,
}

/// A loaded video scene (metadata only).
#[derive(Debug, Clone, PartialEq)]
pub struct VideoScene {
    pub root: PathBuf,
    pub layout: VideoLayout,
    /// Cameras sorted by name.
    pub cameras: Vec<VideoCamera>,
    /// The segment's first frame in the source video.
    pub first_frame: usize,
    /// Frames in the segment (every camera has this many).
    pub frames: usize,
    /// The segment whose normalisation gives the frames their times: the loaded one, or the
    /// one a model was trained on (`LoadOptions::time_base`), which holds the loaded one.
    pub time_base: Segment,
    /// Indices into `cameras`.
    pub train: Vec<usize>,
    pub test: Vec<usize>,
    /// Mean of the training camera centres and 1.1 × their largest distance from it.
    pub center: [f64; 3],
    pub extent: f64,
}

impl VideoScene {
    /// Whether `root` holds a video scene in a layout this module reads.
    pub fn detect(root: &Path) -> Option<VideoLayout> {
        if root.join("train_meta.json").exists() {
            Some(VideoLayout::Panoptic)
        } else if root.join("poses_bounds.npy").exists() && !is_llff_still(root) {
            Some(VideoLayout::NeuralVideo)
        } else {
            None
        }
    }

    /// Loads the video scene in `root` (`opts.resolution_factor` and the width cap apply as for
    /// still scenes).
    /// With `opts.time_base` the frames take their times from that segment (a trained model's),
    /// which must hold the loaded frames.
    pub fn load(root: &Path, opts: &LoadOptions, range: FrameRange) -> anyhow::Result<Self> {
        let mut scene = match Self::detect(root) {
            Some(VideoLayout::Panoptic) => panoptic::load(root, opts, range)?,
            Some(VideoLayout::NeuralVideo) => n3v::load(root, opts, range)?,
            None => crate::error::bad_input(
                root,
                "video scene folder",
                "holds neither train_meta.json (Panoptic / Dynamic 3D Gaussians) nor \
                 poses_bounds.npy (Neural 3D Video)",
                "point at the scene's top folder",
            )?,
        };
        if let Some(base) = opts.time_base {
            let loaded = scene.segment();
            if loaded.start < base.start || loaded.end() > base.end() {
                return crate::error::bad_input(
                    root,
                    "frames",
                    format!(
                        "the frames {}..{} lie outside the segment {}..{} the model was trained \
                         on (a video model knows only the times of its own segment)",
                        loaded.start,
                        loaded.end(),
                        base.start,
                        base.end()
                    ),
                    format!(
                        "pass --frames within {}..{}, or leave it out for the whole segment",
                        base.start,
                        base.end()
                    ),
                );
            }
            scene.time_base = base;
        }
        Ok(scene)
    }

    /// The loaded frames.
    pub fn segment(&self) -> Segment {
        Segment {
            start: self.first_frame,
            frames: self.frames,
        }
    }

    /// The time of loaded frame `frame`: its place in the time base, `(first_frame + frame −
    /// base start) / base frames` (SpacetimeGaussians' normalisation; `frame / frames` when the
    /// loaded segment is the time base).
    pub fn time(&self, frame: usize) -> f64 {
        (self.first_frame + frame - self.time_base.start) as f64 / self.time_base.frames as f64
    }

    /// Camera `camera` at segment frame `frame` as a still view (its image and camera).
    pub fn view(&self, camera: usize, frame: usize) -> View {
        let c = &self.cameras[camera];
        let number = self.first_frame + frame;
        View {
            name: format!("{}/{number:06}", c.name),
            stem: format!("{}_{number:06}", c.name),
            image_path: c.frames[frame].clone(),
            source_model: c.source_model,
            source_width: c.source_width,
            source_height: c.source_height,
            camera: c.camera,
            pose: c.pose,
            colmap_image_id: None,
            keypoints: None,
        }
    }

    /// Every camera at every segment frame as one scene (camera-major: view `c × frames + k` is
    /// camera `c` at frame `k`, which is also name order) with each view's time; the split
    /// follows the cameras (every frame of a test camera is a test view).
    pub fn to_scene(&self) -> Scene {
        let f = self.frames;
        let mut views = Vec::with_capacity(self.cameras.len() * f);
        let mut times = Vec::with_capacity(views.capacity());
        for c in 0..self.cameras.len() {
            for k in 0..f {
                views.push(self.view(c, k));
                times.push(self.time(k));
            }
        }
        let expand = |cams: &[usize]| -> Vec<usize> {
            cams.iter().flat_map(|&c| c * f..(c + 1) * f).collect()
        };
        Scene {
            root: self.root.clone(),
            format: SceneFormat::Video,
            views,
            train: expand(&self.train),
            test: expand(&self.test),
            points: None,
            center: self.center,
            extent: self.extent,
            background: None,
            has_alpha: false,
            view_times: Some(times),
            time_base: Some(self.time_base),
            frame: crate::scene::SceneFrame::IDENTITY,
        }
    }

    /// Segment frame `frame` as a still scene: one view per camera (in camera order, so view
    /// `i` is camera `i`), the same split, centre and extent.
    pub fn frame_scene(&self, frame: usize) -> Scene {
        Scene {
            root: self.root.clone(),
            format: SceneFormat::Video,
            views: (0..self.cameras.len())
                .map(|c| self.view(c, frame))
                .collect(),
            train: self.train.clone(),
            test: self.test.clone(),
            points: None,
            center: self.center,
            extent: self.extent,
            background: None,
            has_alpha: false,
            view_times: None,
            time_base: None,
            frame: crate::scene::SceneFrame::IDENTITY,
        }
    }
}

/// Whether a folder with `poses_bounds.npy` is a still scene in the layout Mip-NeRF 360 and
/// LLFF are distributed in (`images/`, `sparse/0/` and `poses_bounds.npy` side by side, the
/// latter for NeRF codes that read LLFF poses): a COLMAP model and no camera video or frame
/// folder (`cam*`). Only such folders make a Neural 3D Video scene.
fn is_llff_still(root: &Path) -> bool {
    let has_cameras = std::fs::read_dir(root)
        .into_iter()
        .flatten()
        .flatten()
        .any(|e| {
            let name = e.file_name().to_string_lossy().to_string();
            name.starts_with("cam")
                && (e.path().is_dir()
                    || e.path()
                        .extension()
                        .is_some_and(|x| x.eq_ignore_ascii_case("mp4")))
        });
    !has_cameras && crate::scene::colmap::find_sparse_dir(root).is_some()
}

/// Checks the segment against the frames every camera has and returns (start, count).
fn segment(root: &Path, available: usize, range: FrameRange) -> anyhow::Result<(usize, usize)> {
    if range.start >= available {
        return crate::error::bad_input(
            root,
            "frames",
            format!(
                "the segment starts at frame {} but the cameras have {available} frames",
                range.start
            ),
            format!("choose a start below {available} (--frames START..END)"),
        );
    }
    let count = match range.count {
        Some(n) if range.start + n > available => {
            return crate::error::bad_input(
                root,
                "frames",
                format!(
                    "the segment {}..{} runs past the {available} frames every camera has",
                    range.start,
                    range.start + n
                ),
                format!("end the segment at or before {available}"),
            )
        }
        Some(n) => n,
        None => SEGMENT_FRAMES.min(available - range.start),
    };
    Ok((range.start, count))
}

/// Sorts cameras by name and fills the split, centre and extent.
fn finish(
    root: &Path,
    layout: VideoLayout,
    mut cameras: Vec<VideoCamera>,
    test_names: &[String],
    first_frame: usize,
    frames: usize,
) -> anyhow::Result<VideoScene> {
    cameras.sort_by(|a, b| a.name.cmp(&b.name));
    let (train, test): (Vec<usize>, Vec<usize>) =
        (0..cameras.len()).partition(|&i| !test_names.contains(&cameras[i].name));
    if train.is_empty() {
        return crate::error::bad_input(
            root,
            "cameras",
            "every camera is a test camera",
            "a video scene needs at least one training camera",
        );
    }
    let mut scene = VideoScene {
        root: root.to_path_buf(),
        layout,
        cameras,
        first_frame,
        frames,
        time_base: Segment {
            start: first_frame,
            frames,
        },
        train,
        test,
        center: [0.0; 3],
        extent: 1.0,
    };
    let views = scene.frame_scene(0).views;
    (scene.center, scene.extent) = split::camera_extent(&views, &scene.train);
    Ok(scene)
}

/// A camera's source model and its training-size pinhole camera.
fn pinhole(
    [fx, fy, cx, cy]: [f64; 4],
    width: u32,
    height: u32,
    opts: &LoadOptions,
) -> (CameraModel, PinholeCamera) {
    let (tw, th) = super::target_size(width, height, opts);
    let camera = PinholeCamera {
        fx,
        fy,
        cx,
        cy,
        width,
        height,
    }
    .resized(tw, th);
    (CameraModel::Pinhole { fx, fy, cx, cy }, camera)
}
