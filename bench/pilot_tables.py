"""Does the sky-share pilot decide from small tables of A as from the full ones? Per scene:
the pilot's share, c* and variance cut (``clothpath.measure_sky_share`` at ``--spp``) with
tables of ``PILOT_MAX_MIB`` and with the full ones (``sky_albedo.MAX_MIB``), and the seconds
each took (its tables' build, the pilot's kernel and renders). ``sky_share`` auto runs the
pilot on the small tables and builds the full ones only where it takes a share
(docs/performance-log.md L63).

    .venv/bin/python bench/pilot_tables.py plane denim drape satin satin-plane sphere swatch
"""
from __future__ import annotations

import argparse
import time

from common import setup_mitsuba


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("scenes", nargs="+")
    parser.add_argument("--res", default="320x180")
    parser.add_argument("--spp", type=int, default=16)
    args = parser.parse_args(argv)
    setup_mitsuba()
    from mscloth.bsdf import sky_albedo
    from mscloth.evaluation.error_budget import lit_scene
    from mscloth.integrators import sky_share_pilot

    width, height = (int(v) for v in args.res.split("x"))
    sizes = (("pilot", sky_share_pilot.PILOT_MAX_MIB), ("full", None))
    print(f"{args.spp} spp; pilot tables {sky_share_pilot.PILOT_MAX_MIB} MiB, full {sky_albedo.MAX_MIB} MiB")
    print("| scene | tables | share | c* | variance cut | seconds (tables + pilot) |")
    print("|---|---|---|---|---|---|")
    for name in args.scenes:
        scene = lit_scene(name, width, height, True)
        for label, mib in sizes:
            start = time.perf_counter()
            p = scene.integrator().measure_sky_share(scene, args.spp, mib)
            print(f"| {name} | {label} | {p.share:.2f} | {p.optimal:.2f} | {p.variance_cut:.3f} | "
                  f"{time.perf_counter() - start:.1f} |", flush=True)
        del scene
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
