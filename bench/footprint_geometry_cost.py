"""What the footprint's geometry and branch cost a sample, per scene (performance log L65):
``sample_cost.py`` with two more variants, every lane fibre level (the footprint still
computed, its blend never taking it) and the same with each shading point's ``si.duv_dx``,
``si.duv_dy`` zeroed before ``FootprintEstimator.footprint`` (Dr.Jit then folds the
geometry away and traces no footprint branch). Their difference bounds what skipping the
footprint at vertices without one (after a camera ray's first hit) could save.

    .venv/bin/python bench/footprint_geometry_cost.py sphere --marginal --rounds 5
"""
from __future__ import annotations

import sys

import sample_cost
from region_terms import parse_variant

FIBRE_LEVEL = ("--attr POINT_TEXELS=1e9 --attr FOOTPRINT_TEXELS=2e9 --attr BLEND_TEXELS_BY_ROUGHNESS=() "
               "--attr EXACT_BLEND_TEXELS=(1e9,2e9)")
NO_GEOMETRY = "no footprint geometry"


def variant(spec: str):
    """``parse_variant``, and for the label NO_GEOMETRY a ``footprint`` method that zeroes
    the interaction's uv differentials first."""
    label, attrs, params = parse_variant(spec)
    if label == NO_GEOMETRY:
        import mitsuba as mi
        from mscloth.bsdf.footprint_estimator import FootprintEstimator

        original = FootprintEstimator.footprint

        def footprint(self, si, fr, *args, **kwargs):
            si = mi.SurfaceInteraction3f(si)
            si.duv_dx, si.duv_dy = mi.Vector2f(0.0), mi.Vector2f(0.0)
            return original(self, si, fr, *args, **kwargs)
        attrs["footprint"] = footprint
    return label, attrs, params


def main(argv=None) -> int:
    sample_cost.parse_variant = variant
    argv = list(sys.argv[1:] if argv is None else argv)
    return sample_cost.main(argv + ["--variant", f"all fibre level: {FIBRE_LEVEL}",
                                    "--variant", f"{NO_GEOMETRY}: {FIBRE_LEVEL}"])


if __name__ == "__main__":
    sys.exit(main())
