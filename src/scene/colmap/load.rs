//! From a raw [`ColmapModel`] to a checked [`Scene`].

use std::collections::HashMap;
use std::path::{Path, PathBuf};

use rayon::prelude::*;

use super::{models, ColmapImage, ColmapModel, ModelFiles};
use crate::error::{bad_input, InputError};
use crate::scene::undistort::undistort_pixel;
use crate::scene::{
    split, target_size, CameraModel, Keypoints, LoadOptions, PinholeCamera, Pose, Scene,
    SceneFormat, SfmPoints, View,
};

/// A checked camera record.
struct Camera {
    model: CameraModel,
    width: u32,
    height: u32,
}

const FIX_EXPORT: &str = "the model is inconsistent; export it again from COLMAP";

fn check_cameras(model: &ColmapModel, file: &Path) -> anyhow::Result<HashMap<u32, Camera>> {
    let mut cameras = HashMap::new();
    for c in &model.cameras {
        let field = |what: &str| format!("camera {} {what}", c.id);
        let cam_model = models::to_camera_model(c, file)?;
        if c.width == 0 || c.height == 0 {
            return bad_input(
                file,
                field("width/height"),
                format!("is {}x{}; an image cannot be empty", c.width, c.height),
                "write the size of the camera's images",
            );
        }
        let (Ok(width), Ok(height)) = (u32::try_from(c.width), u32::try_from(c.height)) else {
            return bad_input(
                file,
                field("width/height"),
                format!("{}x{} is too large", c.width, c.height),
                FIX_EXPORT,
            );
        };
        if let Some(k) = c.params.iter().position(|p| !p.is_finite()) {
            return bad_input(
                file,
                field(&format!("params[{k}]")),
                format!("is {} (not a finite number)", c.params[k]),
                "recalibrate or export the model again",
            );
        }
        let (fx, fy, _, _) = cam_model.pinhole_part();
        if !(fx > 0.0 && fy > 0.0) {
            return bad_input(
                file,
                field("focal length"),
                format!("fx = {fx}, fy = {fy}; focal lengths must be positive"),
                "recalibrate or export the model again",
            );
        }
        if cameras
            .insert(
                c.id,
                Camera {
                    model: cam_model,
                    width,
                    height,
                },
            )
            .is_some()
        {
            return bad_input(file, field("id"), "appears twice", FIX_EXPORT);
        }
    }
    Ok(cameras)
}

/// Checks an image record's own fields and its camera; returns its camera.
fn check_image<'a>(
    im: &ColmapImage,
    cameras: &'a HashMap<u32, Camera>,
    files: &ModelFiles,
) -> anyhow::Result<&'a Camera> {
    let file = &files.images;
    let field = |what: &str| format!("image {} ({}) {what}", im.id, im.name);
    let Some(cam) = cameras.get(&im.camera_id) else {
        let mut known: Vec<u32> = cameras.keys().copied().collect();
        known.sort_unstable();
        return bad_input(
            file,
            field("camera_id"),
            format!(
                "camera {} does not exist in {} (cameras there: {known:?})",
                im.camera_id,
                files.cameras.display()
            ),
            "add the camera to the cameras file or fix the image's camera_id",
        );
    };
    if im.qvec.iter().chain(&im.tvec).any(|v| !v.is_finite()) {
        return bad_input(
            file,
            field("qvec/tvec"),
            format!("pose {:?} {:?} is not finite", im.qvec, im.tvec),
            "the reconstruction failed for this image; remove it from the model or reconstruct again",
        );
    }
    if im.qvec.iter().all(|&q| q == 0.0) {
        return bad_input(
            file,
            field("qvec"),
            "is all zeros, not a rotation",
            FIX_EXPORT,
        );
    }
    if let Some(k) = im
        .points2d
        .iter()
        .position(|p| !p[0].is_finite() || !p[1].is_finite())
    {
        return bad_input(
            file,
            field(&format!("points2D[{k}]")),
            format!("{:?} is not finite", im.points2d[k]),
            FIX_EXPORT,
        );
    }
    if im.name.is_empty() {
        return bad_input(file, field("name"), "is empty", FIX_EXPORT);
    }
    Ok(cam)
}

/// Checks that an image exists on disk with the size its camera says (reading only the header).
fn check_image_file(
    im: &ColmapImage,
    cam: &Camera,
    path: &Path,
    files: &ModelFiles,
) -> anyhow::Result<()> {
    let field = format!(
        "image {} '{}' listed in {}",
        im.id,
        im.name,
        files.images.display()
    );
    if !path.is_file() {
        return bad_input(
            path,
            field,
            "is listed in the model but missing on disk",
            "copy the image into the scene's images/ folder, or remove it from the model",
        );
    }
    let (w, h) = image::image_dimensions(path).map_err(|e| {
        InputError::new(
            path,
            &field,
            format!("cannot read the image header: {e}"),
            "replace the file with a readable JPEG or PNG",
        )
    })?;
    crate::scene::images::check_file_complete(path)?;
    if (w, h) != (cam.width, cam.height) {
        return bad_input(
            path,
            format!("{field}: width x height"),
            format!(
                "is {w}x{h} on disk, but camera {} in {} says {}x{}",
                im.camera_id,
                files.cameras.display(),
                cam.width,
                cam.height
            ),
            "use the images the model was built from (not resized copies), or scale the model with them",
        );
    }
    Ok(())
}

/// The scene's own downscaled copy of an image for `-r N`, as Mip-NeRF 360 and LLFF scenes
/// ship them (`images_2/`, `images_4/`, `images_8/` beside `images/`, each image at 1/N of
/// the size, rounded either way): its path, the camera scaled to it and its size. `None`
/// without `-r N` or without such a folder; a folder that lacks the image, or holds it at
/// another size, is an error naming the file (a stale or partial copy would train on the
/// wrong pixels).
fn downscaled_copy(
    root: &Path,
    im: &ColmapImage,
    cam: &Camera,
    opts: &LoadOptions,
) -> anyhow::Result<Option<(PathBuf, crate::scene::CameraModel, u32, u32)>> {
    let Some(r) = opts.resolution_factor.filter(|&r| r > 1) else {
        return Ok(None);
    };
    let dir = root.join(format!("images_{r}"));
    if !dir.is_dir() {
        return Ok(None);
    }
    let path = dir.join(&im.name);
    let fix = format!(
        "regenerate {} from images/ at 1/{r} of the size, or remove the folder to downscale \
         images/ on loading",
        dir.display()
    );
    if !path.is_file() {
        return bad_input(
            &path,
            format!("image {} '{}'", im.id, im.name),
            format!("is in images/ but missing from images_{r}/, which -r {r} reads"),
            fix,
        );
    }
    let (w, h) = image::image_dimensions(&path).map_err(|e| {
        InputError::new(
            &path,
            "image header",
            format!("cannot be read: {e}"),
            "replace the file with a readable JPEG or PNG",
        )
    })?;
    let near = |got: u32, full: u32| (got as f64 - full as f64 / r as f64).abs() <= 1.0;
    if !(near(w, cam.width) && near(h, cam.height)) {
        return bad_input(
            &path,
            "width x height",
            format!(
                "is {w}x{h}, but 1/{r} of the camera's {}x{} is {:.1}x{:.1}",
                cam.width,
                cam.height,
                cam.width as f64 / r as f64,
                cam.height as f64 / r as f64
            ),
            fix,
        );
    }
    let model = cam
        .model
        .scaled(w as f64 / cam.width as f64, h as f64 / cam.height as f64);
    Ok(Some((path, model, w, h)))
}

/// Keypoints in the view's pixels, and for each COLMAP point2D index the keypoint index it
/// became (`None` when its undistortion failed and it was dropped).
fn map_keypoints(
    im: &ColmapImage,
    cam: &Camera,
    view_camera: &PinholeCamera,
) -> (Keypoints, Vec<Option<u32>>) {
    let sx = view_camera.width as f64 / cam.width as f64;
    let sy = view_camera.height as f64 / cam.height as f64;
    let mut kp = Keypoints::default();
    let mut index = Vec::with_capacity(im.points2d.len());
    for (xy, &id) in im.points2d.iter().zip(&im.point3d_ids) {
        match undistort_pixel(&cam.model, xy[0], xy[1]) {
            Some([u, v]) => {
                index.push(Some(kp.xy.len() as u32));
                kp.xy.push([u * sx, v * sy]);
                kp.point3d.push(id);
            }
            None => index.push(None),
        }
    }
    (kp, index)
}

/// Checks `model` against itself and the images under `root/images`, and builds the scene.
pub fn build_scene(
    root: &Path,
    sparse: &Path,
    binary: bool,
    model: &ColmapModel,
    opts: &LoadOptions,
) -> anyhow::Result<Scene> {
    let files = ModelFiles::new(sparse, binary);
    let cameras = check_cameras(model, &files.cameras)?;
    if model.images.is_empty() {
        return bad_input(
            &files.images,
            "images",
            "the model has no images",
            "reconstruct again: COLMAP registered no image, so there is nothing to train on",
        );
    }
    let mut order: Vec<&ColmapImage> = model.images.iter().collect();
    order.sort_by(|a, b| a.name.cmp(&b.name).then(a.id.cmp(&b.id)));
    let mut view_of_image = HashMap::new();
    for (k, im) in order.iter().enumerate() {
        if view_of_image.insert(im.id, k).is_some() {
            return bad_input(
                &files.images,
                format!("image {} id", im.id),
                "appears twice",
                FIX_EXPORT,
            );
        }
        if k > 0 && order[k - 1].name == im.name {
            return bad_input(
                &files.images,
                format!("image {} name", im.id),
                format!(
                    "'{}' is also the name of image {}",
                    im.name,
                    order[k - 1].id
                ),
                FIX_EXPORT,
            );
        }
    }
    let point_ids: HashMap<u64, ()> = model.points.iter().map(|p| (p.id, ())).collect();
    let images_dir = root.join("images");

    let built: Vec<anyhow::Result<(View, Vec<Option<u32>>)>> = order
        .par_iter()
        .map(|im| {
            let cam = check_image(im, &cameras, &files)?;
            if let Some(k) = im
                .point3d_ids
                .iter()
                .position(|&id| id != -1 && (id < 0 || !point_ids.contains_key(&(id as u64))))
            {
                return bad_input(
                    &files.images,
                    format!("image {} ({}) points2D[{k}] point3D_id", im.id, im.name),
                    format!(
                        "{} is not a point in {}",
                        im.point3d_ids[k],
                        files.points.display()
                    ),
                    FIX_EXPORT,
                );
            }
            let full_size: PathBuf = images_dir.join(&im.name);
            check_image_file(im, cam, &full_size, &files)?;
            let (image_path, source_model, source_width, source_height) =
                match downscaled_copy(root, im, cam, opts)? {
                    Some(copy) => copy,
                    None => (full_size, cam.model, cam.width, cam.height),
                };
            let (fx, fy, cx, cy) = cam.model.pinhole_part();
            let (tw, th) = target_size(cam.width, cam.height, opts);
            let pinhole = PinholeCamera {
                fx,
                fy,
                cx,
                cy,
                width: cam.width,
                height: cam.height,
            };
            let camera = pinhole.resized(tw, th);
            let (keypoints, index) = map_keypoints(im, cam, &camera);
            let stem = Path::new(&im.name)
                .file_stem()
                .map(|s| s.to_string_lossy().into_owned())
                .unwrap_or_default();
            let view = View {
                name: im.name.clone(),
                stem,
                image_path,
                source_model,
                source_width,
                source_height,
                camera,
                pose: Pose::from_qvec_tvec(im.qvec, im.tvec),
                colmap_image_id: Some(im.id),
                keypoints: Some(keypoints),
            };
            Ok((view, index))
        })
        .collect();
    let mut views = Vec::with_capacity(built.len());
    let mut keypoint_index = Vec::with_capacity(built.len());
    for b in built {
        let (view, index) = b?;
        views.push(view);
        keypoint_index.push(index);
    }

    let points = build_points(model, &files, &view_of_image, &keypoint_index)?;
    let (train, test) = match split::listed_split(root, &views, opts.eval_split)? {
        Some(listed) => listed,
        None => split::holdout_split(&views, opts.holdout_every, opts.eval_split),
    };
    let (center, extent) = split::camera_extent(&views, &train);
    Ok(Scene {
        root: root.to_path_buf(),
        format: SceneFormat::Colmap {
            sparse_dir: sparse.to_path_buf(),
            binary,
        },
        views,
        train,
        test,
        points: Some(points),
        center,
        extent,
        background: None,
        has_alpha: false,
        view_times: None,
        time_base: None,
        frame: crate::scene::SceneFrame::IDENTITY,
    })
}

/// SfM points sorted by id, tracks turned into (view index, keypoint index).
fn build_points(
    model: &ColmapModel,
    files: &ModelFiles,
    view_of_image: &HashMap<u32, usize>,
    keypoint_index: &[Vec<Option<u32>>],
) -> anyhow::Result<SfmPoints> {
    let file = &files.points;
    let mut order: Vec<usize> = (0..model.points.len()).collect();
    order.sort_by_key(|&i| model.points[i].id);
    let mut out = SfmPoints::default();
    for (k, &i) in order.iter().enumerate() {
        let p = &model.points[i];
        if k > 0 && model.points[order[k - 1]].id == p.id {
            return bad_input(
                file,
                format!("point3D {} id", p.id),
                "appears twice",
                FIX_EXPORT,
            );
        }
        if p.xyz.iter().any(|v| !v.is_finite()) {
            return bad_input(
                file,
                format!("point3D {} xyz", p.id),
                format!("{:?} is not finite", p.xyz),
                "remove the point from the model or export it again",
            );
        }
        let mut track = Vec::with_capacity(p.track.len());
        for (t, &(image_id, idx)) in p.track.iter().enumerate() {
            let Some(&view) = view_of_image.get(&image_id) else {
                return bad_input(
                    file,
                    format!("point3D {} track[{t}] image_id", p.id),
                    format!(
                        "image {image_id} does not exist in {}",
                        files.images.display()
                    ),
                    FIX_EXPORT,
                );
            };
            let Some(kp) = keypoint_index[view].get(idx as usize) else {
                return bad_input(
                    file,
                    format!("point3D {} track[{t}] point2D_idx", p.id),
                    format!(
                        "image {image_id} has {} keypoints, index {idx} is out of range",
                        keypoint_index[view].len()
                    ),
                    FIX_EXPORT,
                );
            };
            // A keypoint whose undistortion failed is gone, and so is its observation.
            if let Some(kp) = kp {
                track.push((view as u32, *kp));
            }
        }
        out.ids.push(p.id);
        out.positions.push(p.xyz);
        out.colors.push(p.rgb);
        out.errors.push(p.error);
        out.tracks.push(track);
    }
    Ok(out)
}
