//! Frames drawn in bands of tile rows (`lpmsplat::render::bands`): a frame whose pairs pass the
//! renderer's pair limit is drawn band by band, and every output (image, final T, last
//! contributor, feature channels, a decoded image, the surfel maps) is the whole frame's bit
//! for bit, as is a benchmark's next frame recorded with the same plan (dropped once frames fit
//! whole again). The planning pass's
//! per-row counts are checked against the whole frame's tile lists (themselves checked against
//! the f64 reference in gpu_forward.rs), a tile row past the limit is refused with its count,
//! and a banded frame is refused where the backward would read it. The limit is lowered with
//! `Renderer::limit_pairs` so that small scenes need bands; outputs are poisoned first; the
//! validation layer is on.

use lpmsplat::gpu::{GpuBuffer, GpuContext, GpuOptions, Recorder};
use lpmsplat::reference::scenes;
use lpmsplat::reference::surfel::random_surfels;
use lpmsplat::render::bands::FrameWork;
use lpmsplat::render::forward::{Capacity, FeatureChannels, FrameSettings, Renderer};
use lpmsplat::render::layout::CameraGpu;
use lpmsplat::render::surfel::forward::{SurfelFrameSettings, SurfelRenderer};
use lpmsplat::render::surfel::layout::{SurfelConstants, MAPS_STRIDE};
use lpmsplat::splats::gpu::GpuSplats;
use rand::{Rng, SeedableRng};
use std::sync::Arc;

fn ctx() -> Arc<GpuContext> {
    GpuContext::new(&GpuOptions::for_tests()).expect("a Vulkan device with the validation layer")
}

/// Pairs per tile row of the last frame, from its tile ranges.
fn row_pairs(r: &Renderer, cam: &CameraGpu) -> Vec<u64> {
    let ranges = r
        .frame
        .tile_ranges
        .read_range(0, cam.tile_count() as usize)
        .unwrap();
    ranges
        .chunks(cam.tiles_x() as usize)
        .map(|row| row.iter().map(|t| u64::from(t[1] - t[0])).sum())
        .collect()
}

/// Every per-pixel output of the last frame of `r` (the median depth too, where it writes one).
fn outputs(r: &Renderer, cam: &CameraGpu) -> [Vec<u32>; 4] {
    let px = (cam.width() * cam.height()) as usize;
    let bits = |v: Vec<f32>| v.iter().map(|x| x.to_bits()).collect::<Vec<_>>();
    [
        bits(r.read_image().unwrap()),
        bits(r.frame.final_t.read_range(0, px).unwrap()),
        r.frame.last_index.read_range(0, px).unwrap(),
        match r.median_depth_buffer() {
            Some(_) => bits(r.read_median_depth().unwrap()),
            None => Vec::new(),
        },
    ]
}

fn poison(r: &Renderer) {
    if let Some(m) = r.median_depth_buffer() {
        m.upload(&vec![f32::NAN; m.len()]).unwrap();
    }
    let f = &r.frame;
    f.image.upload(&vec![f32::NAN; f.image.len()]).unwrap();
    f.final_t.upload(&vec![f32::NAN; f.final_t.len()]).unwrap();
    f.last_index
        .upload(&vec![u32::MAX; f.last_index.len()])
        .unwrap();
}

/// The limit that makes a frame with these rows take several bands without a row past it.
fn banding_limit(rows: &[u64]) -> u64 {
    let total: u64 = rows.iter().sum();
    (*rows.iter().max().unwrap()).max(total / 4)
}

#[test]
fn a_frame_drawn_in_bands_is_the_whole_frame_bit_for_bit() {
    let ctx = ctx();
    let mut rng = rand_pcg::Pcg64::seed_from_u64(0xBA4D);
    let mut banded_frames = 0;
    for seed in 0..4 {
        let n = rng.gen_range(300..700);
        let g = scenes::random_gaussians(&mut rng, n);
        let (w, h) = (rng.gen_range(100..220), rng.gen_range(90..200));
        let (camera, pose) = scenes::random_view(&mut rng, w, h);
        let cam = CameraGpu::new(&camera, &pose);
        let params = g.to_params(3);
        let splats = GpuSplats::upload(&ctx, &params, n).unwrap();
        let cameras = GpuBuffer::from_slice(&ctx, "cameras", &[cam]).unwrap();
        // 0: colour only; 7: feature channels kept for a backward; the decoder's own count:
        // the decoding rasterizer (SpacetimeGaussians' displayed frames).
        let decoded = seed == 2;
        let channels = match seed % 3 {
            0 => 0,
            1 => 7,
            _ => lpmsplat::reference::decoder::FEATURE_CHANNELS,
        };
        let values: Vec<f32> = (0..n * channels.max(1))
            .map(|_| rng.gen_range(-1.5f32..1.5))
            .collect();
        let feature_buf = GpuBuffer::from_slice(&ctx, "features", &values).unwrap();
        let weights: Vec<f32> = (0..lpmsplat::reference::decoder::WEIGHTS)
            .map(|_| rng.gen_range(-0.5f32..0.5))
            .collect();
        let weight_buf = GpuBuffer::from_slice(&ctx, "decoder", &weights).unwrap();
        let frame = FrameSettings {
            features: (channels > 0).then_some(FeatureChannels {
                values: &feature_buf,
                channels: channels as u32,
                decoded_by: decoded.then_some(&weight_buf),
            }),
            ..FrameSettings::plain(3, [0.2, 0.5, 0.7])
        };
        let label = format!("seed {seed}, {n} Gaussians at {w}×{h}, {channels} channels");

        let mut whole = Renderer::for_camera(&ctx, n, &cam)
            .unwrap()
            .with_median_depth()
            .unwrap();
        whole
            .render_blocking(&splats, &cameras, 0, &cam, &frame)
            .unwrap();
        assert_eq!(whole.last_frame_bands(), 1, "{label}");
        let rows = row_pairs(&whole, &cam);
        let total = whole.last_intersections().unwrap();
        assert_eq!(rows.iter().sum::<u64>(), total, "{label}");
        let want = outputs(&whole, &cam);
        let want_features = match frame.features {
            Some(fc) if fc.decoded_by.is_none() => Some(
                whole
                    .feature_image()
                    .unwrap()
                    .read_range(0, (w * h) as usize * channels)
                    .unwrap(),
            ),
            _ => None,
        };

        let limit = banding_limit(&rows);
        let mut banded = Renderer::new(&ctx, Capacity::for_frame(n, &cam))
            .unwrap()
            .with_median_depth()
            .unwrap();
        banded.limit_pairs(limit);
        poison(&banded);
        banded
            .render_blocking(&splats, &cameras, 0, &cam, &frame)
            .unwrap();
        let bands = banded.bands_for(&cam);
        assert!(
            bands.len() >= 2,
            "{label}: {bands:?} with a limit of {limit}"
        );
        assert_eq!(banded.last_frame_bands(), bands.len(), "{label}");
        banded_frames += 1;
        // The planned counts are the whole frame's rows, and every band fits the limit.
        for b in &bands {
            let rows_sum: u64 = rows[b.first_row as usize..b.end_row as usize].iter().sum();
            assert_eq!(b.pairs, rows_sum, "{label}: band {b:?}");
            assert!(b.pairs <= limit, "{label}: band {b:?}");
        }
        assert_eq!(banded.last_intersections().unwrap(), total, "{label}");
        assert!(banded.capacity().intersections as u64 <= limit, "{label}");
        assert_eq!(outputs(&banded, &cam), want, "{label}: drawn in bands");
        if let Some(f) = &want_features {
            let got = banded
                .feature_image()
                .unwrap()
                .read_range(0, (w * h) as usize * channels)
                .unwrap();
            assert!(
                got.iter().zip(f).all(|(a, b)| a.to_bits() == b.to_bits()),
                "{label}: feature image"
            );
        }
        // The backward cannot read such a frame.
        let err = banded.whole_frame().unwrap_err().to_string();
        assert!(
            err.contains("bands of tile rows") && err.contains("Fix:"),
            "{err}"
        );

        // A benchmark's next frame, recorded with the plan.
        poison(&banded);
        let mut rec = Recorder::new(&ctx).unwrap();
        rec.begin().unwrap();
        let planned = FrameWork::Bands(banded.bands_for(&cam));
        banded
            .record_work(&mut rec, &splats, &cameras, 0, &cam, &frame, &planned, None)
            .unwrap();
        rec.submit_and_wait().unwrap();
        assert!(banded.last_frame_complete().unwrap(), "{label}");
        assert_eq!(outputs(&banded, &cam), want, "{label}: planned frame");

        // A plain record draws the whole frame again (training's frames): it does not fit
        // the limited buffers, and says so.
        let mut rec = Recorder::new(&ctx).unwrap();
        rec.begin().unwrap();
        banded
            .record(&mut rec, &splats, &cameras, 0, &cam, &frame, None)
            .unwrap();
        rec.submit_and_wait().unwrap();
        assert_eq!(banded.last_frame_bands(), 1, "{label}");
        assert!(!banded.last_frame_complete().unwrap(), "{label}");
        assert!(banded.whole_frame().is_ok());
        let refused = banded
            .ensure_capacity(Capacity {
                intersections: total as usize,
                ..banded.capacity()
            })
            .unwrap_err()
            .to_string();
        assert!(
            refused.contains(&format!("{total} (tile, Gaussian) intersections"))
                && refused.contains("training needs"),
            "{refused}"
        );

        // With room for the whole frame, the next frame still follows the plan, finds that
        // the frame fits whole and drops the plan; the one after is drawn whole.
        banded.limit_pairs(total);
        banded
            .render_blocking(&splats, &cameras, 0, &cam, &frame)
            .unwrap();
        assert_eq!(banded.last_frame_bands(), bands.len(), "{label}");
        assert_eq!(banded.bands_for(&cam).len(), 1, "{label}: plan kept");
        poison(&banded);
        banded
            .render_blocking(&splats, &cameras, 0, &cam, &frame)
            .unwrap();
        assert_eq!(banded.last_frame_bands(), 1, "{label}");
        assert_eq!(outputs(&banded, &cam), want, "{label}: whole again");
    }
    assert_eq!(banded_frames, 4);
    ctx.check_validation().unwrap();
}

#[test]
fn a_tile_row_past_the_limit_is_refused_with_its_count() {
    let ctx = ctx();
    let mut rng = rand_pcg::Pcg64::seed_from_u64(0xF011);
    let g = scenes::random_gaussians(&mut rng, 500);
    let (camera, pose) = scenes::random_view(&mut rng, 160, 120);
    let cam = CameraGpu::new(&camera, &pose);
    let params = g.to_params(0);
    let splats = GpuSplats::upload(&ctx, &params, params.len()).unwrap();
    let cameras = GpuBuffer::from_slice(&ctx, "cameras", &[cam]).unwrap();
    let frame = FrameSettings::plain(0, [0.0; 3]);
    let mut whole = Renderer::for_camera(&ctx, params.len(), &cam).unwrap();
    whole
        .render_blocking(&splats, &cameras, 0, &cam, &frame)
        .unwrap();
    let rows = row_pairs(&whole, &cam);
    let total: u64 = rows.iter().sum();
    let (row, &most) = rows
        .iter()
        .enumerate()
        .max_by_key(|(i, &n)| (n, std::cmp::Reverse(*i)))
        .unwrap();
    let mut r = Renderer::for_camera(&ctx, params.len(), &cam).unwrap();
    r.limit_pairs(most - 1);
    let err = format!(
        "{:#}",
        r.render_blocking(&splats, &cameras, 0, &cam, &frame)
            .unwrap_err()
    );
    // The first row (from the top) with that many pairs is named.
    let first = rows.iter().position(|&n| n == most).unwrap();
    assert_eq!(first, row);
    assert!(
        err.contains(&format!("{total} (tile, Gaussian) intersections"))
            && err.contains(&format!("row {first} of 16-px tiles alone has {most}"))
            && err.contains("Fix:"),
        "{err}"
    );
    // At exactly the largest row, the frame is drawn (one band per such row at least).
    r.limit_pairs(most);
    r.render_blocking(&splats, &cameras, 0, &cam, &frame)
        .unwrap();
    assert_eq!(
        outputs(&r, &cam),
        outputs(&whole, &cam),
        "drawn at the limit"
    );
    ctx.check_validation().unwrap();
}

#[test]
fn surfels_drawn_in_bands_are_the_whole_frame_bit_for_bit() {
    let ctx = ctx();
    let mut rng = rand_pcg::Pcg64::seed_from_u64(0x5B4D);
    for seed in 0..2 {
        let n = rng.gen_range(200..500);
        let s = random_surfels(&mut rng, n);
        let (w, h) = (rng.gen_range(100..200), rng.gen_range(90..180));
        let (camera, pose) = scenes::random_view(&mut rng, w, h);
        let cam = CameraGpu::new(&camera, &pose);
        let params = s.to_params(3, 30.0);
        let splats = GpuSplats::upload(&ctx, &params, n).unwrap();
        let cameras = GpuBuffer::from_slice(&ctx, "cameras", &[cam]).unwrap();
        let settings = SurfelFrameSettings {
            sh_degree: 3,
            background: [0.1, 0.4, 0.8],
            constants: SurfelConstants::default(),
        };
        let label = format!("seed {seed}, {n} surfels at {w}×{h}");
        let px = (w * h) as usize;
        let read = |r: &SurfelRenderer| {
            let maps = r.surfel.maps.read_range(0, px * MAPS_STRIDE).unwrap();
            let median = r.surfel.median_index.read_range(0, px).unwrap();
            (
                outputs(&r.base, &cam),
                maps.iter().map(|x| x.to_bits()).collect::<Vec<_>>(),
                median,
            )
        };
        let mut whole = SurfelRenderer::new(&ctx, Capacity::for_frame(n, &cam)).unwrap();
        whole
            .render_blocking(&splats, 3, &cameras, 0, &cam, &settings)
            .unwrap();
        let rows = row_pairs(&whole.base, &cam);
        let want = read(&whole);

        let mut banded = SurfelRenderer::new(&ctx, Capacity::for_frame(n, &cam)).unwrap();
        banded.base.limit_pairs(banding_limit(&rows));
        poison(&banded.base);
        let sf = &banded.surfel;
        sf.maps.upload(&vec![f32::NAN; sf.maps.len()]).unwrap();
        sf.median_index
            .upload(&vec![u32::MAX; sf.median_index.len()])
            .unwrap();
        banded
            .render_blocking(&splats, 3, &cameras, 0, &cam, &settings)
            .unwrap();
        let bands = banded.base.bands_for(&cam);
        assert!(bands.len() >= 2, "{label}: {bands:?}");
        for b in &bands {
            let rows_sum: u64 = rows[b.first_row as usize..b.end_row as usize].iter().sum();
            assert_eq!(b.pairs, rows_sum, "{label}: band {b:?}");
        }
        assert!(read(&banded) == want, "{label}: drawn in bands");
        assert!(banded.base.whole_frame().is_err(), "{label}");
    }
    ctx.check_validation().unwrap();
}
