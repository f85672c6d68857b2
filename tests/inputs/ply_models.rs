//! Which base model a PLY belongs to: each model reads its own files (2DGS also in the official
//! two-scale layout), refuses another model's where it would draw them wrongly, with an error
//! naming the file, the property and the `--model` to pass, and warns where a 3D Gaussian model
//! reads a file of surfels.

use std::path::Path;

use lpmsplat::error::InputError;
use lpmsplat::models::BaseModel;
use lpmsplat::splats::init::random_init;
use lpmsplat::splats::{write_ply, GaussianParams};

fn model(n: usize, degree: u32, seed: u64) -> GaussianParams {
    random_init(n, [0.0; 3], [1.0; 3], seed, degree).unwrap()
}

fn written(dir: &Path, name: &str, params: &GaussianParams) -> std::path::PathBuf {
    let path = dir.join(name);
    write_ply(&path, params).unwrap();
    path
}

/// `err` is an [`InputError`] for `path` whose field mentions `field` and whose fix names `fix`.
fn assert_refused(err: &anyhow::Error, path: &Path, field: &str, fix: &str) {
    let text = format!("{err:#}");
    let ie = err
        .downcast_ref::<InputError>()
        .unwrap_or_else(|| panic!("not an InputError: {text}"));
    assert_eq!(ie.file, path, "{text}");
    assert!(
        ie.field.contains(field),
        "field {:?} lacks {field:?}: {text}",
        ie.field
    );
    assert!(
        ie.fix.contains(fix),
        "fix {:?} lacks {fix:?}: {text}",
        ie.fix
    );
}

/// The official 2DGS code's PLY: the Inria layout without `scale_2`, as ASCII.
fn official_2dgs_ply(params: &GaussianParams) -> String {
    let n = params.len();
    let rest = params.sh_rest.len() / n / 3;
    let mut h = format!("ply\nformat ascii 1.0\nelement vertex {n}\n");
    let mut names: Vec<String> = [
        "x", "y", "z", "nx", "ny", "nz", "f_dc_0", "f_dc_1", "f_dc_2",
    ]
    .map(String::from)
    .to_vec();
    names.extend((0..3 * rest).map(|k| format!("f_rest_{k}")));
    names.extend(
        [
            "opacity", "scale_0", "scale_1", "rot_0", "rot_1", "rot_2", "rot_3",
        ]
        .map(String::from),
    );
    for name in &names {
        h.push_str(&format!("property float {name}\n"));
    }
    h.push_str("end_header\n");
    for i in 0..n {
        let mut row: Vec<f32> = params.positions[i].to_vec();
        row.extend([0.0; 3]);
        row.extend(params.sh_dc[i]);
        // Channel-major in the file, coefficient-major in memory.
        for c in 0..3 {
            row.extend((0..rest).map(|k| params.sh_rest[(i * rest + k) * 3 + c]));
        }
        row.push(params.opacity_logits[i]);
        row.extend(&params.log_scales[i][..2]);
        row.extend(params.rotations[i]);
        let text: Vec<String> = row.iter().map(|v| format!("{v:e}")).collect();
        h.push_str(&text.join(" "));
        h.push('\n');
    }
    h
}

#[test]
fn a_2dgs_model_reads_in_both_layouts_and_refuses_3d_gaussians() {
    let dir = tempfile::tempdir().unwrap();
    let surfels = BaseModel::Surfels2d.initialise(model(50, 1, 3), 3);
    // Ours: the Inria layout with the unused third log-scale.
    let ours = written(dir.path(), "ours.ply", &surfels);
    let read = BaseModel::Surfels2d.read_ply(&ours).unwrap();
    assert_eq!(read.log_scales, surfels.log_scales);
    // The official layout: two scales; the third becomes the surfel's unused one.
    let official = dir.path().join("official.ply");
    std::fs::write(&official, official_2dgs_ply(&surfels)).unwrap();
    let read = BaseModel::Surfels2d.read_ply(&official).unwrap();
    assert_eq!(read.len(), 50);
    assert_eq!(read.positions, surfels.positions);
    assert_eq!(read.log_scales, surfels.log_scales);
    assert_eq!(read.rotations, surfels.rotations);
    assert_eq!(read.sh_rest, surfels.sh_rest);
    // A still format takes either layout as the flat discs they draw as.
    assert_eq!(BaseModel::read_still_ply(&official).unwrap(), read);
    assert_eq!(BaseModel::read_still_ply(&ours).unwrap(), surfels);
    // As 3D Gaussians the two-scale file lacks scale_2, and the error says what it is.
    let e = BaseModel::Gaussians3d.read_ply(&official).unwrap_err();
    assert_refused(&e, &official, "property scale_2", "--model 2dgs");
    // Ours read as 3D Gaussians: drawn as flat discs, with a warning naming the flag.
    let params = BaseModel::Gaussians3d.read_ply(&ours).unwrap();
    let w = BaseModel::Gaussians3d
        .check_ply_shape(&ours, &params)
        .unwrap()
        .expect("a file of surfels read as 3dgs is warned about");
    assert!(w.contains("--model 2dgs"), "{w}");
    // 3D Gaussians read as surfels: refused at the first Gaussian that is not flat.
    let mut gaussians = model(50, 1, 4);
    gaussians.log_scales.iter_mut().for_each(|l| l[2] = -30.0);
    gaussians.log_scales[17] = [-2.0, -2.5, -3.0];
    let path = written(dir.path(), "gaussians.ply", &gaussians);
    let e = BaseModel::Surfels2d.read_ply(&path).unwrap_err();
    assert_refused(&e, &path, "vertex 17, property scale_2", "--model 3dgs");
    assert!(BaseModel::Gaussians3d
        .check_ply_shape(&path, &BaseModel::Gaussians3d.read_ply(&path).unwrap())
        .unwrap()
        .is_none());
    // A surfel whose two scales shrank far (its third only shrinks from -20) is still one.
    let mut tiny = surfels.clone();
    tiny.log_scales[5] = [-40.0, -41.0, -20.0 - 1.6f32.ln()];
    let path = written(dir.path(), "tiny.ply", &tiny);
    assert_eq!(
        BaseModel::Surfels2d.read_ply(&path).unwrap().log_scales[5],
        tiny.log_scales[5]
    );
}

#[test]
fn a_spacetime_model_is_read_only_as_itself() {
    let dir = tempfile::tempdir().unwrap();
    let still = written(dir.path(), "still.ply", &model(20, 0, 1));
    let still_surfels = BaseModel::Surfels2d.initialise(model(20, 0, 1), 1);
    let still_surfels = written(dir.path(), "surfels.ply", &still_surfels);
    let lite_params = BaseModel::SpacetimeLite.initialise(model(20, 0, 1), 1);
    let full_params = BaseModel::SpacetimeFull.initialise(model(20, 0, 1), 1);
    let lite = written(dir.path(), "lite.ply", &lite_params);
    let full = written(dir.path(), "full.ply", &full_params);
    assert_eq!(
        BaseModel::SpacetimeLite.read_ply(&lite).unwrap(),
        lite_params
    );
    assert_eq!(
        BaseModel::SpacetimeFull.read_ply(&full).unwrap(),
        full_params
    );
    for m in [
        BaseModel::Gaussians3d,
        BaseModel::PixelGs,
        BaseModel::MipSplatting,
        BaseModel::Surfels2d,
    ] {
        let e = m.read_ply(&lite).unwrap_err();
        assert_refused(&e, &lite, "property trbf_center", "--model spacetime-lite");
        let e = m.read_ply(&full).unwrap_err();
        assert_refused(&e, &full, "property trbf_center", "--model spacetime-full");
        assert!(
            format!("{e:#}").contains(&format!("--model {}", m.name())),
            "{e:#}"
        );
        let own = if m == BaseModel::Surfels2d {
            &still_surfels
        } else {
            &still
        };
        assert!(m.read_ply(own).is_ok());
    }
    for video in [&lite, &full] {
        let e = BaseModel::read_still_ply(video).unwrap_err();
        assert_refused(&e, video, "property trbf_center", "--time");
    }
    assert_eq!(
        BaseModel::read_still_ply(&still).unwrap(),
        BaseModel::Gaussians3d.read_ply(&still).unwrap()
    );
    let e = BaseModel::SpacetimeLite.read_ply(&full).unwrap_err();
    assert_refused(&e, &full, "property f_spec_0", "--model spacetime-full");
    let e = BaseModel::SpacetimeFull.read_ply(&lite).unwrap_err();
    assert_refused(&e, &lite, "property f_spec_0", "--model spacetime-lite");
    // A still model has no temporal groups: the reader names the first one missing.
    let e = BaseModel::SpacetimeLite.read_ply(&still).unwrap_err();
    assert!(
        e.downcast_ref::<InputError>()
            .unwrap()
            .field
            .contains("motion_0"),
        "{e:#}"
    );
}
