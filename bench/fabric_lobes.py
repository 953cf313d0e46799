"""How bright and how wide a fabric preset's highlight is, from its fibre-level BSDF
averaged over whole tiles (what a distant pixel sees).

For a view 45 degrees from the normal, looking along the warp or across it, it reports the
tile-mean f cos over a grid of light directions: the peak, the solid angle where it exceeds
half the peak, and the directional albedo; for the preset as it is and with changed
parameters (``--set name=value``, repeatable, each a separate row), e.g. flat floats
(``float_arch=0``, built into the maps) or a thicker yarn layer.

    .venv/bin/python bench/fabric_lobes.py silk-charmeuse --set thickness=20 --set float_arch=0
"""
from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "src"))


def lobe(bsdf, wi, grid: int = 48, per_direction: int = 256, seed: int = 3):
    """(f cos per light direction on a grid over the hemisphere (grid x grid, equal-area in
    cos theta and phi), its solid angle per cell)."""
    import drjit as dr
    import mitsuba as mi

    from mscloth.validation import non_delta_context

    rng = np.random.default_rng(seed)
    i, j = np.meshgrid(np.arange(grid), np.arange(grid), indexing="ij")
    cos_t = (i.ravel() + 0.5) / grid
    phi = 2.0 * np.pi * (j.ravel() + 0.5) / grid
    sin_t = np.sqrt(1.0 - cos_t ** 2)
    wo = np.stack([sin_t * np.cos(phi), sin_t * np.sin(phi), cos_t], axis=1)
    n = len(wo) * per_direction
    rep = np.repeat(np.arange(len(wo)), per_direction)
    si = dr.zeros(mi.SurfaceInteraction3f, n)
    si.uv = mi.Point2f(*rng.random((2, n)))
    si.wi = mi.Vector3f(*[float(c) for c in wi])
    si.sh_frame = mi.Frame3f(mi.Vector3f(0.0, 0.0, 1.0))
    value = np.array(bsdf.eval(non_delta_context(), si, mi.Vector3f(*wo[rep].T)))
    luminance = value.T @ np.array([0.2126, 0.7152, 0.0722])
    fcos = np.bincount(rep, luminance, minlength=len(wo)) / per_direction
    return fcos, 2.0 * np.pi / (grid * grid)


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("fabric")
    parser.add_argument("--set", action="append", default=[], metavar="NAME=VALUE")
    args = parser.parse_args(argv)

    import mitsuba as mi

    import mscloth

    mi.set_variant("llvm_ad_rgb")
    mscloth.register()
    from mscloth.fabrics import fabric

    rows = [("preset", {})] + [(s, dict([s.split("=", 1)])) for s in args.set]
    print(f"{args.fabric}: tile-mean f cos (luminance) for a view 45 deg from the normal")
    print(f"{'variant':22s} {'view':7s} {'peak':>7s} {'half-max sr':>11s} {'albedo':>7s}")
    for label, change in rows:
        params = {"type": "cloth", "fabric": args.fabric, "multiscale": False, "uv_unit": 0.0,
                  "uv_scale": 1.0}
        maps_change = {k: float(v) for k, v in change.items() if k == "float_arch"}
        bsdf_change = {k: float(v) for k, v in change.items() if k != "float_arch"}
        params.update(bsdf_change)
        if maps_change:
            from dataclasses import replace

            from mscloth.fabrics import register_fabric

            name = f"{args.fabric}~{label}"
            register_fabric(replace(fabric(args.fabric), name=name, **maps_change), replace=True)
            params["fabric"] = name
        bsdf = mi.load_dict(params)
        s = np.sqrt(0.5)
        for view, wi in (("along", (0.0, -s, s)), ("across", (-s, 0.0, s))):
            fcos, cell = lobe(bsdf, wi)
            peak = fcos.max()
            print(f"{label:22s} {view:7s} {peak:7.3f} {cell * np.count_nonzero(fcos > 0.5 * peak):11.3f} "
                  f"{fcos.sum() * cell:7.3f}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
