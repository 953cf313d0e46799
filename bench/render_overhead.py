"""Per-render cost against per-sample cost, multi-scale and brute force: each render's
seconds at several spp (interleaved rounds, after compilation) fitted as t = c + spp * tau.
c is what every render pays whatever its spp (tracing the kernel in Python, code
generation, film); tau the marginal seconds per sample. A speed-up measured at a few spp
pays c in full; a long render amortises it.

    .venv/bin/python bench/render_overhead.py satin satin-plane plane
"""
from __future__ import annotations

import argparse
import sys

import numpy as np

from common import setup_mitsuba


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("scenes", nargs="+")
    parser.add_argument("--res", default="320x180")
    parser.add_argument("--spps", default="4,16,64")
    parser.add_argument("--rounds", type=int, default=3)
    args = parser.parse_args(argv)
    setup_mitsuba()
    from mscloth.evaluation.error_budget import LIGHTS, lit_scene
    from mscloth.evaluation.renders import timed_render, with_scene_alone

    width, height = (int(v) for v in args.res.split("x"))
    spps = [int(v) for v in args.spps.split(",")]
    print(f"| scene ({args.res}) | method | per render c (s) | per sample tau (ms) | "
          f"c / (c + 16 tau) | tau / tau brute force |")
    print("|---|---|---|---|---|---|")
    for name in args.scenes:
        methods = ("multi-scale", "brute force")

        def loaded(m, use):  # each method's scene alone: a render traces every loaded scene's BSDFs
            return with_scene_alone(lambda: lit_scene(name, width, height, m == "multi-scale", LIGHTS["both"]), use)

        for m in methods:
            loaded(m, lambda scene: timed_render(scene, spps[0], 1))  # compile
        seconds = {m: {s: [] for s in spps} for m in methods}
        for r in range(args.rounds):
            for m in methods:
                def use(scene):
                    timed_render(scene, 1, 1)  # its tables warm
                    return [timed_render(scene, s, 10 + r).seconds for s in spps]
                for s, t in zip(spps, loaded(m, use)):
                    seconds[m][s].append(t)
        fit = {}
        for m in methods:
            t = np.array([np.median(seconds[m][s]) for s in spps])
            tau, c = np.polyfit(np.array(spps, dtype=np.float64), t, 1)
            fit[m] = (c, tau)
        for m, (c, tau) in fit.items():
            print(f"| {name} | {m} | {c:.3f} | {1000 * tau:.1f} | {c / (c + 16 * tau):.0%} | "
                  f"{tau / fit['brute force'][1]:.2f} |", flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
