"""Render small built-in scenes with fixed seeds and save them, to compare two versions of
the code image for image (a refactor must leave them equal within float noise).

    PYTHONPATH=src .venv/bin/python bench/render_fingerprint.py --out /tmp/after.npz
    .venv/bin/python bench/render_fingerprint.py --compare /tmp/before.npz /tmp/after.npz
"""
from __future__ import annotations

import argparse

import numpy as np

SCENES = ("sphere", "satin", "denim")


def render_all(res=(64, 36), spp=8, scenes=SCENES) -> dict:
    import mitsuba as mi

    import mscloth
    from mscloth.scenes import builtin

    mscloth.setup_mitsuba("llvm_ad_rgb")
    images = {}
    mscloth.register()
    for name in scenes:
        for multiscale in (True, False):
            scene_dict = builtin.builtin_scene(name, *res)
            builtin.set_cloth_parameters(scene_dict, multiscale=multiscale)
            image = mi.render(mi.load_dict(scene_dict), seed=7, spp=spp)
            images[f"{name}-{'ms' if multiscale else 'bf'}"] = np.array(image)
    return images


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--out")
    ap.add_argument("--compare", nargs=2)
    ap.add_argument("--scenes", nargs="+", default=list(SCENES))
    ap.add_argument("--res", nargs=2, type=int, default=[64, 36])
    ap.add_argument("--spp", type=int, default=8)
    args = ap.parse_args()
    if args.out:
        np.savez(args.out, **render_all(tuple(args.res), args.spp, args.scenes))
    if args.compare:
        a, b = (np.load(p) for p in args.compare)
        for key in a.files:
            x, y = a[key], b[key]
            rel = np.abs(x - y).max() / max(np.abs(x).max(), 1e-12)
            print(f"{key:12s} max |diff| / max = {rel:.2e}  mean {x.mean():.5f} vs {y.mean():.5f}")


if __name__ == "__main__":
    main()
