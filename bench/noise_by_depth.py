"""Where a scene's noise per sample comes from along the path: both methods' noise per
sample per region (sun and sky, 16 spp, relMSE units against ``mscloth compare``'s cached
reference) with the path cut at each ``--depth`` (2: direct light only), for variants of the
cloth (``--set NAME=VALUE``, e.g. ``specular_transmittance=0``). What the noise gains from
one depth to the next is the noise of that bounce's light, which multi-scale shading of the
first hit cannot remove. At several ``--spp`` it shows how each method's noise per sample
falls with the count under the scene's stratified sampler (a noise per sample that stays
is not stratified away). Variants may also set class attributes (``--attr``) or hold one
of the footprint estimator's random numbers at 1/2 (``--freeze xi|round|u|offset``, as in
``region_terms.py``): its change of the noise is that number's share.

    .venv/bin/python bench/noise_by_depth.py sphere --depth 2 3 8 \\
        --variant "opaque: --set specular_transmittance=0 --set diffuse_transmittance=0"
    .venv/bin/python bench/noise_by_depth.py satin --depth 2 --spp 16 64 --variant "u held: --freeze u"
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
    parser.add_argument("--depth", type=int, nargs="+", default=[2, 3, 8])
    parser.add_argument("--variant", action="append", default=[], help="'LABEL: --set NAME=VALUE --attr NAME=VALUE --freeze xi ...'")
    parser.add_argument("--res", default="320x180")
    parser.add_argument("--spp", type=int, nargs="+", default=[16])
    parser.add_argument("--renders", type=int, default=4)
    args = parser.parse_args(argv)
    setup_mitsuba()
    from mscloth.evaluation.error_budget import LIGHTS, NOISE_SEED, lit_scene
    from mscloth.evaluation.metrics import per_sample_noise
    from mscloth.evaluation.references import reference_image
    from mscloth.evaluation.regions import REGIONS, depth_and_cloth, region_masks
    from mscloth.evaluation.renders import timed_render, with_scene_alone

    width, height = (int(v) for v in args.res.split("x"))
    masks = region_masks(*depth_and_cloth(args.scene, width, height))[0]
    ref = reference_image(args.scene, width, height, 1024, quiet=True)[0]
    variants = [("default", {}, {})] + [parse_variant(v) for v in args.variant]
    print(f"{args.scene}, {args.renders} renders: noise per sample near / middle / far")
    for label, attrs, params in variants:
        for spp in args.spp:
            for depth in args.depth:
                noise = {}
                for method, multiscale in (("multi-scale", True), ("brute force", False)):
                    def use(scene):
                        images = [timed_render(scene, spp, NOISE_SEED + k).image for k in range(args.renders)]
                        pixel = per_sample_noise(images, spp, ref)
                        return [float(pixel[masks[g]].mean()) for g in REGIONS]
                    saved = set_class_attributes(attrs if multiscale else {})
                    try:
                        noise[method] = with_scene_alone(
                            lambda: lit_scene(args.scene, width, height, multiscale, LIGHTS["both"],
                                              max_depth=depth, **params), use)
                    finally:
                        set_class_attributes(saved)
                ratio = np.asarray(noise["brute force"]) / np.asarray(noise["multi-scale"])
                print(f"{label:>12} {spp:>4} spp depth {depth}: multi-scale "
                      + " / ".join(f"{v:.3g}" for v in noise["multi-scale"])
                      + "; brute force " + " / ".join(f"{v:.3g}" for v in noise["brute force"])
                      + "; ratio " + " / ".join(f"{v:.2f}" for v in ratio), flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
