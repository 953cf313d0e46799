"""Relative variance of the ``cloth`` BSDF's sample weights (f cos / pdf) under uniform
light: the noise one bounce adds when the light behind it is smooth (a sunlit floor, the
sky seen in a shiny sphere). Multi-scale (one footprint of ``a`` texels) against brute force
(a fibre-level sample at a uniform point of the same footprint).

    .venv/bin/python bench/sampling_weights.py            # the satin scenes' BSDF
    .venv/bin/python bench/sampling_weights.py --fabric cotton-jersey
    .venv/bin/python bench/sampling_weights.py --scene plane    # a built-in scene's first cloth
"""
from __future__ import annotations

import argparse
import sys

import numpy as np

from common import parse_settings, setup_mitsuba


def weights(bsdf, n, uv, a_texels, tile, wi, seed, multiscale):
    import drjit as dr
    import mitsuba as mi

    from mscloth.validation import non_delta_context, sheared_interaction

    rng = np.random.default_rng(seed)
    if multiscale:
        si = sheared_interaction(n, uv, a_texels, 0.0, tile, wi)
    else:  # a uniform point of the footprint, shaded at fibre level
        si = sheared_interaction(n, uv, 0.0, 0.0, tile, wi)
        du, dv = (rng.random((2, n)) - 0.5) * a_texels / tile
        si.uv = mi.Point2f(uv[0] + du, uv[1] + dv)
    si.p = mi.Point3f(*(rng.uniform(0, 1, (3, n))))  # the shading hash's source
    sampler = mi.load_dict({"type": "independent"})
    sampler.seed(seed, n)
    bs, w = bsdf.sample(non_delta_context(), si, sampler.next_1d(), sampler.next_2d())
    w = np.asarray(w).mean(axis=0)
    return np.where(np.asarray(bs.pdf) > 0, w, 0.0)


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--set", action="append", default=[], help="NAME=VALUE cloth parameter")
    parser.add_argument("--n", type=int, default=1 << 17)
    parser.add_argument("--fabric", default=None, help="a fabric preset instead (uv_scale 1: footprints in its texels)")
    parser.add_argument("--scene", default=None, help="a built-in scene's first cloth instead (uv_scale 1)")
    parser.add_argument("--texels", default="8,24,70,550,2200", help="footprint areas in texels")
    args = parser.parse_args(argv)
    mi = setup_mitsuba()
    from mscloth.scenes.builtin import SATIN_MAPS, scene_maps, _satin_cloth

    if args.scene:
        from eval_cost import cloth_dict
        spec = dict(cloth_dict(args.scene), uv_scale=1.0)
        spec.pop("uv_scale_v", None)
        tile = mi.load_dict(spec).maps.resolution[1]
    elif args.fabric:
        spec = {"type": "cloth", "fabric": args.fabric, "uv_scale": 1.0, "uv_scale_v": 1.0}
        tile = mi.load_dict(spec).maps.resolution[1]  # footprints in texels along u
    else:
        spec = _satin_cloth(scene_maps("satin_maps", SATIN_MAPS), (0.12, 0.09, 0.05), 1.0)
        tile = SATIN_MAPS["resolution"]
    spec.update(parse_settings(args.set))
    ms = mi.load_dict({**spec, "multiscale": True})
    bf = mi.load_dict({**spec, "multiscale": False})
    print("| theta | azimuth | footprint texels | mean w ms | mean w bf | relvar ms | relvar bf | bf/ms "
          "| max w / mean ms | max w / mean bf |")
    print("|---|---|---|---|---|---|---|---|---|---|")
    for theta, phi in ((30, 0), (60, 0), (60, 45), (75, 90), (85, 30)):
        t, p = np.radians(theta), np.radians(phi)
        wi = [float(np.sin(t) * np.cos(p)), float(np.sin(t) * np.sin(p)), float(np.cos(t))]
        for a in (float(v) for v in args.texels.split(",")):
            uv = [0.37, 0.61]
            r = []
            for b, multiscale in ((ms, True), (bf, False)):
                w = weights(b, args.n, uv, float(np.sqrt(a)), tile, wi, 7, multiscale)
                r.append((w.mean(), w.var() / max(w.mean() ** 2, 1e-12), w.max() / max(w.mean(), 1e-12)))
            print(f"| {theta} | {phi} | {a:g} | {r[0][0]:.4f} | {r[1][0]:.4f} | {r[0][1]:.3f} | {r[1][1]:.3f} "
                  f"| {r[1][1] / max(r[0][1], 1e-9):.2f} | {r[0][2]:.0f} | {r[1][2]:.0f} |")
    return 0


if __name__ == "__main__":
    sys.exit(main())
