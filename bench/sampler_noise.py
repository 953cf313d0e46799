"""How a scene's noise depends on the pixel sampler, per region and method (issue 20).

Multi-scale shades one slice (probe) of a long, turned footprint per sample, picked by the
sample's position in its pixel: under the independent sampler a pixel's samples pick
slices at random, under a stratified one they spread over them. This measures the relative
variance of a pixel's mean at ``spp`` (not per sample: stratification does not scale as
1/spp) of both methods under each sampler, and the equal-spp noise ratio.

    .venv/bin/python bench/sampler_noise.py satin-plane --samplers independent multijitter --spp 16
"""
from __future__ import annotations

import argparse
import sys

import numpy as np

from common import setup_mitsuba


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("scene")
    parser.add_argument("--res", default="320x180")
    parser.add_argument("--renders", type=int, default=8)
    parser.add_argument("--spp", type=int, nargs="+", default=[16])
    parser.add_argument("--samplers", nargs="+", default=["independent", "multijitter"])
    args = parser.parse_args(argv)
    setup_mitsuba()
    from mscloth.evaluation.error_budget import NOISE_SEED
    from mscloth.evaluation.metrics import RELMSE_EPS
    from mscloth.evaluation.references import reference_image
    from mscloth.evaluation.regions import REGIONS, depth_and_cloth, region_masks
    from mscloth.evaluation.renders import scene_dict, timed_render
    from mscloth.loading import load_dict

    width, height = (int(v) for v in args.res.split("x"))
    masks = region_masks(*depth_and_cloth(args.scene, width, height))[0]
    ref, _, _ = reference_image(args.scene, width, height, 1024, quiet=True)
    ref = np.asarray(ref, np.float64)[..., :3]
    print(f"| {args.scene}: sampler | spp | " + " | ".join(
        f"{g}: multi-scale / brute force (ratio)" for g in REGIONS) + " | seconds: ms / bf |")
    print("|---|---|" + "---|" * len(REGIONS) + "---|")
    for sampler in args.samplers:
        for spp in args.spp:
            noise, seconds = {}, {}
            for multiscale in (True, False):
                scene = load_dict(scene_dict(args.scene, width, height, multiscale, sampler=sampler))
                renders = [timed_render(scene, spp, NOISE_SEED + k) for k in range(args.renders)]
                images = np.asarray([r.image for r in renders], np.float64)
                var = (images.var(axis=0, ddof=1) / (ref ** 2 + RELMSE_EPS)).mean(axis=-1)
                noise[multiscale] = [float(var[masks[g]].mean()) for g in REGIONS]
                seconds[multiscale] = float(np.median([r.seconds for r in renders]))
                del scene
            cells = [f"{m:.3g} / {b:.3g} ({b / m:.1f}x)" for m, b in zip(noise[True], noise[False])]
            print(f"| {sampler} | {spp} | " + " | ".join(cells) + f" | {seconds[True]:.2f} / {seconds[False]:.2f} |",
                  flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
