"""Which term blocks the speed-up, per region: multi-scale's noise per sample (sun alone and
sun + sky) and squared bias, for variants of the footprint estimator (issue 20).

Each variant sets class attributes of the ``cloth`` BSDF (``--attr NAME=VALUE``) or cloth
parameters (``--set NAME=VALUE``); the reference is ``mscloth compare``'s cached brute-force
image, so run ``mscloth compare SCENE`` (or ``make bench``) once first.

    .venv/bin/python bench/region_terms.py satin --variant default \\
        --variant "probes 1: --attr MAX_PROBES=1" --variant "no visibility: --set visibility=false"
"""
from __future__ import annotations

import argparse
import shlex
import sys

from common import parse_settings, set_class_attributes, setup_mitsuba


def parse_variant(spec: str):
    """'LABEL: --attr A=1 --set b=2' -> (label, {attr: value}, {param: value})."""
    label, _, rest = spec.partition(":")
    words = shlex.split(rest)
    pairs = list(zip(words[::2], words[1::2]))
    attrs = parse_settings(item for flag, item in pairs if flag == "--attr")
    params = parse_settings(item for flag, item in pairs if flag != "--attr")
    return label.strip(), attrs, params


def measure(name: str, width: int, height: int, attrs: dict, params: dict, renders: int = 8, spp: int = 4,
            bias_spp: int = 256) -> dict:
    """{region: {"noise sun": v, "noise both": v, "bias2": b}} of multi-scale shading with the
    class attributes ``attrs`` and cloth parameters ``params``."""
    from mscloth.compare import REGIONS, depth_and_cloth, reference_image, region_masks, timed_render
    from mscloth.error_budget import BIAS_SEEDS, LIGHTS, NOISE_SEED, _scene, per_sample_noise, squared_bias

    saved = set_class_attributes(attrs)
    try:
        masks = region_masks(*depth_and_cloth(name, width, height))[0]
        ref, ref_var, _ = reference_image(name, width, height, 1024, quiet=True)
        out = {g: {} for g in REGIONS}
        for light in ("sun", "both"):
            scene = _scene(name, width, height, True, LIGHTS[light], **params)
            images = [timed_render(scene, spp, NOISE_SEED + k).image for k in range(renders)]
            noise = per_sample_noise(images, spp, ref)
            for g in REGIONS:
                out[g][f"noise {light}"] = float(noise[masks[g]].mean())
            if light == "both":
                a, b = (timed_render(scene, bias_spp // 2, seed).image for seed in BIAS_SEEDS)
                bias = squared_bias(a, b, ref, ref_var)
                for g in REGIONS:
                    out[g]["bias2"] = float(bias[masks[g]].mean())
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
    args = parser.parse_args(argv)
    setup_mitsuba()
    from mscloth.compare import REGIONS
    width, height = (int(v) for v in args.res.split("x"))
    print(f"| {args.scene} variant | region | noise per sample, sun | noise per sample, sun + sky | bias^2 |")
    print("|---|---|---|---|---|")
    for spec in args.variant or ["default"]:
        label, attrs, params = parse_variant(spec)
        result = measure(args.scene, width, height, attrs, params)
        for g in REGIONS:
            r = result[g]
            print(f"| {label} | {g} | {r['noise sun']:.3g} | {r['noise both']:.3g} | {r['bias2']:.2g} |", flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
