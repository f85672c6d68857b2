//! GPU layer smoke tests, with the validation layer on and its errors required to be zero.

use lpmsplat::gpu::{
    BufferKind, ComputePipeline, GpuBuffer, GpuContext, GpuOptions, HoldFrees, Recorder,
    TimestampPool,
};
use lpmsplat::shaders;
use rand::{Rng, SeedableRng};
use std::sync::Arc;

fn ctx() -> Arc<GpuContext> {
    GpuContext::new(&GpuOptions::for_tests())
        .expect("a Vulkan device (lavapipe in CI) with the validation layer")
}

#[test]
fn subgroup_scan_matches_host_and_reports_device_subgroup_size() {
    let ctx = ctx();
    let sg = ctx.info.subgroup_size;
    assert!(sg.is_power_of_two() && sg >= 1, "subgroup size {sg}");
    let wg = 64u32.max(sg);
    let pipe = ComputePipeline::new(
        &ctx,
        "subgroup_probe",
        shaders::UTIL_SUBGROUP_PROBE,
        3,
        8,
        wg,
        &[],
    )
    .unwrap();
    let fill = ComputePipeline::new(&ctx, "fill", shaders::UTIL_FILL_U32, 1, 8, 64, &[]).unwrap();
    let mut rng = rand_pcg::Pcg64::seed_from_u64(7);
    for &n in &[1usize, 7, 64, 1000, 4097] {
        let xs: Vec<u32> = (0..n).map(|_| rng.gen_range(0..1000)).collect();
        let input = GpuBuffer::from_slice(&ctx, "xs", &xs).unwrap();
        let out = GpuBuffer::<u32>::new(&ctx, "ys", n, BufferKind::DeviceLocal).unwrap();
        let info = GpuBuffer::<u32>::new(&ctx, "info", 1, BufferKind::DeviceLocal).unwrap();
        let mut rec = Recorder::new(&ctx).unwrap();
        // Poison the outputs so an element the kernel skips is caught.
        rec.dispatch_named(
            &fill,
            &[("data", &out)],
            &[n as u32, 0xDEAD_BEEFu32],
            ctx.groups_1d(n as u64, 64),
        );
        rec.fill(&info, 0);
        rec.barrier();
        rec.dispatch_named(
            &pipe,
            &[("xs", &input), ("ys", &out), ("subgroup_size", &info)],
            &[n as u32, 3u32],
            ctx.groups_1d(n as u64, wg),
        );
        rec.submit_and_wait().unwrap();
        let ys = out.read().unwrap();
        let ran_with = info.read().unwrap()[0];
        assert!(
            ran_with.is_power_of_two()
                && ran_with <= ctx.info.max_subgroup_size
                && ran_with >= ctx.info.min_subgroup_size
        );
        for (i, &y) in ys.iter().enumerate() {
            let start = i / ran_with as usize * ran_with as usize;
            let prefix: u32 = xs[start..=i].iter().sum();
            assert_eq!(
                y,
                xs[i] * 3 + prefix,
                "element {i} of {n} (subgroup size {ran_with})"
            );
        }
    }
    ctx.check_validation().unwrap();
}

#[test]
fn host_visible_buffers_round_trip_and_timestamps_report_stages() {
    let ctx = ctx();
    let data: Vec<f32> = (0..1000).map(|i| i as f32 * 0.5 - 3.0).collect();
    let up = GpuBuffer::<f32>::new(&ctx, "upload", data.len(), BufferKind::Upload).unwrap();
    up.upload(&data).unwrap();
    let dev = GpuBuffer::<f32>::new(&ctx, "device", data.len(), BufferKind::DeviceLocal).unwrap();
    let back = GpuBuffer::<f32>::new(&ctx, "readback", data.len(), BufferKind::Readback).unwrap();
    let mut pool = TimestampPool::new(&ctx, 8).unwrap();
    let mut rec = Recorder::new(&ctx).unwrap();
    rec.start_timestamps(&mut pool);
    rec.copy(&up, &dev, data.len());
    rec.timestamp(&mut pool, "upload");
    rec.barrier();
    rec.copy(&dev, &back, data.len());
    rec.timestamp(&mut pool, "readback");
    rec.submit_and_wait().unwrap();
    assert_eq!(back.read().unwrap(), data);
    assert_eq!(dev.read_range(10, 5).unwrap(), data[10..15].to_vec());
    let times = pool.read().unwrap();
    if ctx.info.timestamps_supported {
        let names: Vec<_> = times.stages.iter().map(|s| s.0.as_str()).collect();
        assert_eq!(names, ["upload", "readback"]);
        assert!(times.stages.iter().all(|s| s.1 >= 0.0 && s.1.is_finite()));
    }
    // The recorder is reusable.
    rec.begin().unwrap();
    rec.fill(&dev, 0);
    rec.submit_and_wait().unwrap();
    assert!(dev.read().unwrap().iter().all(|&v| v == 0.0));
    ctx.check_validation().unwrap();
}

#[test]
fn oversized_buffers_and_unknown_devices_are_clear_errors() {
    let ctx = ctx();
    let too_big = (ctx.info.max_storage_buffer_range / 4 + 1) as usize;
    let err = GpuBuffer::<u32>::new(&ctx, "huge", too_big, BufferKind::DeviceLocal)
        .err()
        .expect("must refuse");
    let msg = err.to_string();
    assert!(
        msg.contains("huge") && msg.contains("maxStorageBufferRange"),
        "{msg}"
    );
    // A kernel binding more storage buffers than the device allows (lavapipe: 32) is refused
    // before the driver sees it, naming the kernel and the limit.
    let too_many = ctx.info.max_storage_buffers + 1;
    let err = ComputePipeline::new(&ctx, "fill", shaders::UTIL_FILL_U32, too_many, 8, 64, &[])
        .err()
        .expect("must refuse");
    let msg = err.to_string();
    assert!(
        msg.contains("kernel fill") && msg.contains("maxPerStageDescriptorStorageBuffers"),
        "{msg}"
    );
    let empty = GpuBuffer::<u32>::new(&ctx, "empty", 0, BufferKind::DeviceLocal).unwrap();
    assert!(empty.is_empty() && empty.read().unwrap().is_empty());
    let err = GpuContext::new(&GpuOptions {
        validation: true,
        device: Some("no-such-device-xyz".into()),
        memory_limit: None,
        sort_digit_bits: None,
    })
    .err()
    .expect("must refuse");
    assert!(err.to_string().contains("--device"), "{err}");
    let err = GpuContext::new(&GpuOptions {
        validation: true,
        device: Some("99".into()),
        memory_limit: None,
        sort_digit_bits: None,
    })
    .err()
    .expect("must refuse");
    assert!(err.to_string().contains("no such device"), "{err}");
    // The sorts take 4- or 8-bit digits; any other width is refused with the fix.
    let err = GpuContext::new(&GpuOptions {
        sort_digit_bits: Some(5),
        ..GpuOptions::for_tests()
    })
    .err()
    .expect("must refuse");
    assert!(err.to_string().contains("pass 4 or 8"), "{err}");
    ctx.check_validation().unwrap();
}

#[test]
fn large_dispatches_spill_into_y() {
    let ctx = ctx();
    let max_x = ctx.info.max_workgroup_count[0] as u64;
    let g = ctx.groups_1d(max_x * 64 * 3 + 5, 64);
    assert!(g[1] > 1 && (g[0] as u64) <= max_x);
    assert!(g[0] as u64 * g[1] as u64 * 64 >= max_x * 64 * 3 + 5);
    // And the fill kernel covers a count that is not a multiple of the workgroup.
    let fill = ComputePipeline::new(&ctx, "fill", shaders::UTIL_FILL_U32, 1, 8, 32, &[]).unwrap();
    let n = 100_003usize;
    let buf = GpuBuffer::<u32>::new(&ctx, "buf", n, BufferKind::DeviceLocal).unwrap();
    let mut rec = Recorder::new(&ctx).unwrap();
    rec.fill(&buf, 1);
    rec.barrier();
    rec.dispatch_named(
        &fill,
        &[("data", &buf)],
        &[n as u32 - 1, 42u32],
        ctx.groups_1d(n as u64 - 1, 32),
    );
    rec.submit_and_wait().unwrap();
    let v = buf.read().unwrap();
    assert!(v[..n - 1].iter().all(|&x| x == 42));
    assert_eq!(v[n - 1], 1);
    ctx.check_validation().unwrap();
}

#[test]
fn validation_layer_is_active_and_counts_errors() {
    // A deliberately invalid call (a zero-sized buffer) must be seen and counted, proving the
    // other tests' "zero errors" means something.
    let ctx = ctx();
    assert!(
        ctx.validation().is_some(),
        "tests always run with validation"
    );
    assert_eq!(ctx.validation_errors(), 0);
    use ash::vk;
    let info = vk::BufferCreateInfo::default()
        .size(0)
        .usage(vk::BufferUsageFlags::STORAGE_BUFFER);
    unsafe {
        if let Ok(b) = ctx.device().create_buffer(&info, None) {
            ctx.device().destroy_buffer(b, None);
        }
    }
    assert!(
        ctx.validation_errors() >= 1,
        "the validation layer did not report an invalid call"
    );
    assert!(ctx.check_validation().is_err());
}

/// Work in flight uses a buffer and a pipeline; both are dropped before its fence. Under a
/// `HoldFrees` guard nothing is destroyed (the memory stays booked) until the last guard goes
/// after the fence, and the validation layer sees no object destroyed while in use; without a
/// guard the same drops are caught by it (on lavapipe), so the check can fail.
#[test]
fn held_frees_wait_for_the_last_guard() {
    let run = |guarded: bool| {
        let ctx = ctx();
        let before = ctx.memory.in_use();
        let n = 1 << 20;
        let buf = GpuBuffer::<u32>::new(&ctx, "held", n, BufferKind::DeviceLocal).unwrap();
        let booked = ctx.memory.in_use() - before;
        assert!(booked >= 4 * n as u64);
        let fill =
            ComputePipeline::new(&ctx, "fill", shaders::UTIL_FILL_U32, 1, 8, 64, &[]).unwrap();
        let mut rec = Recorder::new(&ctx).unwrap();
        for _ in 0..8 {
            rec.dispatch_named(
                &fill,
                &[("data", &buf)],
                &[n as u32, 7u32],
                ctx.groups_1d(n as u64, 64),
            );
            rec.barrier();
        }
        rec.submit().unwrap();
        let guards = guarded.then(|| (HoldFrees::new(&ctx), HoldFrees::new(&ctx)));
        if !guarded {
            // Let the work finish before the unguarded drops, so that they break nothing: the
            // validation layer still counts it in flight until the fence is seen.
            std::thread::sleep(std::time::Duration::from_millis(300));
        }
        drop(buf);
        drop(fill);
        if let Some((a, b)) = guards {
            assert_eq!(ctx.memory.in_use(), before + booked, "freed under a guard");
            rec.wait().unwrap();
            drop(a);
            assert_eq!(
                ctx.memory.in_use(),
                before + booked,
                "freed before the last guard"
            );
            drop(b);
        } else {
            rec.wait().unwrap();
        }
        assert_eq!(ctx.memory.in_use(), before, "never freed");
        ctx.check_validation()
    };
    run(true).unwrap();
    let unguarded = run(false);
    if ctx().info.device_type.starts_with("CPU") {
        let e = unguarded.expect_err("destroying objects in use went unnoticed");
        assert!(e.to_string().contains("in use"), "{e}");
    }
}

/// Bindings are declared once, in each kernel's GLSL: `build.rs` reads every kernel's
/// declarations (includes expanded, aliases of one binding kept once) into a table; a pipeline
/// whose Rust side binds another count is refused, naming both; a named dispatch places
/// buffers by those names and refuses a name the kernel does not declare, one given twice, or
/// one left out.
#[test]
fn bindings_come_from_the_kernels_declarations_and_named_dispatch_checks_them() {
    assert_eq!(shaders::BINDINGS.len(), shaders::ALL.len());
    for ((path, code), (table_code, names)) in shaders::ALL.iter().zip(shaders::BINDINGS) {
        assert_eq!(code, table_code, "{path}");
        assert!(names.iter().all(|n| !n.is_empty()), "{path}: {names:?}");
    }
    let names = shaders::BINDINGS
        .iter()
        .find(|(c, _)| *c == shaders::BACKWARD_PREPROCESS_BACKWARD)
        .unwrap()
        .1;
    assert_eq!(names.len(), 25);
    assert_eq!(names[3], "positions");
    assert_eq!(names[9], "g_positions");
    assert_eq!(names[24], "g_sh_rest4");
    // The float alias of binding 7 keeps the first declaration's name.
    let raster = shaders::BINDINGS
        .iter()
        .find(|(c, _)| *c == shaders::BACKWARD_RASTERIZE_BACKWARD)
        .unwrap()
        .1;
    assert_eq!(raster[7], "grad2d_bits");

    let ctx = ctx();
    let e = ComputePipeline::new(&ctx, "probe", shaders::UTIL_SUBGROUP_PROBE, 2, 8, 64, &[])
        .err()
        .expect("a count its GLSL does not declare")
        .to_string();
    assert!(e.contains("binds 2") && e.contains("declares 3"), "{e}");

    let pipe =
        ComputePipeline::new(&ctx, "probe", shaders::UTIL_SUBGROUP_PROBE, 3, 8, 64, &[]).unwrap();
    let declared = shaders::BINDINGS
        .iter()
        .find(|(c, _)| *c == shaders::UTIL_SUBGROUP_PROBE)
        .unwrap()
        .1;
    let buf = GpuBuffer::<u32>::new(&ctx, "b", 64, BufferKind::DeviceLocal).unwrap();
    let attempt = |named: Vec<&'static str>| {
        let ctx = ctx.clone();
        let pipe = &pipe;
        let buf = &buf;
        std::panic::catch_unwind(std::panic::AssertUnwindSafe(move || {
            let mut rec = Recorder::new(&ctx).unwrap();
            rec.begin().unwrap();
            let buffers: Vec<(&str, &dyn lpmsplat::gpu::Bindable)> = named
                .iter()
                .map(|&n| (n, buf as &dyn lpmsplat::gpu::Bindable))
                .collect();
            rec.dispatch_named(pipe, &buffers, &[0u32; 2], [0, 1, 1]);
        }))
    };
    let message = |r: std::thread::Result<()>| match r {
        Ok(()) => String::new(),
        Err(p) => p
            .downcast_ref::<String>()
            .cloned()
            .or_else(|| p.downcast_ref::<&str>().map(|s| s.to_string()))
            .unwrap_or_default(),
    };
    // In any order.
    let mut reversed: Vec<&str> = declared.to_vec();
    reversed.reverse();
    assert!(attempt(reversed).is_ok());
    let m = message(attempt(vec![declared[0], declared[1], "nope"]));
    assert!(m.contains("no binding is named \"nope\""), "{m}");
    let m = message(attempt(vec![declared[0], declared[0], declared[1]]));
    assert!(m.contains("given twice"), "{m}");
    let m = message(attempt(vec![declared[0], declared[1]]));
    assert!(m.contains("no buffer given for"), "{m}");
}
