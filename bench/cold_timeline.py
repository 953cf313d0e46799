"""Where a cold ``mscloth render`` spends its seconds, per thread (issue 22).

Runs the CLI's render in this process with an empty table cache and an empty Dr.Jit kernel
cache (fresh temporary directories) and times the steps of loading each cloth (tables,
their upload, the fuzz's samplers, the calibration) on the thread that ran them, then the
render's compilation and the render. Prints one line per step, in order of start:

    .venv/bin/python bench/cold_timeline.py [SCENE] [--res 320x180] [--spp 16] [--warm]

``--warm`` keeps the caches the first (cold) run filled and times a second run on them in
a new process instead.
"""
from __future__ import annotations

import argparse
import functools
import os
import subprocess
import sys
import tempfile
import threading
import time

T0 = time.perf_counter()
EVENTS: list[tuple[float, float, str, str]] = []


def _timed(owner, name: str, label: str):
    original = getattr(owner, name)

    @functools.wraps(original)
    def wrapper(*args, **kwargs):
        start = time.perf_counter()
        try:
            return original(*args, **kwargs)
        finally:
            EVENTS.append((start - T0, time.perf_counter() - T0, threading.current_thread().name, label))

    setattr(owner, name, wrapper)


def _instrument():
    from mscloth import loading
    from mscloth.bsdf import cloth, footprint_data, lobe_calibration, lobe_mixture
    from mscloth.precompute import tables

    _timed(loading, "load_dict", "load_dict (all)")
    _timed(loading, "load_file", "load_file (all)")
    _timed(cloth, "cloth_maps", "maps (generate or load)")
    _timed(tables, "load_or_build", "tables (build or load)")
    _timed(footprint_data.FootprintData, "__init__", "FootprintData (upload)")
    _timed(lobe_mixture.LobeSamplers, "for_fuzz", "LobeSamplers.for_fuzz")
    _timed(lobe_calibration, "measure_ratios", "calibration: albedo ratios")
    _timed(lobe_calibration, "measure_share_factors", "calibration: share passes")
    # cloth.py imports load_or_build inside a method (the module attribute is read at call
    # time), but binds cloth_maps and calibrate at import: wrap the names it reads.
    _timed(cloth, "calibrate", "calibration (all)")


def child(argv: list[str]) -> int:
    sys.path.insert(0, "src")
    import mscloth  # noqa: F401  (configures LLVM before Dr.Jit starts)

    started = time.perf_counter()
    import mitsuba  # noqa: F401
    from mscloth import cli
    EVENTS.append((started - T0, time.perf_counter() - T0, threading.current_thread().name, "imports"))
    _instrument()
    rc = cli.main(argv)
    EVENTS.sort()
    print(f"\n{'start':>6} {'end':>6}  {'thread':<22} step")
    for start, end, thread, label in EVENTS:
        print(f"{start:6.2f} {end:6.2f}  {thread[:22]:<22} {label}")
    print(f"total {time.perf_counter() - T0:.2f} s")
    return rc


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("scene", nargs="?", default="sphere")
    parser.add_argument("--res", default="320x180")
    parser.add_argument("--spp", type=int, default=16)
    parser.add_argument("--warm", action="store_true")
    parser.add_argument("--child", action="store_true", help=argparse.SUPPRESS)
    args, rest = parser.parse_known_args()
    with tempfile.TemporaryDirectory() as tmp:
        argv = ["render", args.scene, "--res", args.res, "--spp", str(args.spp), "--out", f"{tmp}/out.exr"]
        if args.child:
            return child(argv + rest)
        env = dict(os.environ, MSCLOTH_CACHE=f"{tmp}/tables", DRJIT_CACHE_DIR=f"{tmp}/kernels")
        runs = ("cold", "warm") if args.warm else ("cold",)
        for run in runs:
            print(f"## {run}", flush=True)
            cmd = [sys.executable, __file__, "--child", args.scene, "--res", args.res, "--spp", str(args.spp)]
            rc = subprocess.call(cmd + rest, env=env)
            if rc:
                return rc
    return 0


if __name__ == "__main__":
    sys.exit(main())
