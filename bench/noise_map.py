"""Where a scene's noise per sample lies, as pictures: the noise per sample of each pixel
(relative, as `make bench` measures it, sun alone) of multi-scale and brute force, written
as greyscale PNGs (out/noise-map-SCENE-METHOD.png, white: the 99th percentile of
multi-scale's) with each region's mean printed (issue 20).

On `satin` this showed the spheres' lower halves (facing the sunlit floor: light transport
noise both methods share) and the pattern's floats near the camera.

    .venv/bin/python bench/noise_map.py satin
"""
from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

from common import setup_mitsuba


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("scene")
    parser.add_argument("--res", default="320x180")
    parser.add_argument("--renders", type=int, default=8)
    parser.add_argument("--spp", type=int, default=4)
    args = parser.parse_args(argv)
    mi = setup_mitsuba()
    from mscloth.evaluation.error_budget import LIGHTS, NOISE_SEED, lit_scene
    from mscloth.evaluation.metrics import per_sample_noise
    from mscloth.evaluation.references import reference_image
    from mscloth.evaluation.regions import REGIONS, depth_and_cloth, region_masks
    from mscloth.evaluation.renders import timed_render

    width, height = (int(v) for v in args.res.split("x"))
    masks = region_masks(*depth_and_cloth(args.scene, width, height))[0]
    ref, _, _ = reference_image(args.scene, width, height, 1024, quiet=True)
    white = None
    print(f"| {args.scene} | method | " + " | ".join(f"noise per sample, {g} (sun)" for g in REGIONS) + " |")
    print("|---|---|" + "---|" * len(REGIONS))
    for multiscale in (True, False):
        label = "multi-scale" if multiscale else "brute force"
        scene = lit_scene(args.scene, width, height, multiscale, LIGHTS["sun"])
        images = [timed_render(scene, args.spp, NOISE_SEED + k).image for k in range(args.renders)]
        noise = per_sample_noise(images, args.spp, ref)
        print(f"| {args.scene} | {label} | " + " | ".join(f"{noise[masks[g]].mean():.3g}" for g in REGIONS) + " |")
        if white is None:
            white = max(float(np.percentile(noise[noise > 0], 99)), 1e-30)
        out = Path("out") / f"noise-map-{args.scene}-{'multiscale' if multiscale else 'bruteforce'}.png"
        out.parent.mkdir(exist_ok=True)
        grey = np.clip(noise / white, 0.0, 1.0).astype(np.float32)
        mi.util.write_bitmap(str(out), np.repeat(grey[..., None], 3, axis=2))
        print(f"  {out}")
        del scene
    return 0


if __name__ == "__main__":
    sys.exit(main())
