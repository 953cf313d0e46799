"""What a control variate for a uniform sky would leave of each region's noise. With a share
c of the sky taken by it, the sky's light at a camera ray's first hit is c L_env A(wi) (A:
the BSDF's non-delta directional albedo) plus what the sampled directions bring minus c
L_env each. With A known exactly, the noise left is that of the image minus c L_env A(wi),
which ``clothpath.SKY_CONTROL_VARIATE_SHARE`` renders. Noise per sample (16 spp, sun and
sky, against ``mscloth compare``'s cached reference) of multi-scale and brute force, each
without (c = 0) and with the control variate. A lower bound: the variance of A itself
between a pixel's samples (a footprint's probes, brute force's texels) is left out.

    .venv/bin/python bench/sky_control_variate.py plane sphere --share 1 --share 0.5
"""
from __future__ import annotations

import argparse
import sys

from common import setup_mitsuba


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("scenes", nargs="+")
    parser.add_argument("--share", type=float, action="append", default=[],
                        help="the share c of the sky the control variate takes (default: 1)")
    parser.add_argument("--res", default="320x180")
    parser.add_argument("--spp", type=int, default=16)
    parser.add_argument("--renders", type=int, default=4)
    args = parser.parse_args(argv)
    setup_mitsuba()
    from mscloth.evaluation.error_budget import LIGHTS, NOISE_SEED, lit_scene
    from mscloth.evaluation.metrics import per_sample_noise
    from mscloth.evaluation.references import reference_image
    from mscloth.evaluation.regions import REGIONS, depth_and_cloth, region_masks
    from mscloth.evaluation.renders import timed_render
    from mscloth.integrators import clothpath

    width, height = (int(v) for v in args.res.split("x"))
    shares = [0.0] + (args.share or [1.0])
    print(f"| scene | method | sky share c | " + " | ".join(f"noise per sample {g}" for g in REGIONS) + " |")
    print("|---|---|---|" + "---|" * len(REGIONS))
    for name in args.scenes:
        masks = region_masks(*depth_and_cloth(name, width, height))[0]
        ref, _, _ = reference_image(name, width, height, 1024, quiet=True)
        for label, multiscale in (("multi-scale", True), ("brute force", False)):
            for share in shares:
                clothpath.SKY_CONTROL_VARIATE_SHARE = share
                try:
                    scene = lit_scene(name, width, height, multiscale, LIGHTS["both"])
                    images = [timed_render(scene, args.spp, NOISE_SEED + k).image for k in range(args.renders)]
                finally:  # (the next scene's reference, rendered on a cache miss, is the true image)
                    clothpath.SKY_CONTROL_VARIATE_SHARE = 0.0
                noise = per_sample_noise(images, args.spp, ref)
                print(f"| {name} | {label} | {share:g} | "
                      + " | ".join(f"{noise[masks[g]].mean():.3g}" for g in REGIONS) + " |", flush=True)
                del scene
    return 0


if __name__ == "__main__":
    sys.exit(main())
