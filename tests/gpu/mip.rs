//! Mip-Splatting's 3D filter computed on the GPU (`render::filter3d`) against the f64 reference
//! (`reference::mip::filter3d`), with the camera buffer holding test cameras that must be
//! ignored, Gaussians seen by no training camera, and a resize.

use lpmsplat::gpu::{GpuBuffer, GpuContext, GpuOptions, Recorder};
use lpmsplat::reference::mip;
use lpmsplat::reference::scenes::random_view;
use lpmsplat::render::filter3d::SmoothingFilter;
use lpmsplat::render::layout::CameraGpu;
use lpmsplat::scene::{PinholeCamera, Pose};
use rand::{Rng, SeedableRng};
use rand_pcg::Pcg64;
use std::sync::Arc;

fn ctx() -> Arc<GpuContext> {
    GpuContext::new(&GpuOptions::for_tests()).expect("a Vulkan device with the validation layer")
}

/// The camera as the GPU sees it (f32), back in f64, so both sides test the same numbers.
fn rounded(c: &CameraGpu) -> (PinholeCamera, Pose) {
    let row = |r: [f32; 4]| [r[0] as f64, r[1] as f64, r[2] as f64];
    (
        PinholeCamera {
            fx: c.intrinsics[0] as f64,
            fy: c.intrinsics[1] as f64,
            cx: c.intrinsics[2] as f64,
            cy: c.intrinsics[3] as f64,
            width: c.size[0],
            height: c.size[1],
        },
        Pose {
            rotation: [row(c.r0), row(c.r1), row(c.r2)],
            translation: [c.r0[3] as f64, c.r1[3] as f64, c.r2[3] as f64],
        },
    )
}

#[test]
fn gpu_filter_matches_the_reference() {
    let ctx = ctx();
    let mut rng = Pcg64::seed_from_u64(0xF3D);
    let cams: Vec<CameraGpu> = (0..9)
        .map(|k| {
            let (c, p) = random_view(&mut rng, 60 + 10 * k, 80 - 5 * k);
            CameraGpu::new(&c, &p)
        })
        .collect();
    // Views 2 and 5 are test views: not used.
    let train: Vec<usize> = (0..cams.len()).filter(|v| *v != 2 && *v != 5).collect();
    let cameras = GpuBuffer::from_slice(&ctx, "cameras", &cams).unwrap();
    let mut filter = SmoothingFilter::new(&ctx, &cams, &train, 16).unwrap();
    for n in [3_000usize, 7_000] {
        // Most inside the cameras' view, some far outside (unseen), some near a camera.
        let positions: Vec<f32> = (0..3 * n)
            .map(|k| {
                if k % 97 == 0 {
                    40.0
                } else {
                    rng.gen_range(-2.5f32..2.5)
                }
            })
            .collect();
        filter.reserve(n).unwrap();
        let pos = GpuBuffer::from_slice(&ctx, "positions", &positions).unwrap();
        filter
            .values()
            .upload(&vec![f32::NAN; filter.values().len()])
            .unwrap();
        let mut rec = Recorder::new(&ctx).unwrap();
        filter.record_update(&mut rec, &pos, &cameras, n).unwrap();
        rec.submit_and_wait().unwrap();
        let got = filter.values().read_range(0, n).unwrap();
        let train_views: Vec<(PinholeCamera, Pose)> =
            train.iter().map(|&v| rounded(&cams[v])).collect();
        let points: Vec<[f64; 3]> = positions
            .chunks(3)
            .map(|p| [p[0] as f64, p[1] as f64, p[2] as f64])
            .collect();
        let want = mip::filter3d(&points, &train_views).unwrap();
        // A centre within f32 rounding of the frustum margin or the depth limit may fall on
        // either side: a few such Gaussians are allowed, the rest agree to f32 precision.
        let off = got
            .iter()
            .zip(&want)
            .filter(|(&g, &w)| (g as f64 - w).abs() > 1e-5 * w.abs())
            .count();
        assert!(off * 200 <= n, "{off} of {n} filters differ");
        let unseen = want
            .iter()
            .filter(|&&w| (w - want.iter().copied().fold(0.0, f64::max)).abs() < 1e-15)
            .count();
        assert!(
            unseen >= n / 100,
            "the scene should leave some Gaussians unseen"
        );
        assert!(got.iter().all(|v| v.is_finite() && *v > 0.0));
    }
    // Too small a buffer is refused with the fix.
    let mut rec = Recorder::new(&ctx).unwrap();
    let pos = GpuBuffer::from_slice(&ctx, "positions", &vec![0.0f32; 3 * 20_000]).unwrap();
    let e = filter
        .record_update(&mut rec, &pos, &cameras, 20_000)
        .unwrap_err()
        .to_string();
    assert!(e.contains("reserve"), "{e}");
    ctx.check_validation().unwrap();
}
