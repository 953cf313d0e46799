"""Which random number of one footprint evaluation carries its variance (issue 20, item 3):
the residual texels' places (xi), the SAT corners' rounding (round) or the probe's choice
(probe). For each footprint size and direction pair of ``footprint_estimator.py``, the
variance ratio (one evaluation over one fibre-level sample of the footprint) with every
number random, and with each one held at 1/2 in turn (biased, but the drop is that
number's share).

    .venv/bin/python bench/estimator_variance_terms.py --roughness 0.1 --halves 24 192
"""
from __future__ import annotations

import argparse
import sys

from footprint_estimator import DIRECTIONS, SATIN


def variance(bsdf, uv, half, tile, wi, wo, frozen, n):
    """Variance of one footprint evaluation (red channel) with ``frozen`` numbers held."""
    from mscloth import validation
    _, err, _ = validation.footprint_expectation(bsdf, uv, half, tile, wi, wo, n=n, frozen=frozen)
    return err * err * n


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--roughness", type=float, nargs="+", default=[0.1])
    parser.add_argument("--halves", type=float, nargs="+", default=[24.0, 192.0])
    parser.add_argument("--n", type=int, default=20000)
    parser.add_argument("--attr", action="append", default=[], metavar="NAME=VALUE")
    args = parser.parse_args(argv)

    from common import parse_settings, set_class_attributes, setup_mitsuba
    mi = setup_mitsuba()
    set_class_attributes(parse_settings(args.attr))
    from mscloth import validation
    uv = [0.3, 0.55]
    print("| roughness | footprint | directions | all | xi fixed | round fixed | probe fixed |")
    print("|---|---|---|---|---|---|---|")
    for alpha in args.roughness:
        params = dict(SATIN, roughness=alpha)
        bsdf = mi.load_dict(params)
        tile = bsdf.fibre.tile.tile_w
        for half in args.halves:
            for name, (wi, wo) in DIRECTIONS.items():
                _, bf_err = validation.brute_force(params, uv, half, tile, wi, wo, n=100000)
                bf_var = bf_err ** 2 * 100000
                cells = [variance(bsdf, uv, half, tile, wi, wo, frozen, args.n) / bf_var
                         for frozen in ((), ("xi",), ("round",), ("probe",))]
                print(f"| {alpha:g} | {2 * half:g}^2 | {name} | " + " | ".join(f"{c:.1e}" for c in cells) + " |",
                      flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
