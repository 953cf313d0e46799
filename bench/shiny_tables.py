"""Multi-scale tables of a shiny satin at a given tile resolution and roughness, built on an
empty cache (issue 20 item 1: a 512^2 tile within 256 MiB and 30 s on 2 cores): direction
bins, directional SAT rank, build time, table size and the process's peak memory.

    .venv/bin/python bench/shiny_tables.py --resolution 512 --roughness 0.1 0.05
"""
from __future__ import annotations

import argparse
import os
import resource
import sys
import tempfile
import time

from common import setup_mitsuba


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--resolution", type=int, default=512)
    parser.add_argument("--roughness", type=float, nargs="+", default=[0.1, 0.05])
    parser.add_argument("--pattern", default="satin-8-3")
    args = parser.parse_args(argv)
    os.environ["MSCLOTH_CACHE"] = tempfile.mkdtemp(prefix="mscloth-shiny-tables-")
    mi = setup_mitsuba()
    cache = os.environ["MSCLOTH_CACHE"]

    def cache_bytes():
        return sum(os.path.getsize(os.path.join(root, f)) for root, _, files in os.walk(cache) for f in files)

    print("| tile | roughness | direction bins | rank | seconds | cache entry MiB | peak RSS MiB |")
    print("|---|---|---|---|---|---|---|")
    for alpha in args.roughness:
        before = cache_bytes()
        start = time.perf_counter()
        bsdf = mi.load_dict({"type": "cloth", "pattern": args.pattern, "resolution": args.resolution,
                             "roughness": alpha})
        seconds = time.perf_counter() - start
        fd = bsdf.footprint_data
        peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
        print(f"| {args.resolution}^2 {args.pattern} | {alpha:g} | {fd.dr} | {bsdf.direction_rank or 'full'} | "
              f"{seconds:.1f} | {(cache_bytes() - before) / 2**20:.0f} | {peak:.0f} |", flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
