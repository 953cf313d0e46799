"""Where a multi-scale sample's time goes, per scene: seconds per spp of the whole frame
(sun and sky, 16 spp) for variants of the code, in interleaved rounds after compilation,
against brute force (``multiscale`` false) in the same rounds. A variant that switches a
piece off (all lanes fibre level, visibility off, fewer residual texels) prices that piece.

    .venv/bin/python bench/sample_cost.py satin-plane \\
        --variant "all fibre level: --attr POINT_TEXELS=1e9 --attr FOOTPRINT_TEXELS=2e9 --attr BLEND_TEXELS_BY_ROUGHNESS=()"

``--marginal`` times a sample without the render's fixed cost (a render at spp minus one at
spp / 4), which at 16 spp is an eighth of a multi-scale frame (tracing its larger kernel).

``--region near|middle|far`` renders only the bounding box of that region's pixels (a film
crop), so that the time per sample is the region's own rather than the whole frame's.
"""
from __future__ import annotations

import argparse
import sys

import numpy as np

from common import set_class_attributes, setup_mitsuba
from region_terms import parse_variant


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("scene")
    parser.add_argument("--variant", action="append", default=[],
                        help="'LABEL: --attr NAME=VALUE --set NAME=VALUE ...'")
    parser.add_argument("--res", default="320x180")
    parser.add_argument("--spp", type=int, default=16)
    parser.add_argument("--rounds", type=int, default=5)
    parser.add_argument("--region", choices=("near", "middle", "far"), help="time this region's bounding box only")
    parser.add_argument("--marginal", action="store_true",
                        help="time per sample without a render's fixed cost (tracing the kernel, "
                             "launching it, the film): a render at spp minus one at spp / 4, per sample")
    args = parser.parse_args(argv)
    if args.marginal and args.spp < 2:
        parser.error("--marginal needs --spp 2 or more (it subtracts a render at spp / 4)")
    mi = setup_mitsuba()
    from mscloth.evaluation.error_budget import LIGHTS, interleaved_rounds, lit_scene
    from mscloth.evaluation.renders import timed_render, with_scene_alone

    width, height = (int(v) for v in args.res.split("x"))
    quarter = max(args.spp // 4, 1)  # --marginal: the render subtracted
    crop = None
    if args.region:
        from mscloth.evaluation.error_budget import region_crops
        crop = region_crops(args.scene, width, height)[args.region]
        print(f"{args.region}: crop x {crop[0]} y {crop[1]}, {crop[2]}x{crop[3]}")
    variants = [("multi-scale", {}, {}), ("brute force", {}, {"multiscale": False})]
    variants += [parse_variant(v) for v in args.variant]
    def loaded(attrs, params, use):
        """``use(scene)`` with the variant's scene loaded alone (each render would trace
        every loaded scene's BSDFs) and calibrated and rendered under its attributes."""
        saved = set_class_attributes(attrs)
        try:
            return with_scene_alone(
                lambda: lit_scene(args.scene, width, height, params.get("multiscale", True), LIGHTS["both"],
                                  crop=crop, **{k: v for k, v in params.items() if k != "multiscale"}), use)
        finally:
            set_class_attributes(saved)

    def compile_(scene):
        timed_render(scene, args.spp, 1)
        if args.marginal:
            timed_render(scene, quarter, 1)

    for label, attrs, params in variants:
        loaded(attrs, params, compile_)

    def seconds_per_spp(attrs, params):
        def render(r):
            def use(scene):
                timed_render(scene, 1, 1)  # its tables warm
                seconds = timed_render(scene, args.spp, 100 + r).seconds
                if not args.marginal:
                    return seconds / args.spp
                return (seconds - timed_render(scene, quarter, 200 + r).seconds) / (args.spp - quarter)
            return loaded(attrs, params, use)
        return render

    seconds = interleaved_rounds({label: seconds_per_spp(attrs, params) for label, attrs, params in variants},
                                 args.rounds)
    bf = np.array(seconds["brute force"])
    where = f", {args.region} region's box" if args.region else ""
    where += ", marginal: spp minus spp / 4" if args.marginal else ""
    print(f"| {args.scene} ({args.res}{where}, {args.spp} spp) | s per spp (median) | / brute force (median, range) |")
    print("|---|---|---|")
    for label, _, _ in variants:
        s = np.array(seconds[label])
        ratio = s / bf
        print(f"| {label} | {np.median(s):.4f} | {np.median(ratio):.2f}x ({ratio.min():.2f}-{ratio.max():.2f}) |")
    return 0


if __name__ == "__main__":
    sys.exit(main())
