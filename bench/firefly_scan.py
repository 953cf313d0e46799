"""Largest sample weights (f cos / pdf) and eval values (f cos at random outgoing directions)
of the multi-scale ``cloth`` BSDF over a grid of viewing directions near a tile axis and
footprint sizes: whether fireflies come from the BSDF itself.

    .venv/bin/python bench/firefly_scan.py --fabric cotton-jersey
"""
from __future__ import annotations

import argparse
import sys

import numpy as np

from common import setup_mitsuba


def scan(bsdf_dict: dict, n: int = 1 << 16, seed: int = 5, delta: bool = False):
    import drjit as dr
    import mitsuba as mi

    from mscloth.validation import non_delta_context, sheared_interaction

    bsdf = mi.load_dict(bsdf_dict)
    tile = 64
    rows = []
    for azimuth_deg in (0.0, 0.05, 0.3, 1.0, 10.0, 90.0, 90.3):
        for theta_deg in (20.0, 60.0, 80.0):
            for a_texels in (4.0, 20.0, 100.0):
                for rotation in (0.0, 0.002, 0.3):
                    t, p = np.radians(theta_deg), np.radians(azimuth_deg)
                    wi = [np.sin(t) * np.cos(p), np.sin(t) * np.sin(p), np.cos(t)]
                    si = sheared_interaction(n, [0.37, 0.61], a_texels, 0.0, tile, wi, rotation)
                    rng = np.random.default_rng(seed)
                    si.p = mi.Point3f(*(rng.uniform(0, 1, (3, n))))
                    sampler = mi.load_dict({"type": "independent"})
                    sampler.seed(seed, n)
                    ctx = mi.BSDFContext() if delta else non_delta_context()  # delta: the gaps too
                    bs, weight = bsdf.sample(ctx, si, sampler.next_1d(), sampler.next_2d())
                    w = np.asarray(dr.max(weight))
                    ok = np.asarray(bs.pdf) > 0
                    w = np.where(ok, w, 0.0)
                    wo = rng.normal(size=(3, n))
                    wo[2] = np.abs(wo[2])
                    wo /= np.linalg.norm(wo, axis=0)
                    f = np.asarray(dr.max(bsdf.eval(non_delta_context(), si, mi.Vector3f(*wo))))
                    rows.append((azimuth_deg, theta_deg, a_texels, rotation, float(w.max()), float(np.mean(w)),
                                 float(f.max()), float(np.mean(f)),
                                 int(np.sum(~np.isfinite(w)) + np.sum(~np.isfinite(f)))))
    return rows


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--fabric", default="cotton-jersey")
    parser.add_argument("--parallax", action="store_true", help="as the swatch's close view")
    parser.add_argument("--delta", action="store_true", help="sample the gaps' delta lobe too")
    args = parser.parse_args(argv)
    setup_mitsuba()
    rows = scan({"type": "cloth", "fabric": args.fabric, "multiscale": True, "parallax": args.parallax},
                delta=args.delta)
    print("| azimuth deg | theta deg | footprint texels | rotation | max weight | mean weight | max eval "
          "| mean eval | non-finite |")
    print("|---|---|---|---|---|---|---|---|---|")
    for r in sorted(rows, key=lambda r: -max(r[4], r[6]))[:12]:
        print("| " + " | ".join(f"{v:.4g}" if isinstance(v, float) else str(v) for v in r) + " |")
    return 0


if __name__ == "__main__":
    sys.exit(main())
