"""Time of the visibility tables (front and back) of the built-in patterns at their default
resolutions, per direction and in all, on the table build's worker threads (issue 22):

    .venv/bin/python bench/visibility_cost.py [PATTERN ...] [--repeat 3]
"""
from __future__ import annotations

import argparse
import sys
import time

sys.path.insert(0, "src")

from mscloth.maps.builtin import resolve_pattern  # noqa: E402
from mscloth.precompute._util import texel_pitch  # noqa: E402
from mscloth.precompute.visibility import visibility_table  # noqa: E402


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("patterns", nargs="*", default=["twill-2-2", "jersey", "satin-5-2"])
    parser.add_argument("--repeat", type=int, default=3)
    parser.add_argument("--dv", type=int, default=8)
    args = parser.parse_args()
    for name in args.patterns:
        maps = resolve_pattern(name)
        pitch = texel_pitch(maps.height.shape, getattr(maps, "meta", None))
        times = []
        for _ in range(args.repeat):
            t0 = time.perf_counter()
            front = visibility_table(maps.height, args.dv, pitch=pitch, fast=True)
            back = visibility_table(maps.height, args.dv, back=True, pitch=pitch, fast=True)
            times.append(time.perf_counter() - t0)
        print(f"{name:12s} {maps.height.shape}  front+back {min(times):.3f} s (best of {args.repeat}; "
              f"{1e3 * min(times) / (2 * args.dv ** 2):.2f} ms a direction)  escaped {front.mean() / 255:.3f} / {back.mean() / 255:.3f}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
