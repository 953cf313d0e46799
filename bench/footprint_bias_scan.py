"""The footprint estimator's bias against brute force over random configurations (issue 20):
random view and light directions, footprint sizes and positions on the `satin` scene's
cloth (satin-8-3, roughness 0.12, 128^2 tile), with and without ``unbiased_ccv``.

For each configuration: the footprint BSDF averaged over shading points (its expectation,
:func:`mscloth.validation.shading_expectation`) against the fibre-level BSDF averaged over
the same parallelogram, and the difference in standard errors. Prints the worst cases and
the RMS relative bias beyond the noise, per footprint size.

    .venv/bin/python bench/footprint_bias_scan.py --configs 40
"""
from __future__ import annotations

import argparse
import sys

import numpy as np

from common import parse_settings, setup_mitsuba

TILE = 128
SATIN = {"type": "cloth", "pattern": "satin-8-3", "resolution": TILE, "roughness": 0.12, "thickness": 2.0,
         "specular_albedo": 0.8, "specular_transmittance": 0.05, "diffuse_albedo": 0.1,
         "diffuse_transmittance": 0.02, "sheen_thickness": 0.1}


def direction(theta_deg: float, phi_deg: float):
    t, p = np.radians(theta_deg), np.radians(phi_deg)
    return [float(np.sin(t) * np.cos(p)), float(np.sin(t) * np.sin(p)), float(np.cos(t))]


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--configs", type=int, default=40)
    parser.add_argument("--halves", default="6,24,96", help="footprint half-widths in texels")
    parser.add_argument("--set", action="append", default=[], help="cloth parameter NAME=VALUE")
    parser.add_argument("--seed", type=int, default=1)
    parser.add_argument("--shear", type=float, default=None, help="every footprint's shear (default: random in [-1, 1])")
    parser.add_argument("--rotate", action="store_true", help="turn each footprint by a random angle too")
    parser.add_argument("--fabric", default=None, help="a fabric preset's cloth instead (uv_scale 1)")
    parser.add_argument("--wo-theta", default="10,85", help="range of the outgoing directions' polar angle (degrees; "
                        "over 90: transmission)")
    args = parser.parse_args(argv)
    mi = setup_mitsuba()
    from mscloth import validation

    base = SATIN if args.fabric is None else {"type": "cloth", "fabric": args.fabric, "uv_scale": 1.0,
                                              "uv_scale_v": 1.0}
    params = dict(base, **parse_settings(args.set))
    bsdf = mi.load_dict(params)
    tile = TILE if args.fabric is None else bsdf.maps.resolution[1]  # texels along u
    wo_lo, wo_hi = (float(v) for v in args.wo_theta.split(","))
    rng = np.random.default_rng(args.seed)
    halves = [float(h) for h in args.halves.split(",")]
    rows = []
    for k in range(args.configs):
        wi = direction(rng.uniform(10, 80), rng.uniform(0, 360))
        wo = direction(rng.uniform(wo_lo, wo_hi), rng.uniform(0, 360))
        uv = [float(rng.random()), float(rng.random())]
        shear = float(rng.uniform(-1.0, 1.0))
        if args.shear is not None:
            shear = args.shear
        half = halves[k % len(halves)]
        rotation = float(rng.uniform(0.0, np.pi)) if args.rotate else 0.0
        si = validation.sheared_interaction(40000, uv, half, shear, tile, wi, rotation)
        ms, ms_err = validation.shading_expectation(bsdf, si, wo, seed=k)
        bf, bf_err = validation.parallelogram_brute_force(params, uv, half, shear, tile, wi, wo, n=80000, seed=k + 100,
                                                          rotation=rotation)
        err = float(np.hypot(ms_err, bf_err))
        rows.append((half, (ms - bf) / max(bf, 1e-9), (ms - bf) / max(err, 1e-12), err / max(bf, 1e-9), wi, wo,
                     uv, shear))
    print(f"| half-width (texels) | configurations | RMS relative difference | RMS noise | "
          f"relative bias beyond noise (RMS) | worst (sigmas) |")
    print("|---|---|---|---|---|---|")
    for half in halves:
        sel = [r for r in rows if r[0] == half]
        rel = np.array([r[1] for r in sel])
        noise = np.array([r[3] for r in sel])
        beyond = np.sqrt(max((rel ** 2).mean() - (noise ** 2).mean(), 0.0))
        worst = max(sel, key=lambda r: abs(r[2]))
        print(f"| {half:g} | {len(sel)} | {np.sqrt((rel ** 2).mean()):.3f} | {np.sqrt((noise ** 2).mean()):.3f} | "
              f"{beyond:.3f} | {worst[2]:+.1f} ({worst[1]:+.1%}) |")
    print("\nWorst configurations (half, relative difference, sigmas, wi, wo, uv, shear):")
    for r in sorted(rows, key=lambda r: -abs(r[2]))[:6]:
        print(f"  {r[0]:g}  {r[1]:+.1%}  {r[2]:+.1f}  wi={np.round(r[4], 2).tolist()}  wo={np.round(r[5], 2).tolist()}"
              f"  uv={np.round(r[6], 3).tolist()}  shear={r[7]:.2f}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
