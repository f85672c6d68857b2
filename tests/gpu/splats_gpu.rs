//! Gaussian parameters survive the trip to GPU buffers and back bit for bit.

use lpmsplat::gpu::{GpuContext, GpuOptions};
use lpmsplat::splats::gpu::{grown_capacity, GpuSplats};
use lpmsplat::splats::random_init;

#[test]
fn upload_download_round_trip_is_bit_exact() {
    let ctx = GpuContext::new(&GpuOptions::for_tests()).unwrap();
    for degree in 0..=3 {
        let mut p = random_init(
            3_001,
            [0.5, -1.0, 2.0],
            [3.0, 1.0, 0.5],
            40 + degree as u64,
            degree,
        )
        .unwrap();
        for (i, v) in p.sh_rest.iter_mut().enumerate() {
            *v = (i as f32 * 0.37).sin() * 1e-3;
        }
        for (i, r) in p.rotations.iter_mut().enumerate() {
            *r = [1.0 + i as f32, -0.5, 0.25, 1e-30];
        }
        let g = GpuSplats::upload(&ctx, &p, grown_capacity(p.len())).unwrap();
        assert!(g.capacity >= p.len() + 1024);
        let back = g.download().unwrap();
        assert_eq!(back.sh_degree, degree);
        let bits = |v: &[f32]| v.iter().map(|x| x.to_bits()).collect::<Vec<_>>();
        assert_eq!(
            bits(bytemuck::cast_slice(&back.positions)),
            bits(bytemuck::cast_slice(&p.positions))
        );
        assert_eq!(
            bits(bytemuck::cast_slice(&back.log_scales)),
            bits(bytemuck::cast_slice(&p.log_scales))
        );
        assert_eq!(
            bits(bytemuck::cast_slice(&back.rotations)),
            bits(bytemuck::cast_slice(&p.rotations))
        );
        assert_eq!(bits(&back.opacity_logits), bits(&p.opacity_logits));
        assert_eq!(
            bits(bytemuck::cast_slice(&back.sh_dc)),
            bits(bytemuck::cast_slice(&p.sh_dc))
        );
        assert_eq!(bits(&back.sh_rest), bits(&p.sh_rest));
    }
    ctx.check_validation().unwrap();
}

#[test]
fn non_finite_parameters_never_reach_the_gpu() {
    let ctx = GpuContext::new(&GpuOptions::for_tests()).unwrap();
    let mut p = random_init(10, [0.0; 3], [1.0; 3], 1, 0).unwrap();
    p.opacity_logits[7] = f32::NAN;
    let err = GpuSplats::upload(&ctx, &p, 10)
        .err()
        .expect("NaN must be refused");
    assert!(err.to_string().contains('7'), "{err}");
    let p = random_init(10, [0.0; 3], [1.0; 3], 1, 0).unwrap();
    assert!(
        GpuSplats::upload(&ctx, &p, 5).is_err(),
        "capacity below count must be refused"
    );
}

/// A model's extra groups upload and download with it, keep their shape in zeroed copies, and
/// the NaN check scans and names them.
#[test]
fn extra_groups_round_trip_and_are_checked_for_nan() {
    use lpmsplat::splats::gpu::SplatShape;
    use lpmsplat::splats::{ExtraGroup, ExtraValues};
    use lpmsplat::train::nan_check::NonFiniteCheck;
    let ctx = GpuContext::new(&GpuOptions::for_tests()).unwrap();
    let mut p = random_init(50, [0.0; 3], [1.0; 3], 3, 1).unwrap();
    p.extra.push(ExtraValues {
        group: ExtraGroup::new("motion", 9),
        values: (0..450).map(|i| i as f32).collect(),
    });
    let g = GpuSplats::upload(&ctx, &p, 64).unwrap();
    assert_eq!(g.download().unwrap(), p);
    assert_eq!(
        g.groups().len(),
        5 + lpmsplat::splats::sh_planes::PLANES + 1,
        "five groups, the SH rest planes, one extra"
    );
    assert_eq!(g.extra_group("motion").unwrap().len(), 64 * 9);
    let shape = g.shape();
    assert_eq!(shape.extra, vec![ExtraGroup::new("motion", 9)]);
    let z = GpuSplats::zeroed_shape(&ctx, "z ", &shape, 50, 64).unwrap();
    assert_eq!(z.shape(), shape);
    assert!(z.download().unwrap().extra[0]
        .values
        .iter()
        .all(|&v| v == 0.0));
    assert_eq!(SplatShape::plain(1).strides().len(), 6);
    let mut check = NonFiniteCheck::new(&ctx).unwrap();
    assert_eq!(check.first(&g).unwrap(), None);
    p.extra[0].values[9 * 17 + 4] = f32::NAN;
    let e = p.validate().unwrap_err().to_string();
    assert!(
        e.contains("Gaussian 17") && e.contains("extra group 0[4]"),
        "{e}"
    );
    let g = GpuSplats::upload(&ctx, &p, 64);
    assert!(g.is_err(), "NaN never reaches the GPU");
    let g = GpuSplats::upload(
        &ctx,
        &{
            let mut q = p.clone();
            q.extra[0].values[9 * 17 + 4] = 0.0;
            q
        },
        64,
    )
    .unwrap();
    g.extra[0].upload(&p.extra[0].values).unwrap();
    let nf = check.first(&g).unwrap().unwrap();
    assert_eq!((nf.group.as_str(), nf.gaussian), ("motion", 17));
    ctx.check_validation().unwrap();
}
