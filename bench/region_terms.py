"""Which term blocks the speed-up, per region: multi-scale's noise per sample (sun alone and
sun + sky) and squared bias, for variants of the footprint estimator (issue 20).

Each variant sets class attributes of the ``cloth`` BSDF or of its footprint estimator
(``--attr NAME=VALUE``) or cloth parameters (``--set NAME=VALUE``); the reference is
``mscloth compare``'s cached brute-force image, so run ``mscloth compare SCENE`` (or
``make bench``) once first.

    .venv/bin/python bench/region_terms.py satin --variant default \\
        --variant "probes 1: --attr MAX_PROBES=1" --variant "no visibility: --set visibility=false"
"""
from __future__ import annotations

import argparse
import shlex
import sys

import numpy as np

from common import parse_settings, set_class_attributes, setup_mitsuba


def parse_variant(spec: str):
    """'LABEL: --attr A=1 --set b=2 --freeze xi' -> (label, {attr: value}, {param: value}).
    ``--freeze NAME`` (xi, round or u) holds that random number of the estimator at 1/2 for
    every shading point: biased, but its change of the noise is that number's share.
    ``--freeze offset``: the footprint ignores the camera sample's pixel offset, which in
    renders places the probe and the residual texels (``STRATIFY``); the hash's u and xi
    place them instead (freeze those too to hold them)."""
    label, _, rest = spec.partition(":")
    words = shlex.split(rest)
    pairs = list(zip(words[::2], words[1::2]))
    attrs = parse_settings(item for flag, item in pairs if flag == "--attr")
    frozen = [item for flag, item in pairs if flag == "--freeze"]
    if frozen:
        attrs["shading_hash"] = frozen_hash(frozen)
    if "offset" in frozen:
        attrs["footprint"] = footprint_without_offset()
    params = parse_settings(item for flag, item in pairs if flag not in ("--attr", "--freeze"))
    return label.strip(), attrs, params


def frozen_hash(names):
    """The footprint estimator's per-shading-point hash (``FootprintEstimator.shading_hash``,
    which the cloth BSDF calls too) with the random numbers ``names`` held at 1/2."""
    import mitsuba as mi
    from mscloth.bsdf.footprint_estimator import FootprintEstimator

    original = FootprintEstimator.shading_hash

    def hashed(self, si):
        xi, xi_round, u = original(self, si)
        half = mi.Point2f(0.5, 0.5)
        return (half if "xi" in names else xi, half if "round" in names else xi_round,
                mi.Float(0.5) if "u" in names else u)
    return hashed


def footprint_without_offset():
    """``FootprintEstimator.footprint`` as if no pixel offset were known."""
    import dataclasses
    from mscloth.bsdf.footprint_estimator import FootprintEstimator

    original = FootprintEstimator.footprint

    def footprint(self, si, fr, *args, **kwargs):
        return original(self, si, dataclasses.replace(fr, pixel_offset=None), *args, **kwargs)
    return footprint


_DIRECT_REFERENCES = {}


def direct_reference(name: str, width: int, height: int, spp: int):
    """(image, variance of its mean) of brute force, direct sunlight alone, at ``spp``."""
    from mscloth.evaluation.error_budget import LIGHTS, lit_scene
    from mscloth.evaluation.renders import timed_render

    key = (name, width, height, spp)
    if key not in _DIRECT_REFERENCES:
        scene = lit_scene(name, width, height, False, LIGHTS["sun"], max_depth=2)
        a, b = (timed_render(scene, spp // 2, seed).image.astype(np.float64) for seed in (7001, 7002))
        _DIRECT_REFERENCES[key] = (0.5 * (a + b), 0.25 * (a - b) ** 2)
    return _DIRECT_REFERENCES[key]


def measure(name: str, width: int, height: int, attrs: dict, params: dict, renders: int = 8, spp: int = 4,
            bias_spp: int = 256, direct_reference_spp: int = 2048) -> dict:
    """{region: {"noise sun": v, "noise direct sun": v, "noise both": v, "bias2": b,
    "seconds": s}} of multi-scale shading with the class attributes ``attrs`` and cloth
    parameters ``params``: noise per sample with the sun alone, with the sun alone and
    direct light only (``max_depth`` 2: what the footprint estimator adds, without the
    light transport's own noise, which brute force shares), with sun and sky; squared bias
    (sun and sky; and "bias2 direct sun": direct sunlight alone, against a brute-force
    reference of it rendered here at ``direct_reference_spp``); seconds per sample per pixel
    of the image (the median render, sun and sky)."""
    from mscloth.evaluation.error_budget import BIAS_SEEDS, LIGHTS, NOISE_SEED, lit_scene
    from mscloth.evaluation.metrics import per_sample_noise, squared_bias
    from mscloth.evaluation.references import reference_image
    from mscloth.evaluation.regions import REGIONS, depth_and_cloth, region_masks
    from mscloth.evaluation.renders import timed_render

    saved = set_class_attributes(attrs)
    try:
        masks = region_masks(*depth_and_cloth(name, width, height))[0]
        ref, ref_var, _ = reference_image(name, width, height, 1024, quiet=True)
        out = {g: {} for g in REGIONS}
        for label, light, depth in (("sun", "sun", None), ("direct sun", "sun", 2), ("both", "both", None)):
            scene = lit_scene(name, width, height, True, LIGHTS[light], max_depth=depth, **params)
            renders_ = [timed_render(scene, spp, NOISE_SEED + k) for k in range(renders)]
            noise = per_sample_noise([r.image for r in renders_], spp, ref)
            for g in REGIONS:
                out[g][f"noise {label}"] = float(noise[masks[g]].mean())
            if label == "direct sun":
                d_ref, d_var = direct_reference(name, width, height, direct_reference_spp)
                a, b = (timed_render(scene, bias_spp // 2, seed).image for seed in BIAS_SEEDS)
                bias = squared_bias(a, b, d_ref, d_var)
                for g in REGIONS:
                    out[g]["bias2 direct sun"] = float(bias[masks[g]].mean())
            if label == "both":
                seconds = float(np.median([r.seconds for r in renders_])) / spp
                a, b = (timed_render(scene, bias_spp // 2, seed).image for seed in BIAS_SEEDS)
                bias = squared_bias(a, b, ref, ref_var)
                for g in REGIONS:
                    out[g]["bias2"] = float(bias[masks[g]].mean())
                    out[g]["seconds"] = seconds
            del scene
        return out
    finally:
        set_class_attributes(saved)


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("scene")
    parser.add_argument("--variant", action="append", default=[],
                        help="'LABEL: --attr NAME=VALUE --set NAME=VALUE ...' (default: the code as it is)")
    parser.add_argument("--res", default="320x180")
    parser.add_argument("--spp", type=int, default=4,
                        help="samples per pixel of each noise render (a stratified sampler's noise per "
                             "sample depends on it: measure at the count you compare at)")
    args = parser.parse_args(argv)
    setup_mitsuba()
    from mscloth.evaluation.regions import REGIONS
    width, height = (int(v) for v in args.res.split("x"))
    print(f"| {args.scene} variant | region | noise per sample: sun | sun, direct only | sun + sky | "
          "bias^2 | bias^2, direct sun | seconds per spp |")
    print("|---|---|---|---|---|---|---|---|")
    for spec in args.variant or ["default"]:
        label, attrs, params = parse_variant(spec)
        result = measure(args.scene, width, height, attrs, params, spp=args.spp)
        for g in REGIONS:
            r = result[g]
            print(f"| {label} | {g} | {r['noise sun']:.3g} | {r['noise direct sun']:.3g} | {r['noise both']:.3g} | "
                  f"{r['bias2']:.2g} | {r['bias2 direct sun']:.2g} | {r['seconds']:.3g} |", flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
