"""Where in a region the noise per sample comes from: silhouette pixels (the pixel partly
covers cloth) against the cloth's interior, for multi-scale and brute force (issue 20).

The noise per sample of each pixel (relative, as `make bench` measures it, sun alone) is
split by the pixel's cloth coverage (8x8 rays per pixel through a copy of the scene without
its non-cloth shapes): each class's share of the region's mean and its mean per pixel.
Also writes the multi-scale noise map as a PNG (out/noise-map-SCENE.png) to look at.

    .venv/bin/python bench/noise_map.py satin
"""
from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

from common import setup_mitsuba


def coverage(scene_dict: dict, width: int, height: int, n: int = 8) -> np.ndarray:
    """Fraction of each pixel's area where a camera ray hits a cloth shape."""
    import drjit as dr
    import mitsuba as mi

    cloth_only = {k: v for k, v in scene_dict.items()
                  if not (isinstance(v, dict) and "bsdf" not in v and v.get("type") in ("rectangle", "disk", "cube"))
                  and not (isinstance(v, dict) and isinstance(v.get("bsdf"), dict) and v["bsdf"].get("type") != "cloth")}
    scene = mi.load_dict(cloth_only)
    sensor = scene.sensors()[0]
    hits = np.zeros((height, width))
    ys, xs = np.meshgrid(np.arange(height), np.arange(width), indexing="ij")
    for i in range(n):
        for j in range(n):
            pos = mi.Point2f(((xs + (i + 0.5) / n) / width).ravel(), ((ys + (j + 0.5) / n) / height).ravel())
            ray, _ = sensor.sample_ray(0.0, 0.5, pos, mi.Point2f(0.5, 0.5))
            si = scene.ray_intersect(ray)
            hits += np.array(si.is_valid(), dtype=float).reshape(height, width)
    del dr
    return hits / (n * n)


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("scene")
    parser.add_argument("--res", default="320x180")
    parser.add_argument("--renders", type=int, default=8)
    parser.add_argument("--spp", type=int, default=4)
    args = parser.parse_args(argv)
    setup_mitsuba()
    from mscloth.compare import REGIONS, depth_and_cloth, reference_image, region_masks, timed_render
    from mscloth.error_budget import LIGHTS, NOISE_SEED, _scene, per_sample_noise
    from mscloth.scenes.builtin import builtin_scene

    width, height = (int(v) for v in args.res.split("x"))
    masks = region_masks(*depth_and_cloth(args.scene, width, height))[0]
    ref, _, _ = reference_image(args.scene, width, height, 1024, quiet=True)
    cover = coverage(builtin_scene(args.scene, width, height), width, height)
    classes = {"interior": cover >= 1.0, "silhouette": (cover > 0.0) & (cover < 1.0)}
    print(f"| {args.scene} | region | method | noise per sample (sun) | silhouette pixels | "
          f"silhouette share of the noise | interior noise per pixel | silhouette noise per pixel |")
    print("|---|---|---|---|---|---|---|---|")
    for multiscale in (True, False):
        scene = _scene(args.scene, width, height, multiscale, LIGHTS["sun"])
        images = [timed_render(scene, args.spp, NOISE_SEED + k).image for k in range(args.renders)]
        noise = per_sample_noise(images, args.spp, ref)
        label = "multi-scale" if multiscale else "brute force"
        for g in REGIONS:
            m = masks[g]
            total = noise[m].sum()
            sil = m & classes["silhouette"]
            inner = m & classes["interior"]
            print(f"| {args.scene} | {g} | {label} | {noise[m].mean():.3g} | {sil.sum()}/{m.sum()} | "
                  f"{noise[sil].sum() / max(total, 1e-30):.0%} | {noise[inner].mean() if inner.any() else 0:.3g} | "
                  f"{noise[sil].mean() if sil.any() else 0:.3g} |", flush=True)
        if multiscale:
            import mitsuba as mi
            out = Path("out") / f"noise-map-{args.scene}.png"
            out.parent.mkdir(exist_ok=True)
            img = np.clip(noise / max(np.percentile(noise[noise > 0], 99), 1e-30), 0, 1)
            mi.util.write_bitmap(str(out), np.repeat(img[..., None], 3, axis=2).astype(np.float32))
            print(f"multi-scale noise map: {out}")
        del scene
    return 0


if __name__ == "__main__":
    sys.exit(main())
