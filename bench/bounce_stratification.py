"""How much of a scene's noise per sample a stratified pixel sampler removes, by path depth,
for the cloth as it is (multi-scale, brute force) and for stand-in BSDFs of one smooth lobe
(``--standin roughconductor``: Mitsuba's anisotropic rough conductor at the satin's
roughness along and across). A BSDF whose sampled directions follow one warp of the
sampler's 2D sample lets ``multijitter`` stratify the light a bounce gathers; a mixture
whose lobe changes from sample to sample (brute force's fibres, or multi-scale's residual
texel lending its tangent) does not. The gap between the two is what sampling the
footprint's aggregate lobe with one continuous warp could gain.

Noise per sample: spp times the variance of a pixel over ``--renders`` independent renders,
over its mean squared (+ RELMSE_EPS), mean over a region's pixels (no reference needed).
``--lights sun`` (or ``sky``) keeps one emitter; the variance is then still over the mean of
the scene with both lit (rendered first), so the lights' shares add up.

    .venv/bin/python bench/bounce_stratification.py satin --depth 2 8 --spp 16 \\
        --samplers independent multijitter --standin roughconductor
"""
from __future__ import annotations

import argparse
import sys

import numpy as np

from common import setup_mitsuba


def standin_bsdf(kind: str, node: dict) -> dict:
    """A stand-in for the cloth BSDF ``node``: one smooth lobe of the cloth's roughness."""
    alpha = float(node.get("roughness", 0.3))
    if kind == "roughconductor":
        return {"type": "roughconductor", "distribution": "ggx", "alpha_u": alpha, "alpha_v": 3.0 * alpha,
                "material": "none", "specular_reflectance": {"type": "rgb", "value": [0.8, 0.8, 0.8]}}
    if kind == "diffuse":
        return {"type": "diffuse", "reflectance": {"type": "rgb", "value": [0.8, 0.8, 0.8]}}
    raise SystemExit(f"unknown stand-in {kind!r}")


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("scene")
    parser.add_argument("--depth", type=int, nargs="+", default=[2, 8])
    parser.add_argument("--spp", type=int, nargs="+", default=[16])
    parser.add_argument("--samplers", nargs="+", default=["independent", "multijitter"])
    parser.add_argument("--standin", nargs="*", default=[])
    parser.add_argument("--res", default="320x180")
    parser.add_argument("--renders", type=int, default=6)
    parser.add_argument("--lights", nargs="+", default=["both"], choices=["both", "sun", "sky"])
    args = parser.parse_args(argv)
    mi = setup_mitsuba()
    from mscloth.evaluation.error_budget import LIGHTS
    from mscloth.evaluation.metrics import RELMSE_EPS
    from mscloth.evaluation.regions import REGIONS, depth_and_cloth, region_masks
    from mscloth.evaluation.renders import scene_dict
    from mscloth.loading import load_dict

    width, height = (int(v) for v in args.res.split("x"))
    masks = region_masks(*depth_and_cloth(args.scene, width, height))[0]
    methods = [("multi-scale", True, None), ("brute force", False, None)]
    methods += [(kind, True, kind) for kind in args.standin]
    print(f"{args.scene}, {args.renders} renders: noise per sample near / middle / far")
    for label, multiscale, kind in methods:
        for sampler in args.samplers:
            for spp in args.spp:
                for depth in args.depth:
                    mean = None
                    for lights in (["both"] + [k for k in args.lights if k != "both"]):
                        scene = scene_dict(args.scene, width, height, multiscale, sampler)
                        scene["integrator"]["max_depth"] = depth
                        for key in LIGHTS["both"]:
                            if key not in LIGHTS[lights]:
                                del scene[key]
                        if kind:
                            for value in scene.values():
                                if isinstance(value, dict) and isinstance(value.get("bsdf"), dict) \
                                        and value["bsdf"].get("type") == "cloth":
                                    value["bsdf"] = standin_bsdf(kind, value["bsdf"])
                        loaded = load_dict(scene)
                        images = np.array([np.array(mi.render(loaded, spp=spp, seed=1000 + 7 * k))[..., :3]
                                           for k in range(args.renders)], dtype=np.float64)
                        if mean is None:
                            mean = images.mean(axis=0)
                        pixel = (images.var(axis=0, ddof=1) * spp / (mean ** 2 + RELMSE_EPS)).mean(axis=-1)
                        noise = [float(pixel[masks[g]].mean()) for g in REGIONS]
                        if lights in args.lights:
                            print(f"{label:>14} {sampler:>12} {spp:>4} spp depth {depth} {lights:>4}: "
                                  + " / ".join(f"{v:.3g}" for v in noise), flush=True)
                        del loaded
    return 0


if __name__ == "__main__":
    sys.exit(main())
