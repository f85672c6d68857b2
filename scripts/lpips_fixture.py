#!/usr/bin/env python3
"""Generate the LPIPS test fixture in tests/data/lpips/ (run once; the output is committed
because CI has no torch). `tests/gpu/lpips.rs` compares `lpmsplat::lpips::Lpips` against it.

Usage:
    python3 -m venv /tmp/lpips-venv
    /tmp/lpips-venv/bin/pip install torch torchvision lpips safetensors pillow
    /tmp/lpips-venv/bin/python scripts/lpips_fixture.py [--out tests/data/lpips]

What it writes, and why:
- `alex_v0.1_heads.safetensors`: the five real v0.1 linear heads of the `lpips` package
  (64+192+384+256+256 = 1,152 floats, BSD-2-Clause, see LICENSE-lpips.txt), written by the converter's writer.
- The AlexNet trunk is NOT stored (≈10 MB): it is randomly initialised from a splitmix64 stream
  that the Rust test reproduces bit-exactly (see `backbone` below), because ImageNet weights are
  not available offline and would be too big to commit anyway.
- `*.png`: 8-bit RGB image pairs (exact values k/255 on both sides), a few sizes, not all square.
- `expected.json`: the lpips distances with `normalize=True` from the float64 and the float32
  model, the per-tap float64 values, a per-tensor checksum of the generated trunk, and the
  smallest image side lpips accepts (found by trying).

The full file (trunk + heads) is written to a temporary folder with
`convert_lpips_weights.write_lpips_safetensors` and loaded back into `lpips.LPIPS` with
`convert_lpips_weights.load_into_lpips`, so the converter's code path is what gets tested.
"""

import argparse
import copy
import json
import math
import os
import sys
import tempfile

import numpy as np
import torch
from PIL import Image

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
import convert_lpips_weights as conv  # noqa: E402

import lpips  # noqa: E402

# The trunk generator (mirrored in tests/gpu/lpips.rs): one splitmix64 stream from SEED, consumed in
# the order features.0.weight, features.0.bias, features.3.weight, …, features.10.bias, each
# weight in PyTorch's row-major [out][in][ky][kx] order. A value takes the top 24 bits k of the
# next output: (k − 2^23) · 2^(e − 23), with 2^e the power of two nearest 1/sqrt(fan_in)
# (PyTorch's default init bound) — exact in float32 and float64 alike.
SEED = 0x6C70697073  # "lpips"
GAMMA = 0x9E3779B97F4A7C15
MASK = (1 << 64) - 1


def splitmix64(seed, n):
    """The first n outputs of splitmix64 seeded with `seed` (vectorised; uint64 arithmetic wraps)."""
    with np.errstate(over="ignore"):
        z = np.uint64(seed) + np.arange(1, n + 1, dtype=np.uint64) * np.uint64(GAMMA)
        z = (z ^ (z >> np.uint64(30))) * np.uint64(0xBF58476D1CE4E5B9)
        z = (z ^ (z >> np.uint64(27))) * np.uint64(0x94D049BB133111EB)
        return z ^ (z >> np.uint64(31))


def splitmix64_scalar(seed, n):
    """Plain-Python splitmix64, to cross-check the vectorised one."""
    out, s = [], seed
    for _ in range(n):
        s = (s + GAMMA) & MASK
        z = s
        z = ((z ^ (z >> 30)) * 0xBF58476D1CE4E5B9) & MASK
        z = ((z ^ (z >> 27)) * 0x94D049BB133111EB) & MASK
        out.append(z ^ (z >> 31))
    return out


def bound_exponent(fan_in):
    return round(-0.5 * math.log2(fan_in))


def backbone():
    counts = []
    for _, cout, cin, k in conv.FEATURE_CONVS:
        counts += [cout * cin * k * k, cout]
    raw = splitmix64(SEED, sum(counts))
    assert [int(v) for v in raw[:16]] == splitmix64_scalar(SEED, 16)
    k24 = (raw >> np.uint64(40)).astype(np.int64) - (1 << 23)
    tensors, checks, pos = {}, {}, 0
    for idx, cout, cin, k in conv.FEATURE_CONVS:
        e = bound_exponent(cin * k * k)
        for kind, shape in (("weight", (cout, cin, k, k)), ("bias", (cout,))):
            n = int(np.prod(shape))
            vals = np.ldexp(k24[pos:pos + n].astype(np.float64), e - 23)
            pos += n
            name = f"features.{idx}.{kind}"
            tensors[name] = torch.from_numpy(vals.astype(np.float32).reshape(shape))
            assert (tensors[name].double().numpy().ravel() == vals).all()  # exact in f32
            checks[name] = {"bound_exp2": e, "first": float(vals[0]), "sum": float(vals.sum()),
                            "sum_abs": float(np.abs(vals).sum())}
    return tensors, checks


# ---- images ---------------------------------------------------------------------------------

def to_u8(img):
    return np.clip(np.rint(img * 255.0), 0, 255).astype(np.uint8)


def gradient(w, h):
    y, x = np.mgrid[0:h, 0:w].astype(np.float64)
    return np.stack([x / (w - 1), y / (h - 1), 0.5 + 0.5 * np.sin((x + y) / (w + h) * 3.0)], -1)


def scene(w, h, rng):
    """Smooth stripes, a disc and a rectangle: edges and texture at several scales."""
    y, x = np.mgrid[0:h, 0:w].astype(np.float64)
    img = np.stack([0.5 + 0.4 * np.sin(0.21 * x + 0.05 * y),
                    0.5 + 0.4 * np.cos(0.07 * x - 0.17 * y),
                    0.5 + 0.3 * np.sin(0.011 * x * y / 4)], -1)
    cx, cy, r = rng.uniform(0.3, 0.7) * w, rng.uniform(0.3, 0.7) * h, 0.2 * min(w, h)
    img[(x - cx) ** 2 + (y - cy) ** 2 < r * r] = [0.9, 0.2, 0.1]
    x0, y0 = int(0.1 * w), int(0.6 * h)
    img[y0:y0 + h // 5, x0:x0 + w // 4] = [0.1, 0.3, 0.85]
    return img + rng.normal(0, 0.02, img.shape)


def box_blur(img, r):
    pad = np.pad(img, ((r, r), (r, r), (0, 0)), mode="edge")
    out = np.zeros_like(img)
    h, w = img.shape[:2]
    for dy in range(2 * r + 1):
        for dx in range(2 * r + 1):
            out += pad[dy:dy + h, dx:dx + w]
    return out / (2 * r + 1) ** 2


def pairs(rng):
    """(name, a, b) as float arrays in [0,1] of shape h×w×3 (quantised to 8 bits later)."""
    out = []
    out.append(("noise_64x64", rng.uniform(size=(64, 64, 3)), rng.uniform(size=(64, 64, 3))))
    g = gradient(96, 71)
    out.append(("gradient_noise_96x71", g, g + rng.normal(0, 0.04, g.shape)))
    s = scene(127, 90, rng)
    out.append(("blur_127x90", s, box_blur(s, 2)))
    s = scene(200, 150, rng)
    out.append(("shift_200x150", s, np.roll(s, (2, 3), axis=(0, 1))))
    s = scene(160, 48, rng)
    out.append(("contrast_160x48", s, 0.7 * s + 0.15))
    s = 0.5 * scene(50, 37, rng) + 0.5 * rng.uniform(size=(37, 50, 3))
    out.append(("identical_50x37", s, s.copy()))
    out.append(("minimum_31x31", rng.uniform(size=(31, 31, 3)), gradient(31, 31)))
    return out


def to_tensor(u8, dtype):
    # Same rounding as the Rust side: k as a float divided by 255 in the working precision.
    return (torch.from_numpy(u8.astype(np.float64 if dtype == torch.float64 else np.float32))
            .permute(2, 0, 1)[None] / 255.0).to(dtype)


def smallest_side(model):
    """The smallest square side lpips accepts (tries sizes; AlexNet's pools set the limit)."""
    for s in range(1, 64):
        try:
            with torch.no_grad():
                model(torch.zeros(1, 3, s, s), torch.zeros(1, 3, s, s), normalize=True)
            return s
        except RuntimeError:
            continue
    raise RuntimeError("no size up to 63 works")


def main():
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    here = os.path.dirname(os.path.abspath(__file__))
    p.add_argument("--out", default=os.path.join(here, "..", "tests", "data", "lpips"))
    args = p.parse_args()
    os.makedirs(args.out, exist_ok=True)
    torch.set_num_threads(1)  # deterministic reductions

    trunk, checks = backbone()
    heads = conv.read_lin_heads()
    heads_path = os.path.join(args.out, "alex_v0.1_heads.safetensors")
    conv.write_lpips_safetensors(heads_path, heads, heads_only=True, metadata={
        "source": "lpips 0.1.4, lpips/weights/v0.1/alex.pth",
        "license": "BSD-2-Clause, see LICENSE-lpips.txt"})
    os.chmod(heads_path, 0o644)  # safetensors creates it 0600

    with tempfile.TemporaryDirectory() as tmp:
        full = os.path.join(tmp, "lpips_random_trunk.safetensors")
        conv.write_lpips_safetensors(full, {**trunk, **heads})
        m32 = lpips.LPIPS(net="alex", version="0.1", pretrained=False, pnet_rand=True, verbose=False)
        conv.load_into_lpips(m32, full)
    m32.eval()
    m64 = copy.deepcopy(m32).double()

    rng = np.random.default_rng(20250607)
    records = []
    for name, a, b in pairs(rng):
        a8, b8 = to_u8(a), to_u8(b)
        h, w = a8.shape[:2]
        Image.fromarray(a8).save(os.path.join(args.out, f"{name}_a.png"), optimize=True)
        Image.fromarray(b8).save(os.path.join(args.out, f"{name}_b.png"), optimize=True)
        with torch.no_grad():
            d64, layers64 = m64(to_tensor(a8, torch.float64), to_tensor(b8, torch.float64),
                                retPerLayer=True, normalize=True)
            d32 = m32(to_tensor(a8, torch.float32), to_tensor(b8, torch.float32), normalize=True)
        rec = {"name": name, "a": f"{name}_a.png", "b": f"{name}_b.png", "width": w, "height": h,
               "lpips_f64": d64.item(), "lpips_f32": d32.item(),
               "per_tap_f64": [t.item() for t in layers64]}
        records.append(rec)
        print(f"{name:24s} f64 {rec['lpips_f64']:.10f}  f32 {rec['lpips_f32']:.10f}")

    expected = {
        "about": "Written by scripts/lpips_fixture.py; read by tests/gpu/lpips.rs.",
        "model": "lpips.LPIPS(net='alex', version='0.1', lpips=True, spatial=False), normalize=True",
        "trunk": {"generator": "splitmix64", "seed": SEED,
                  "order": [f"features.{i}.{k}" for i, *_ in conv.FEATURE_CONVS for k in ("weight", "bias")],
                  "value": "(k - 2^23) * 2^(e - 23), k = top 24 bits, 2^e nearest 1/sqrt(fan_in)",
                  "checks": checks},
        "heads": "alex_v0.1_heads.safetensors",
        "smallest_side": smallest_side(m32),
        "versions": {"torch": torch.__version__, "lpips": getattr(lpips, "__version__", "0.1.4"),
                     "numpy": np.__version__},
        "pairs": records,
    }
    with open(os.path.join(args.out, "expected.json"), "w") as f:
        json.dump(expected, f, indent=1)
        f.write("\n")
    print(f"smallest side: {expected['smallest_side']}")


if __name__ == "__main__":
    main()
