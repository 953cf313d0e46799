"""The sky albedo table's bias per region, without a reference: what ``clothpath``'s control
variate adds to each pixel's mean at c = 1 is the mean of its recorded term L (A - w) (A: the
table's read, w: the sampled direction's weight), zero where A is the weight's expectation.
Two independent renders of each region's pixels (the render's sampler, ``--spp`` each) give
that mean per pixel; the product of the two halves' means over the pixel's value squared is
an unbiased squared relative bias, averaged per region. At share c the bias is c times it
(``make bench``'s squared bias adds the method's own, small on open cloth). The signed mean
says whether the table reads high or low; by the first hit's view angle (``--angles``) it
says where.

Settings of ``mscloth.bsdf.sky_albedo`` (SHAPE_STEPS, OUTER_BIN_NODES, SAMPLES, OUTER_INSETS,
NODES_PER_BIN, MAX_MIB) can be varied for experiments with ``--attr NAME=VALUE`` (the table
is rebuilt; docs/performance-log.md L62).

    .venv/bin/python bench/sky_table_bias.py plane drape denim --spp 256 --pixels 1000
    .venv/bin/python bench/sky_table_bias.py plane --angles --attr SHAPE_STEPS=0 --attr OUTER_BIN_NODES=2
"""
from __future__ import annotations

import argparse

import numpy as np

from common import parse_settings, setup_mitsuba


def region_pixels(name: str, width: int, height: int, count: int, seed: int) -> dict:
    """{region: (x, y)}: up to ``count`` random pixels of each region of ``compare``."""
    from mscloth.evaluation.regions import REGIONS, depth_and_cloth, region_masks

    depth, cloth = depth_and_cloth(name, width, height)
    masks, _ = region_masks(depth, cloth)
    rng = np.random.default_rng(seed)
    out = {}
    for region in REGIONS:
        y, x = np.nonzero(masks[region])
        pick = rng.permutation(len(x))[:count]
        out[region] = (x[pick], y[pick])
    return out


def view_cosines(scene, x, y, spp: int, seed: int) -> np.ndarray:
    """Per pixel, the mean |cos| of the view angle at the first hit of the camera rays that
    ``clothpath.sky_terms`` traces with the same seed."""
    import drjit as dr
    import mitsuba as mi

    from mscloth.integrators import sky_share_pilot

    rays, _ = sky_share_pilot.camera_rays(scene.sensors()[0], x, y, spp, seed)
    si = scene.ray_intersect(mi.Ray3f(rays))
    cos = dr.abs(dr.dot(si.n, rays.d))
    dr.eval(cos)
    return np.array(cos, dtype=np.float64).reshape(len(x), spp).mean(axis=1)


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("scenes", nargs="+")
    parser.add_argument("--res", default="320x180")
    parser.add_argument("--spp", type=int, default=256,
                        help="samples per pixel of each of the two renders (a square: the multijitter sampler's)")
    parser.add_argument("--pixels", type=int, default=1500, help="pixels per region")
    parser.add_argument("--angles", action="store_true", help="also the signed bias by the view angle")
    parser.add_argument("--attr", action="append", default=[], help="NAME=VALUE of mscloth.bsdf.sky_albedo")
    args = parser.parse_args(argv)
    mi = setup_mitsuba()
    from mscloth.bsdf import sky_albedo
    from mscloth.evaluation.error_budget import lit_scene

    for key, value in parse_settings(args.attr).items():
        if not hasattr(sky_albedo, key):
            raise SystemExit(f"sky_table_bias.py: --attr {key}: mscloth.bsdf.sky_albedo has no such setting")
        setattr(sky_albedo, key, value)
    width, height = (int(v) for v in args.res.split("x"))
    print(f"settings: {args.attr or 'landed'}; {args.spp} spp x 2, {args.pixels} pixels per region")
    print("| scene | region | squared relative bias at c = 1 (standard error) | signed mean, relative | its standard error |")
    print("|---|---|---|---|---|")
    for name in args.scenes:
        scene = lit_scene(name, width, height, True)
        if not scene.integrator().sky_table_possible(scene):
            print(f"| {name} | (no table) | | | |")
            continue
        for region, (x, y) in region_pixels(name, width, height, args.pixels, 11).items():
            (f0, t0), (f1, t1) = (scene.integrator().sky_terms(scene, x, y, args.spp, 101 + k) for k in range(2))
            value = np.maximum(0.5 * (f0 + f1), 1e-6)
            b2 = t0 * t1 / value ** 2
            rel = 0.5 * (t0 + t1) / value
            print(f"| {name} | {region} | {b2.mean():.2e} ({b2.std() / np.sqrt(len(b2)):.0e}) | {rel.mean():+.2e} | "
                  f"{rel.std() / np.sqrt(len(rel)):.1e} |")
            if args.angles:
                cos = view_cosines(scene, x, y, args.spp, 101)
                theta = np.degrees(np.arccos(np.clip(cos, 0.0, 1.0)))
                edges = np.percentile(theta, [0, 25, 50, 75, 100])
                for lo, hi in zip(edges[:-1], edges[1:]):
                    m = (theta >= lo) & (theta <= hi)
                    print(f"|  | {lo:.1f}-{hi:.1f} deg | {b2[m].mean():.2e} ({b2[m].std() / np.sqrt(m.sum()):.0e}) | "
                          f"{rel[m].mean():+.2e} | "
                          f"{rel[m].std() / np.sqrt(m.sum()):.1e} |")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
