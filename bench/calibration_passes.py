"""How many passes the footprint mixture's share calibration needs (issue 22: they are most
of a cold start's calibration time): the relative variance of footprint sample weights
after calibrating with each variant of (passes, relaxation), per fabric and incident angle.

    .venv/bin/python bench/calibration_passes.py --variant 12,1 --variant 6,1.5 --variant 4,2

Each variant calibrates in a fresh cache directory (a cached calibration would be reused)."""
from __future__ import annotations

import argparse
import os
import sys
import tempfile
import time

import numpy as np

from common import setup_mitsuba

#: Cloths of the built-in scenes' kind: rough twill (plane), plain weave (sphere), shiny satin.
CLOTHS = {
    "twill 0.3": {"type": "cloth", "pattern": "twill-2-1-S", "diffuse_albedo": {"type": "rgb", "value": [0.42, 0.1, 0.08]},
                  "specular_albedo": 0.45, "specular_transmittance": 0.25, "diffuse_transmittance": 0.05,
                  "roughness": 0.3, "sheen_thickness": 0.3},
    "plain 0.3": {"type": "cloth", "pattern": "plain", "roughness": 0.3, "specular_albedo": 0.4,
                  "diffuse_albedo": 0.3, "specular_transmittance": 0.3, "diffuse_transmittance": 0.1},
    "satin 0.12": {"type": "cloth", "pattern": "satin-8-3", "roughness": 0.12, "specular_albedo": 0.8,
                   "diffuse_albedo": 0.1, "sheen_thickness": 0.1},
}


def weight_relvar(mi, dr, bsdf, theta_deg, n=200_000, footprint_texels=64.0):
    """Relative variance of the footprint mixture's sample weight at ``theta_deg``."""
    rng = np.random.default_rng(5)
    mu = np.cos(np.radians(theta_deg))
    phi = rng.random(n) * 2.0 * np.pi
    s = np.sqrt(1.0 - mu * mu)
    si = dr.zeros(mi.SurfaceInteraction3f, n)
    si.wi = mi.Vector3f(s * np.cos(phi), s * np.sin(phi), np.full(n, mu))
    d = footprint_texels / bsdf.fibre.tile.tile_w
    si.uv = mi.Point2f(rng.random(n), rng.random(n))
    si.duv_dx = mi.Vector2f(d, 0.0)
    si.duv_dy = mi.Vector2f(0.0, d)
    _, weight = bsdf.sample(mi.BSDFContext(), si, mi.Float(rng.random(n)), mi.Point2f(rng.random(n), rng.random(n)))
    w = np.asarray(weight, dtype=np.float64).mean(axis=0)
    return w.var() / w.mean() ** 2


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--variant", action="append", default=[], help="PASSES,RELAXATION[,EARLY_LANES,FINAL_PASSES]")
    parser.add_argument("--angles", default="20,45,70")
    args = parser.parse_args(argv)
    mi = setup_mitsuba()
    import drjit as dr

    from mscloth.bsdf import lobe_calibration

    angles = [float(a) for a in args.angles.split(",")]
    print("| cloth | passes, relaxation, early lanes, final passes | " + " | ".join(f"relvar {a:g} deg" for a in angles) + " | load s |")
    print("|---|---|" + "---|" * (len(angles) + 1))
    for name, params in CLOTHS.items():
        for spec in args.variant or ["12,1"]:
            passes, relax, *lanes = spec.split(",")
            lobe_calibration.SHARE_PASSES, lobe_calibration.SHARE_RELAXATION = int(passes), float(relax)
            early, final = (int(lanes[0]), int(lanes[1])) if lanes else (lobe_calibration.SHARE_LANES, int(passes))
            lobe_calibration.SHARE_EARLY_LANES, lobe_calibration.SHARE_FINAL_PASSES = early, final
            with tempfile.TemporaryDirectory() as cache:
                os.environ["MSCLOTH_CACHE"] = cache
                started = time.perf_counter()
                bsdf = mi.load_dict(params)
                seconds = time.perf_counter() - started
                values = [weight_relvar(mi, dr, bsdf, a) for a in angles]
            print(f"| {name} | {spec} | " + " | ".join(f"{v:.4f}" for v in values) + f" | {seconds:.1f} |",
                  flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
