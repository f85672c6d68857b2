//! GPU prefix scan and radix sort against the host, on random data, with validation on.
//! Also re-runs itself with lavapipe forced to subgroup size 16, so two subgroup sizes are
//! covered on one machine.

use crate::child_run;

use lpmsplat::gpu::{BufferKind, GpuBuffer, GpuContext, GpuOptions, Recorder};
use lpmsplat::render::scan::PrefixScan;
use lpmsplat::render::sort::{BlockShape, Digits, DropKeys, RadixSort, SortedIn};
use rand::{Rng, SeedableRng};
use std::sync::Arc;

fn ctx() -> Arc<GpuContext> {
    GpuContext::new(&GpuOptions::for_tests()).expect("a Vulkan device with the validation layer")
}

const POISON: u32 = 0xDEAD_BEEF;

#[test]
fn exclusive_scan_matches_host() {
    let ctx = ctx();
    let mut rng = rand_pcg::Pcg64::seed_from_u64(11);
    let scan = PrefixScan::new(&ctx, 5_000_000).unwrap();
    for &n in &[0usize, 1, 2047, 2048, 2049, 100_000, 4_200_000] {
        let data: Vec<u32> = (0..n).map(|_| rng.gen_range(0..100)).collect();
        // Extra poisoned tail: elements past the count must stay untouched.
        let mut padded = data.clone();
        padded.extend(std::iter::repeat_n(POISON, 5));
        let buf = GpuBuffer::from_slice(&ctx, "data", &padded).unwrap();
        let counts = GpuBuffer::from_slice(&ctx, "counts", &[n as u32, POISON]).unwrap();
        let mut rec = Recorder::new(&ctx).unwrap();
        scan.record(&mut rec, &buf, &counts, 0, Some(1));
        rec.submit_and_wait().unwrap();
        let out = buf.read().unwrap();
        let mut acc = 0u32;
        for i in 0..n {
            assert_eq!(out[i], acc, "n={n} i={i}");
            acc += data[i];
        }
        assert!(
            out[n..].iter().all(|&v| v == POISON),
            "scan wrote past the count"
        );
        assert_eq!(counts.read().unwrap()[1], acc, "total for n={n}");
    }
    ctx.check_validation().unwrap();
}

/// Sorts `keys` (values: their input positions) on the GPU by their low `bits` bits and checks
/// the result against a stable host sort; returns the sorted values.
fn check_sort(ctx: &Arc<GpuContext>, sorter: &RadixSort, keys: &[u32], bits: u32) -> Vec<u32> {
    let values: Vec<u32> = (0..keys.len() as u32).collect();
    check_sort_with(ctx, sorter, keys, &values, bits)
}

fn check_sort_with(
    ctx: &Arc<GpuContext>,
    sorter: &RadixSort,
    keys: &[u32],
    values: &[u32],
    bits: u32,
) -> Vec<u32> {
    let n = keys.len();
    let cap = sorter.capacity() as usize;
    let kbuf = GpuBuffer::<u32>::new(ctx, "keys", cap, BufferKind::DeviceLocal).unwrap();
    let vbuf = GpuBuffer::<u32>::new(ctx, "values", cap, BufferKind::DeviceLocal).unwrap();
    let sk = GpuBuffer::<u32>::new(ctx, "scratch keys", cap, BufferKind::DeviceLocal).unwrap();
    let sv = GpuBuffer::<u32>::new(ctx, "scratch values", cap, BufferKind::DeviceLocal).unwrap();
    kbuf.upload(keys).unwrap();
    vbuf.upload(values).unwrap();
    let counts = GpuBuffer::from_slice(ctx, "counts", &[n as u32, 0]).unwrap();
    let mut rec = Recorder::new(ctx).unwrap();
    rec.fill(&sk, POISON);
    rec.fill(&sv, POISON);
    rec.barrier();
    let where_ = sorter.record(&mut rec, &kbuf, &vbuf, &sk, &sv, &counts, 0, 1, bits);
    rec.submit_and_wait().unwrap();
    let (ko, vo) = match where_ {
        SortedIn::Input => (
            kbuf.read_range(0, n).unwrap(),
            vbuf.read_range(0, n).unwrap(),
        ),
        SortedIn::Scratch => (sk.read_range(0, n).unwrap(), sv.read_range(0, n).unwrap()),
    };
    // Host oracle: a stable sort on the same bits.
    let mask = if bits >= 32 {
        u32::MAX
    } else {
        (1u32 << bits) - 1
    };
    let mut expect: Vec<(u32, u32)> = keys.iter().copied().zip(values.iter().copied()).collect();
    expect.sort_by_key(|&(k, _)| k & mask);
    for i in 0..n {
        assert_eq!((ko[i], vo[i]), expect[i], "n={n} bits={bits} position {i}");
    }
    vo
}

#[test]
fn radix_sort_is_stable_and_matches_host_sort() {
    let ctx = ctx();
    let mut rng = rand_pcg::Pcg64::seed_from_u64(3);
    // Both block shapes (GPUs: 256 invocations of 8 keys, CPU drivers 64 of 256), whatever the
    // device, with 4-bit passes only and with the 5-bit passes that save a pass (13, 29, 31 and
    // 32 bits use them), and the ballot-ranked 8-bit passes; the sizes straddle both block
    // lengths (2048 and 16384 keys).
    let (gpu, cpu) = (BlockShape::GPU, BlockShape::CPU);
    let (narrow, wide, byte) = (Digits::Narrow, Digits::Wide, Digits::Byte);
    let sorters = [
        RadixSort::with_options(&ctx, 300_000, gpu, narrow, false).unwrap(),
        RadixSort::with_options(&ctx, 300_000, cpu, narrow, false).unwrap(),
        RadixSort::with_options(&ctx, 300_000, gpu, wide, false).unwrap(),
        RadixSort::with_options(&ctx, 300_000, cpu, wide, false).unwrap(),
        RadixSort::with_options(&ctx, 300_000, gpu, byte, false).unwrap(),
    ];
    let shape = |wg, items| BlockShape { wg, items };
    assert!(
        RadixSort::with_shape(&ctx, 10, shape(256, 256)).is_err(),
        "65536-key blocks overflow"
    );
    for (wg, digits) in [(16, wide), (128, byte)] {
        assert!(
            RadixSort::with_options(&ctx, 10, shape(wg, 64), digits, false).is_err(),
            "{wg} invocations: fewer than a {digits:?} pass has digits"
        );
    }
    assert!(RadixSort::with_options(&ctx, 10, shape(16, 64), narrow, false).is_ok());
    // GPU-sized blocks are ordered in shared memory before they are written out (where the
    // device has room: 16.25 KiB), CPU-sized ones are not: both scatters run here.
    assert!(!RadixSort::reorders(&ctx.info, cpu));
    assert_eq!(
        RadixSort::reorders(&ctx.info, gpu),
        ctx.info.max_shared_memory >= 16 * 1024 + 256,
        "{} bytes of shared memory",
        ctx.info.max_shared_memory
    );
    for (&(n, bits), k) in [
        (0usize, 32u32),
        (1, 8),
        (5, 13),
        (2048, 31),
        (2049, 32),
        (16_384, 20),
        (16_385, 32),
        (70_001, 29),
        (300_000, 32),
        (50_000, 6),
        (40_000, 13),
        (9_000, 1),
    ]
    .iter()
    .flat_map(|c| (0..sorters.len()).map(move |k| (c, k)))
    {
        let sorter = &sorters[k];
        // Keys carry random bits above `bits` too: the sort must ignore them. Few distinct
        // values in some runs so that stability is exercised.
        let distinct = rng.gen_bool(0.5);
        let keys: Vec<u32> = (0..n)
            .map(|_| {
                if distinct {
                    rng.gen::<u32>()
                } else {
                    rng.gen_range(0..64u32) | (rng.gen::<u32>() << 6)
                }
            })
            .collect();
        check_sort(&ctx, sorter, &keys, bits);
    }
    ctx.check_validation().unwrap();
}

/// Keys equal to the dropped key are left out: the kept ones come first, stably sorted, their
/// number lands in the counts buffer, and nothing is written past them (the scratch buffers
/// keep their poison there).
#[test]
fn radix_sort_drops_the_named_key_in_its_first_pass() {
    let ctx = ctx();
    let mut rng = rand_pcg::Pcg64::seed_from_u64(9);
    let drop_key = 0x7FFF_FFFF;
    let digits_and_shapes = [
        (Digits::Narrow, BlockShape::GPU),
        (Digits::Narrow, BlockShape::CPU),
        (Digits::Wide, BlockShape::GPU),
        (Digits::Wide, BlockShape::CPU),
        (Digits::Byte, BlockShape::GPU),
    ];
    for (digits, shape) in digits_and_shapes {
        let sorter = RadixSort::with_options(&ctx, 100_000, shape, digits, true).unwrap();
        // (n, bits, share dropped): none, all, some; one and several passes; the dropped
        // key's digits collide with kept keys' digits in every pass.
        for (n, bits, share) in [
            (0usize, 31u32, 0.5),
            (1, 31, 1.0),
            (3_000, 31, 0.0),
            (3_000, 31, 1.0),
            (20_001, 31, 0.3),
            (70_000, 31, 0.9),
            (50_000, 4, 0.5),
            (40_000, 32, 0.5),
        ] {
            let keys: Vec<u32> = (0..n)
                .map(|_| {
                    if rng.gen_bool(share) {
                        drop_key
                    } else if rng.gen_bool(0.3) {
                        // Equal to the dropped key in the sorted bits or in one digit.
                        drop_key ^ (1 << rng.gen_range(0..32))
                    } else {
                        rng.gen::<u32>() >> rng.gen_range(0..8)
                    }
                })
                .collect();
            let values: Vec<u32> = (0..n as u32).collect();
            let cap = sorter.capacity() as usize;
            let dl = BufferKind::DeviceLocal;
            let bufs: Vec<GpuBuffer<u32>> = (0..4)
                .map(|_| GpuBuffer::<u32>::new(&ctx, "sort buffer", cap, dl).unwrap())
                .collect();
            bufs[0].upload(&keys).unwrap();
            bufs[1].upload(&values).unwrap();
            let counts = GpuBuffer::from_slice(&ctx, "counts", &[n as u32, 0, POISON]).unwrap();
            let mut rec = Recorder::new(&ctx).unwrap();
            rec.fill(&bufs[2], POISON);
            rec.fill(&bufs[3], POISON);
            rec.barrier();
            let drop = Some(DropKeys {
                key: drop_key,
                kept_index: 2,
            });
            let at = sorter.record_dropping(
                &mut rec,
                [&bufs[0], &bufs[1], &bufs[2], &bufs[3]],
                &counts,
                0,
                1,
                bits,
                drop,
            );
            rec.submit_and_wait().unwrap();
            let mask = if bits >= 32 {
                u32::MAX
            } else {
                (1u32 << bits) - 1
            };
            let mut expect: Vec<(u32, u32)> = keys
                .iter()
                .copied()
                .zip(values.iter().copied())
                .filter(|&(k, _)| k != drop_key)
                .collect();
            expect.sort_by_key(|&(k, _)| k & mask);
            let label = format!("n={n} bits={bits} {shape:?} {digits:?}");
            let kept = counts.read().unwrap()[2] as usize;
            assert_eq!(kept, expect.len(), "{label}: kept count");
            let (ko, vo) = match at {
                SortedIn::Input => (&bufs[0], &bufs[1]),
                SortedIn::Scratch => (&bufs[2], &bufs[3]),
            };
            let (ko, vo) = (ko.read().unwrap(), vo.read().unwrap());
            for (i, e) in expect.iter().enumerate() {
                assert_eq!((ko[i], vo[i]), *e, "{label}: position {i}");
            }
            // One pass: the output is the scratch, poisoned past the kept keys.
            if RadixSort::pass_widths(bits, digits).len() == 1 {
                assert_eq!(at, SortedIn::Scratch);
                assert!(ko[kept..].iter().all(|&k| k == POISON), "{label}: tail");
            }
        }
    }
    ctx.check_validation().unwrap();
}

#[test]
fn splat_like_depth_then_tile_sort_orders_pairs_by_tile_then_depth() {
    // The renderer's two sorts: Gaussians by depth (the float bits of positive depths, 31 bits,
    // culled ones 0x7FFFFFFF),
    // then their (tile, Gaussian) pairs, emitted in depth order, stably by tile id alone (13 bits
    // at 1352×1014 in 16×16 tiles). Together they must equal one sort by (tile, depth, index).
    let ctx = ctx();
    let mut rng = rand_pcg::Pcg64::seed_from_u64(5);
    let gaussians = 40_000usize;
    let tiles = 5_440u32;
    let tile_bits = lpmsplat::render::forward::tile_bits(tiles);
    assert_eq!(tile_bits, 13);
    // Few distinct depths, so ties are broken by index as in the CPU reference.
    let depths: Vec<f32> = (0..gaussians)
        .map(|_| rng.gen_range(1..2_000) as f32 * 0.05)
        .collect();
    // A tenth culled: the largest key, and no tiles.
    let culled: Vec<bool> = (0..gaussians).map(|_| rng.gen_bool(0.1)).collect();
    let depth_keys: Vec<u32> = depths
        .iter()
        .zip(&culled)
        .map(|(d, &c)| if c { 0x7FFF_FFFF } else { d.to_bits() })
        .collect();
    let by_depth = check_sort(
        &ctx,
        &RadixSort::new(&ctx, gaussians as u64).unwrap(),
        &depth_keys,
        31,
    );
    let touched: Vec<Vec<u32>> = (0..gaussians)
        .map(|g| {
            if culled[g] {
                return Vec::new();
            }
            let first = rng.gen_range(0..tiles);
            let len = rng.gen_range(1..6u32);
            (first..(first + len).min(tiles)).collect()
        })
        .collect();
    let (mut tile_keys, mut ids) = (Vec::new(), Vec::new());
    for &g in &by_depth {
        for &t in &touched[g as usize] {
            tile_keys.push(t);
            ids.push(g);
        }
    }
    let sorter = RadixSort::new(&ctx, tile_keys.len() as u64).unwrap();
    let sorted = check_sort_with(&ctx, &sorter, &tile_keys, &ids, tile_bits);
    let mut expect: Vec<(u32, u32, u32)> = (0..gaussians as u32)
        .flat_map(|g| {
            let d = depth_keys[g as usize];
            touched[g as usize].iter().map(move |&t| (t, d, g))
        })
        .collect();
    expect.sort_unstable();
    let expect_ids: Vec<u32> = expect.iter().map(|e| e.2).collect();
    assert_eq!(sorted, expect_ids);
    ctx.check_validation().unwrap();
}

#[test]
fn sort_and_scan_under_subgroup_size_16() {
    // lavapipe runs with subgroup size 16 when LP_NATIVE_VECTOR_WIDTH=512 (set before the driver
    // loads, hence a child process). Other drivers ignore the variable.
    child_run::rerun_under_subgroup_size_16(
        module_path!(),
        &["radix_sort_is_stable", "exclusive_scan", "splat_like"],
    );
}

#[test]
fn a_full_binding_of_pairs_sorted_reversed_and_equal() {
    // 2^25 pairs of 32-bit keys fill exactly a 128 MiB binding (lavapipe's limit). Patterns the
    // issue names: already sorted, reverse sorted and all-equal keys (stability: values must stay
    // in input order), on the 16 bits a 4K image's tile ids need.
    let ctx = ctx();
    let n = 1usize << 25;
    if (n as u64) * 4 > ctx.info.max_storage_buffer_range {
        eprintln!("skipped: this device cannot bind 128 MiB");
        return;
    }
    let sorter = RadixSort::new(&ctx, n as u64).unwrap();
    let bits = 16;
    let mut rng = rand_pcg::Pcg64::seed_from_u64(16);
    #[allow(clippy::type_complexity)]
    let patterns: [(&str, Box<dyn Fn(usize) -> u32>); 3] = [
        ("sorted", Box::new(|i| (i >> 9) as u32)),
        ("reversed", Box::new(move |i| ((n - 1 - i) >> 9) as u32)),
        ("equal", Box::new(|_| 0xBEEF)),
    ];
    for (name, f) in patterns.iter() {
        let keys: Vec<u32> = (0..n).map(f).collect();
        eprintln!("{name}");
        check_sort(&ctx, &sorter, &keys, bits);
    }
    let keys: Vec<u32> = (0..n).map(|_| rng.gen::<u32>() & 0xFFFF).collect();
    check_sort(&ctx, &sorter, &keys, bits);
    ctx.check_validation().unwrap();
}

/// Group counts computed on the GPU from a count in a buffer: enough workgroups for every item,
/// not a row more, within the device's limits, at least one, and no wrap for counts near 2^32.
#[test]
fn dispatch_sizes_from_a_gpu_count_cover_it_exactly() {
    use lpmsplat::render::dispatch_size::DispatchSize;
    let ctx = ctx();
    let max_x = ctx.info.max_workgroup_count[0] as u64;
    let counts_host = [0u32, 1, 255, 256, 257, 1_000_000, u32::MAX - 1, u32::MAX];
    let counts = GpuBuffer::from_slice(&ctx, "counts", &counts_host).unwrap();
    let sizes = DispatchSize::new(&ctx, counts_host.len()).unwrap();
    for per_group in [1u64, 256, 16_384] {
        let mut rec = Recorder::new(&ctx).unwrap();
        for slot in 0..counts_host.len() as u32 {
            sizes.record(&mut rec, &counts, slot, per_group, slot);
        }
        rec.submit_and_wait().unwrap();
        let (args, at) = sizes.args(0);
        assert_eq!(at, 0);
        let got = args.read_range(0, 3 * counts_host.len()).unwrap();
        for (slot, &n) in counts_host.iter().enumerate() {
            let [x, y, z] = [0, 1, 2].map(|k| got[3 * slot + k] as u64);
            let need = (n as u64).div_ceil(per_group).max(1);
            let label = format!("{n} items, {per_group} a group: {x}×{y}×{z}");
            assert_eq!(z, 1, "{label}");
            assert!(x >= 1 && x <= max_x && y >= 1, "{label}");
            assert!(x * y >= need, "{label}: too few groups for {need}");
            assert!(
                x * (y - 1) < need,
                "{label}: a whole row of groups too many"
            );
            if need <= max_x {
                assert_eq!((x, y), (need, 1), "{label}");
            }
        }
    }
    ctx.check_validation().unwrap();
}
