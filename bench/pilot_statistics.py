"""How steady the sky-share pilot's answer is, per scene (performance log L64): its cut over
independent seeds, a crop's pilot against its frame's, and what a share per screen tile
would cut, held out.

* ``seeds``: the pilot (``sky_share_pilot.choose_share`` on ``clothpath.sky_terms``, small
  tables, the render's sampler at ``--spp``) on four independent triples of renders.
* ``crop``: the pilot's pixel estimates in the whole frame and in two crops of it (the same
  pixels of the whole frame), their relative differences and the crops' shares.
* ``tiles``: 16384 pixels rendered six times; c* fitted per screen tile on one pair of
  renders, its variance cut measured on the other two pairs (with the pilot's weights).
* ``regions``: the same with one c* per make bench region (near, middle, far: on the
  built-in scenes, one cloth each), and each region's own cut at its c* and at the frame's.

    .venv/bin/python bench/pilot_statistics.py seeds satin-plane swatch drape sphere denim satin
    .venv/bin/python bench/pilot_statistics.py crop denim
    .venv/bin/python bench/pilot_statistics.py tiles sphere
    .venv/bin/python bench/pilot_statistics.py regions sphere
"""
from __future__ import annotations

import argparse

import numpy as np

from common import setup_mitsuba

CROPS = ((0, 120, 320, 60), (100, 50, 120, 60))
TILES = (0, 160, 80, 40, 20)


def terms(scene, x, y, spp: int, seeds) -> tuple[np.ndarray, np.ndarray]:
    """(F, T), each (len(seeds), pixels): the pilot's renders with those seeds."""
    from mscloth.integrators import sky_share_pilot as pilot

    out = [scene.integrator().sky_terms(scene, x, y, spp, seed, pilot.PILOT_MAX_MIB) for seed in seeds]
    return np.array([f for f, _ in out]), np.array([t for _, t in out])


def seeds(scene, name: str, spp: int) -> None:
    from mscloth.integrators import sky_share_pilot as pilot

    x, y = pilot.pilot_pixels(scene.sensors()[0])
    F, T = terms(scene, x, y, spp, range(1000, 1012))
    runs = [pilot.choose_share(F[3 * i:3 * i + 2], T[3 * i:3 * i + 2], F[3 * i + 2]) for i in range(4)]
    print(f"| {name} | " + " | ".join(f"{p.variance_cut:.3f} ({p.optimal:.2f})" for p in runs) + " |", flush=True)


def crop(name: str, spp: int, res) -> None:
    from mscloth.evaluation.error_budget import lit_scene
    from mscloth.integrators import sky_share_pilot as pilot

    frame = None
    for window in (None, *CROPS):
        scene = lit_scene(name, *res, True, crop=window)
        x, y = pilot.pilot_pixels(scene.sensors()[0])
        F, T = terms(scene, x, y, spp, range(pilot.PILOT_SEED, pilot.PILOT_SEED + 3))
        p = pilot.choose_share(F[:2], T[:2], F[2])
        line = f"| {name} | {window or 'frame'} | {p.share:.2f} | {p.optimal:.2f} | {p.variance_cut:.3f} |"
        if frame is None:
            frame = F
            line += " |"
        else:
            rel = np.abs(F - frame) / (np.abs(frame) + 1e-3)
            q = np.nanquantile(rel.max(axis=0), [0.5, 0.9, 0.99])
            line += " " + " / ".join(f"{v:.2g}" for v in q) + " |"
        print(line, flush=True)
        del scene


def tiles(scene, name: str, spp: int, res, by_region: bool = False) -> None:
    from mscloth.integrators import sky_share_pilot as pilot

    rng = np.random.default_rng(3)
    x, y = rng.integers(0, res[0], 16384), rng.integers(0, res[1], 16384)
    F, T = terms(scene, x, y, spp, range(500, 506))
    M = F.mean(axis=0)
    weight = 1.0 / (M * M + pilot.RELMSE_EPS)
    ok = np.isfinite(F).all(axis=0) & (T != 0).any(axis=0)

    def sums(i, j, sel):
        df, dt = F[i] - F[j], T[i] - T[j]
        return tuple(float(np.sum((weight * a * b)[sel])) for a, b in ((df, df), (dt, dt), (df, dt)))

    if by_region:
        from mscloth.evaluation.regions import REGIONS, depth_and_cloth, region_masks
        masks = region_masks(*depth_and_cloth(name, *res))[0]
        _, vt, cov = sums(0, 1, ok)
        c_frame = float(np.clip(-cov / vt, 0.0, 1.0)) if vt > 0.0 else 0.0
        for g in REGIONS:
            sel = ok & masks[g][y, x]
            _, vt, cov = sums(0, 1, sel)
            c = float(np.clip(-cov / vt, 0.0, 1.0)) if vt > 0.0 else 0.0
            cuts = []
            for share in (c, c_frame):
                base = with_share = 0.0
                for i, j in ((2, 3), (4, 5)):
                    vf2, vt2, cov2 = sums(i, j, sel)
                    base += vf2
                    with_share += vf2 + 2.0 * share * cov2 + share * share * vt2
                cuts.append(1.0 - with_share / base if base > 0.0 else 0.0)
            print(f"| {name} | {g} | {int(sel.sum())} | {c:.2f} / {cuts[0]:.3f} | {c_frame:.2f} / {cuts[1]:.3f} |",
                  flush=True)
        return
    for size in TILES:
        key = np.zeros_like(x) if size == 0 else (y // size) * 100_000 + x // size
        base = with_share = 0.0
        for k in np.unique(key[ok]):
            sel = ok & (key == k)
            _, vt, cov = sums(0, 1, sel)
            c = float(np.clip(-cov / vt, 0.0, 1.0)) if vt > 0.0 else 0.0
            for i, j in ((2, 3), (4, 5)):
                vf2, vt2, cov2 = sums(i, j, sel)
                base += vf2
                with_share += vf2 + 2.0 * c * cov2 + c * c * vt2
        print(f"| {name} | {size or 'frame'} | {1.0 - with_share / base:.3f} |", flush=True)


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("what", choices=("seeds", "crop", "tiles", "regions"))
    parser.add_argument("scenes", nargs="+")
    parser.add_argument("--res", default="320x180")
    parser.add_argument("--spp", type=int, default=16)
    args = parser.parse_args(argv)
    setup_mitsuba()
    from mscloth.evaluation.error_budget import lit_scene

    res = tuple(int(v) for v in args.res.split("x"))
    print({"seeds": "| scene | cut (c*), seeds 1000-1002 | 1003-1005 | 1006-1008 | 1009-1011 |\n|---|---|---|---|---|",
           "crop": "| scene | window | share | c* | cut | relative difference to the frame: median / 90th / 99th percentile |\n"
                   "|---|---|---|---|---|---|",
           "tiles": "| scene | tile (pixels) | held-out cut |\n|---|---|---|",
           "regions": "| scene | region | pixels | its c* / held-out cut | the frame's c* / held-out cut |\n"
                      "|---|---|---|---|---|"}[args.what])
    for name in args.scenes:
        if args.what == "crop":
            crop(name, args.spp, res)
            continue
        scene = lit_scene(name, *res, True)
        if args.what == "seeds":
            seeds(scene, name, args.spp)
        else:
            tiles(scene, name, args.spp, res, by_region=args.what == "regions")
        del scene
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
