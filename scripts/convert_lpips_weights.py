#!/usr/bin/env python3
"""Convert the official LPIPS weights (AlexNet trunk, v0.1 linear heads) into the one
safetensors file that lpmsplat's `Lpips::load` reads.

Usage (the LPIPS metric of the LPM paper's tables is `lpips.LPIPS(net='alex', version='0.1')`):

    python3 -m venv /tmp/lpips-venv
    /tmp/lpips-venv/bin/pip install torch torchvision lpips safetensors
    # Either let torchvision download its ImageNet AlexNet (needs internet) ...
    /tmp/lpips-venv/bin/python scripts/convert_lpips_weights.py lpips_alex_v0.1.safetensors
    # ... or pass the file you downloaded yourself from
    # https://download.pytorch.org/models/alexnet-owt-7be5be79.pth
    /tmp/lpips-venv/bin/python scripts/convert_lpips_weights.py lpips_alex_v0.1.safetensors \
        --alexnet alexnet-owt-7be5be79.pth

`--lin` defaults to `weights/v0.1/alex.pth` inside the installed `lpips` package (the five
linear heads, BSD-2-Clause). With `--check` the script also compares the distance of a random
image pair computed by `lpips.LPIPS` with both state dicts against the same model re-loaded from
the written file.

The written file holds float32 tensors named as in torchvision's `alexnet().features`
(`features.0.weight` … `features.10.bias`, only the five convolutions) plus `lin0.weight` …
`lin4.weight` (shape 1×C×1×1). `scripts/lpips_fixture.py` writes its test files through the
same functions, so this code path is exercised by the test fixture.
"""

import argparse
import os
import sys

import torch

# (torchvision index in `alexnet().features`, out channels, in channels, kernel size)
FEATURE_CONVS = [
    (0, 64, 3, 11),
    (3, 192, 64, 5),
    (6, 384, 192, 3),
    (8, 256, 384, 3),
    (10, 256, 256, 3),
]
# Channels of the five taps (relu1 … relu5), i.e. of the five linear heads.
HEAD_CHANNELS = [64, 192, 384, 256, 256]
# Where each convolution sits inside `lpips.pretrained_networks.alexnet` (slice1 … slice5).
LPIPS_SLICE = {0: 1, 3: 2, 6: 3, 8: 4, 10: 5}


def expected_shapes(heads_only=False):
    """Name -> shape of every tensor in the file (the same table as src/lpips/weights.rs)."""
    shapes = {}
    if not heads_only:
        for idx, cout, cin, k in FEATURE_CONVS:
            shapes[f"features.{idx}.weight"] = (cout, cin, k, k)
            shapes[f"features.{idx}.bias"] = (cout,)
    for i, c in enumerate(HEAD_CHANNELS):
        shapes[f"lin{i}.weight"] = (1, c, 1, 1)
    return shapes


def read_lin_heads(path=None):
    """The five v0.1 linear heads as {'lin0.weight': tensor, ...} from lpips' alex.pth."""
    if path is None:
        import lpips

        path = os.path.join(os.path.dirname(lpips.__file__), "weights", "v0.1", "alex.pth")
    sd = torch.load(path, map_location="cpu", weights_only=True)
    heads = {}
    for i in range(len(HEAD_CHANNELS)):
        key = f"lin{i}.model.1.weight"
        if key not in sd:
            sys.exit(f"{path}: no tensor {key!r}; is this lpips' weights/v0.1/alex.pth?")
        heads[f"lin{i}.weight"] = sd[key]
    return heads


def read_alexnet_features(path=None):
    """The five AlexNet convolutions as {'features.0.weight': tensor, ...}: from a torchvision
    state dict file if given, else from torchvision's IMAGENET1K_V1 weights (downloaded)."""
    if path is None:
        import torchvision

        sd = torchvision.models.alexnet(weights="IMAGENET1K_V1").state_dict()
    else:
        sd = torch.load(path, map_location="cpu", weights_only=True)
    out = {}
    for idx, _, _, _ in FEATURE_CONVS:
        for kind in ("weight", "bias"):
            key = f"features.{idx}.{kind}"
            if key not in sd:
                sys.exit(f"{path}: no tensor {key!r}; is this torchvision's AlexNet state dict?")
            out[key] = sd[key]
    return out


def write_lpips_safetensors(path, tensors, heads_only=False, metadata=None):
    """Validates names, shapes and finiteness, then writes float32 tensors to `path`."""
    from safetensors.torch import save_file

    shapes = expected_shapes(heads_only)
    missing = sorted(set(shapes) - set(tensors))
    extra = sorted(set(tensors) - set(shapes))
    if missing or extra:
        raise ValueError(f"tensor names: missing {missing}, unexpected {extra}")
    out = {}
    for name, shape in shapes.items():
        t = tensors[name].detach().to(torch.float32).contiguous()
        if tuple(t.shape) != shape:
            raise ValueError(f"{name}: shape {tuple(t.shape)}, expected {shape}")
        if not torch.isfinite(t).all():
            raise ValueError(f"{name}: holds NaN or infinity")
        out[name] = t
    save_file(out, path, metadata=metadata or {})


def load_into_lpips(model, path):
    """Loads a file written by `write_lpips_safetensors` into an `lpips.LPIPS(net='alex')`
    model (the inverse name mapping), strictly: every trunk conv and head must be present."""
    from safetensors.torch import load_file

    tensors = load_file(path)
    sd = {}
    for idx, _, _, _ in FEATURE_CONVS:
        for kind in ("weight", "bias"):
            sd[f"net.slice{LPIPS_SLICE[idx]}.{idx}.{kind}"] = tensors[f"features.{idx}.{kind}"]
    for i in range(len(HEAD_CHANNELS)):
        sd[f"lin{i}.model.1.weight"] = tensors[f"lin{i}.weight"]
    own = model.state_dict()
    for key, value in sd.items():
        if key not in own or own[key].shape != value.shape:
            raise ValueError(f"{path}: {key} does not fit the lpips model")
        own[key] = value.to(own[key].dtype)
    model.load_state_dict(own, strict=True)
    return model


def _check(path, features, heads):
    import lpips

    torch.manual_seed(0)
    a, b = torch.rand(1, 3, 64, 80), torch.rand(1, 3, 64, 80)
    ref = lpips.LPIPS(net="alex", version="0.1", pretrained=False, pnet_rand=True, verbose=False)
    ref_sd = ref.state_dict()
    for idx, _, _, _ in FEATURE_CONVS:
        for kind in ("weight", "bias"):
            ref_sd[f"net.slice{LPIPS_SLICE[idx]}.{idx}.{kind}"] = features[f"features.{idx}.{kind}"]
    for i in range(len(HEAD_CHANNELS)):
        ref_sd[f"lin{i}.model.1.weight"] = heads[f"lin{i}.weight"]
    ref.load_state_dict(ref_sd)
    mine = lpips.LPIPS(net="alex", version="0.1", pretrained=False, pnet_rand=True, verbose=False)
    load_into_lpips(mine, path)
    with torch.no_grad():
        d_ref = ref(a, b, normalize=True).item()
        d_mine = mine(a, b, normalize=True).item()
    print(f"check: lpips from the state dicts {d_ref:.8f}, from {path} {d_mine:.8f}")
    if d_ref != d_mine:
        sys.exit("check failed: the written file does not reproduce the distance")


def main():
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("output", help="the .safetensors file to write")
    p.add_argument("--alexnet", help="torchvision AlexNet state dict (alexnet-owt-7be5be79.pth); "
                   "default: torchvision's IMAGENET1K_V1 download")
    p.add_argument("--lin", help="lpips' weights/v0.1/alex.pth (default: from the lpips package)")
    p.add_argument("--check", action="store_true", help="re-load the file and compare a distance")
    args = p.parse_args()

    features = read_alexnet_features(args.alexnet)
    heads = read_lin_heads(args.lin)
    tensors = {**features, **heads}
    write_lpips_safetensors(args.output, tensors, metadata={
        "description": "LPIPS AlexNet v0.1 for lpmsplat: torchvision AlexNet features + lpips linear heads",
    })
    print(f"wrote {args.output} ({len(tensors)} tensors)")
    if args.check:
        _check(args.output, features, heads)


if __name__ == "__main__":
    main()
