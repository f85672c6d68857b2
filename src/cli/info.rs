//! `info`: devices, limits, and a scene summary.

use super::SceneArgs;
use clap::Args;
use lpmsplat::gpu::{list_devices, GpuContext, GpuOptions};
use lpmsplat::scene::{Scene, SceneFormat};

#[derive(Args, Debug)]
pub struct InfoArgs {
    /// Scene folder to summarise (optional).
    pub scene: Option<std::path::PathBuf>,
    /// Downscale images by this factor.
    #[arg(short = 'r', long = "resolution")]
    pub resolution: Option<u32>,
    /// NeRF-synthetic: `val` or `test` as the test split.
    #[arg(long, value_parser = ["val", "test"])]
    pub test_split: Option<String>,
    /// A Gaussian model (PLY) to describe: its Gaussians, SH degree and extra groups, the
    /// model its header records (or that it is read as 3DGS when it records none), and the
    /// shift and video segment it is stored with.
    #[arg(long)]
    pub ply: Option<std::path::PathBuf>,
}

pub fn run(gpu: &GpuOptions, args: &InfoArgs) -> anyhow::Result<()> {
    // A scene summary is useful even without a GPU, so scene errors come first.
    let scene = match &args.scene {
        Some(path) => {
            let s = SceneArgs {
                scene: path.clone(),
                resolution: args.resolution,
                test_split: args.test_split.clone(),
                frames: None,
            };
            Some(Scene::load(path, &s.load_options()?)?)
        }
        None => None,
    };
    if let Some(ply) = &args.ply {
        print_ply(ply)?;
    }
    match list_devices() {
        Ok(devices) => {
            println!("Vulkan devices:");
            for (i, name, ty, api) in devices {
                println!("  [{i}] {name} ({ty}, Vulkan {api})");
            }
            let ctx = GpuContext::new(gpu)?;
            println!("{}", ctx.info.summary());
            let digits = lpmsplat::render::sort::Digits::for_device(&ctx);
            let shape = lpmsplat::render::sort::RadixSort::shape_for(&ctx, digits);
            println!(
                "  radix sorts: {digits:?} digits ({}-bit at most), blocks of {} × {} keys",
                digits.max_bits(),
                shape.wg,
                shape.items
            );
            ctx.check_validation()?;
        }
        Err(e) => println!("Vulkan: {e:#}"),
    }
    if let Some(scene) = scene {
        print_scene(&scene);
    }
    Ok(())
}

fn print_ply(path: &std::path::Path) -> anyhow::Result<()> {
    use lpmsplat::models::BaseModel;
    let recorded = BaseModel::recorded_in(path)?;
    let model = recorded.unwrap_or_default();
    let params = model.read_ply(path)?;
    println!("Model {}:", path.display());
    println!(
        "  {} Gaussians, SH degree {}{}",
        params.len(),
        params.sh_degree,
        if params.extra.is_empty() {
            String::new()
        } else {
            format!(
                ", extra groups {}",
                params
                    .extra
                    .iter()
                    .map(|e| format!("{} ({})", e.group.name, e.group.stride))
                    .collect::<Vec<_>>()
                    .join(", ")
            )
        }
    );
    match recorded {
        Some(m) => println!(
            "  model: {} (recorded in its header; eval, render, mesh and bench fps read it so)",
            m.name()
        ),
        None => println!(
            "  model: none recorded (another trainer's file, or one from before lpmsplat \
             recorded it): read as 3dgs unless --model says otherwise"
        ),
    }
    let comments = lpmsplat::splats::ply_comments(path)?;
    let shift = lpmsplat::scene::frame::shift_from_comments(path, &comments)?;
    if shift != [0.0; 3] {
        println!(
            "  positions are stored relative to ({}, {}, {}): add it for the scene's own \
             coordinates",
            shift[0], shift[1], shift[2]
        );
    }
    if let Some(seg) = lpmsplat::scene::video::Segment::from_comments(path, &comments)? {
        println!("  trained on frames {}..{}", seg.start, seg.end());
    }
    Ok(())
}

fn print_scene(scene: &Scene) {
    let format = match &scene.format {
        SceneFormat::Colmap { sparse_dir, binary } => {
            format!(
                "COLMAP ({}, {})",
                if *binary { "binary" } else { "text" },
                sparse_dir.display()
            )
        }
        SceneFormat::NerfSynthetic => "NeRF-synthetic transforms_*.json".to_string(),
        SceneFormat::Nerfstudio => "nerfstudio transforms.json".to_string(),
        SceneFormat::Video => "multi-view video (cameras × frames)".to_string(),
    };
    println!("scene {}", scene.root.display());
    println!("  format: {format}");
    println!(
        "  views: {} ({} train, {} test)",
        scene.views.len(),
        scene.train.len(),
        scene.test.len()
    );
    let mut models: Vec<String> = scene
        .views
        .iter()
        .map(|v| v.source_model.name().to_string())
        .collect();
    models.sort();
    models.dedup();
    println!("  camera models: {}", models.join(", "));
    let mut sizes: Vec<(u32, u32, u32, u32)> = scene
        .views
        .iter()
        .map(|v| {
            (
                v.source_width,
                v.source_height,
                v.camera.width,
                v.camera.height,
            )
        })
        .collect();
    sizes.sort();
    sizes.dedup();
    for (sw, sh, w, h) in sizes {
        println!("  image size: {sw}x{sh} source -> {w}x{h} training");
    }
    if let Some(v) = scene.views.first() {
        let c = &v.camera;
        let (fx, fy) = c.fov();
        println!(
            "  first camera: fx {:.2} fy {:.2} cx {:.2} cy {:.2}, FoV {:.1}°x{:.1}°",
            c.fx,
            c.fy,
            c.cx,
            c.cy,
            fx.to_degrees(),
            fy.to_degrees()
        );
    }
    let names = |ids: &[usize]| {
        ids.iter()
            .map(|&i| scene.views[i].name.as_str())
            .collect::<Vec<_>>()
    };
    let test = names(&scene.test);
    if test.len() <= 12 {
        println!("  test views: {}", test.join(" "));
    }
    match &scene.points {
        Some(p) => {
            let tracks: usize = p.tracks.iter().map(|t| t.len()).sum();
            println!(
                "  SfM points: {} (mean track length {:.2})",
                p.len(),
                tracks as f64 / p.len().max(1) as f64
            )
        }
        None => println!("  SfM points: none (random initialisation)"),
    }
    let kp: usize = scene
        .views
        .iter()
        .filter_map(|v| v.keypoints.as_ref())
        .map(|k| k.xy.len())
        .sum();
    if kp > 0 {
        println!("  keypoints: {kp}");
    }
    if let Some(dir) = scene
        .views
        .first()
        .and_then(|v| v.image_path.parent())
        .and_then(|d| d.file_name())
        .map(|d| d.to_string_lossy().to_string())
        .filter(|d| d.starts_with("images_"))
    {
        println!("  images: the scene's downscaled copies in {dir}/ (for this -r)");
    }
    // The training cameras' centre and extent in the scene's own units, and the frame the
    // scene is trained in (`lpmsplat::scene::frame`).
    let f = &scene.frame;
    let c = f.to_user(scene.center);
    println!(
        "  centre ({}, {}, {}), extent {:.6} (training cameras, the scene's units)",
        c[0],
        c[1],
        c[2],
        scene.extent / f.scale
    );
    println!(
        "  trained in its own frame recentred on ({}, {}, {}) and scaled by {:.6e} (unit extent)",
        f.origin[0], f.origin[1], f.origin[2], f.scale
    );
    let shift = f.output_shift();
    if shift != [0.0; 3] {
        println!(
            "  far from the origin: outputs hold positions relative to ({}, {}, {}), recorded \
             in their headers (comment {})",
            shift[0],
            shift[1],
            shift[2],
            lpmsplat::scene::frame::SHIFT_COMMENT
        );
    }
    if let Some(b) = scene.background {
        println!("  background: ({}, {}, {})", b[0], b[1], b[2]);
    }
}
