"""What a control variate for a uniform sky would leave of each region's noise. With a share
c of the sky taken by it, the sky's light at a camera ray's first hit is c L_env A(wi) (A:
the BSDF's non-delta directional albedo) plus what the sampled directions bring minus c
L_env each (``clothpath.SKY_CONTROL_VARIATE_SHARE``, docs/performance-log.md L59).

Per scene, method and c, noise per sample (16 spp, sun and sky, four renders, against
``mscloth compare``'s cached reference) of:

* ``residual``: the image minus c L_env A(wi), i.e. with A known exactly; a lower bound, as
  it leaves out how A varies between a pixel's samples (a footprint's probes, brute force's
  texels);
* ``A from K samples`` (``--albedo-samples K``): the whole estimator, A estimated by the
  mean weight of K non-delta samples of the BSDF in the sampled direction's state
  (``clothpath.SKY_ALBEDO_SAMPLES``): unbiased, so its squared bias (two 128-spp halves) is
  the method's own; its noise tends, as K grows, to what a table of each probe's A would
  leave (the part that falls as 1 / K is the samples').

* ``A from the table`` (``--table``): the landed estimator, A from the sky albedo table
  (``clothpath.SKY_TABLE_SHARE``, docs/performance-log.md L60): its squared bias adds the
  table's error to the method's own.

c = 0 is the method without either (the landed table switched off too). Times are not the
point (K samples cost K BSDF samples; ``bench/sample_cost.py --variant "...: --attr
SKY_TABLE_SHARE=0"`` prices the table's reads).

    .venv/bin/python bench/sky_control_variate.py plane sphere --share 0.5 --share 1 --albedo-samples 32
    .venv/bin/python bench/sky_control_variate.py satin denim --share 0.5 --share 1 --table --no-residual \
        --multiscale-only
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
    parser.add_argument("--albedo-samples", type=int, action="append", default=[],
                        help="K: also the whole estimator, A from K BSDF samples")
    parser.add_argument("--table", action="store_true",
                        help="also the landed estimator: A from the sky albedo table (clothpath.SKY_TABLE_SHARE)")
    parser.add_argument("--no-residual", action="store_true", help="leave out the residual (A exact) rows")
    parser.add_argument("--multiscale-only", action="store_true", help="leave out brute force")
    parser.add_argument("--res", default="320x180")
    parser.add_argument("--spp", type=int, default=16)
    parser.add_argument("--renders", type=int, default=4)
    args = parser.parse_args(argv)
    setup_mitsuba()
    from mscloth.evaluation.error_budget import BIAS_SEEDS, LIGHTS, NOISE_SEED, lit_scene
    from mscloth.evaluation.metrics import per_sample_noise, squared_bias
    from mscloth.evaluation.references import reference_image
    from mscloth.evaluation.regions import REGIONS, depth_and_cloth, region_masks
    from mscloth.evaluation.renders import timed_render
    from mscloth.integrators import clothpath

    width, height = (int(v) for v in args.res.split("x"))
    shares = args.share or [1.0]
    cases = [("as it is", 0.0, 0)]
    for share in shares:
        if not args.no_residual:
            cases.append(("residual", share, 0))
        cases += [(f"A from {k} samples", share, k) for k in args.albedo_samples]
        if args.table:
            cases.append(("A from the table", share, -1))
    print("| scene | method | c | estimator | noise per sample " + " / ".join(REGIONS)
          + " | squared bias " + " / ".join(REGIONS) + " |")
    print("|---|---|---|---|---|---|")
    for name in args.scenes:
        masks = region_masks(*depth_and_cloth(name, width, height))[0]
        ref, ref_var, _ = reference_image(name, width, height, 1024, quiet=True)
        methods = (("multi-scale", True),) if args.multiscale_only else (("multi-scale", True), ("brute force", False))
        for label, multiscale in methods:
            for estimator, share, k in cases:
                landed = clothpath.SKY_TABLE_SHARE
                if k < 0:
                    clothpath.SKY_TABLE_SHARE = share
                else:  # ("as it is": the method without the landed control variate)
                    clothpath.SKY_TABLE_SHARE = 0.0
                    clothpath.SKY_CONTROL_VARIATE_SHARE, clothpath.SKY_ALBEDO_SAMPLES = share, k
                try:
                    scene = lit_scene(name, width, height, multiscale, LIGHTS["both"])
                    images = [timed_render(scene, args.spp, NOISE_SEED + j).image for j in range(args.renders)]
                    bias = None
                    if estimator != "residual":  # (the residual's mean is not the image's)
                        a, b = (timed_render(scene, 128, seed).image for seed in BIAS_SEEDS)
                        bias = squared_bias(a, b, ref, ref_var)
                finally:  # (the next scene's reference, rendered on a cache miss, is the true image)
                    clothpath.SKY_CONTROL_VARIATE_SHARE, clothpath.SKY_ALBEDO_SAMPLES = 0.0, 0
                    clothpath.SKY_TABLE_SHARE = landed
                noise = per_sample_noise(images, args.spp, ref)
                biases = "-" if bias is None else " / ".join(f"{bias[masks[g]].mean():.2g}" for g in REGIONS)
                print(f"| {name} | {label} | {share:g} | {estimator} | "
                      + " / ".join(f"{noise[masks[g]].mean():.3g}" for g in REGIONS) + f" | {biases} |", flush=True)
                del scene
    return 0


if __name__ == "__main__":
    sys.exit(main())
