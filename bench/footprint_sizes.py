"""How large a built-in scene's pixel footprints are, per region, in texels of each cloth's
tile: which branch of the footprint estimator a region takes (fibre level below
``POINT_TEXELS``, blended up to ``FOOTPRINT_TEXELS``, whole footprints above; issue 20).

    .venv/bin/python bench/footprint_sizes.py satin satin-plane denim
"""
from __future__ import annotations

import argparse
import sys

import numpy as np

from common import setup_mitsuba


def footprint_texels(name: str, width: int, height: int) -> dict:
    """{region: (pixels, 10th, 50th, 90th percentile of the footprint's area in texels)} of
    the camera rays' first hits on cloth (``clothpath``'s footprint AOVs, one sample per
    pixel at the pixel centre's footprint)."""
    import mitsuba as mi

    from mscloth.evaluation.regions import REGIONS, depth_and_cloth, region_masks
    from mscloth.evaluation.renders import scene_dict

    d = scene_dict(name, width, height, True)
    d["integrator"]["footprint_aovs"] = True
    scene = mi.load_dict(d)
    image = np.asarray(mi.render(scene, spp=1, seed=1))
    names = list(scene.integrator().aov_names())
    channels = image.shape[-1]
    first = channels - len(names)
    tu = image[..., first + names.index("footprint_texels_u")]
    tv = image[..., first + names.index("footprint_texels_v")]
    area = tu * tv
    masks = region_masks(*depth_and_cloth(name, width, height))[0]
    out = {}
    for g in REGIONS:
        values = area[masks[g] & (area > 0.0)]
        if values.size == 0:
            out[g] = (0, 0.0, 0.0, 0.0)
            continue
        out[g] = (int(values.size), *(float(np.percentile(values, q)) for q in (10, 50, 90)))
    return out


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("scenes", nargs="+")
    parser.add_argument("--res", default="320x180")
    args = parser.parse_args(argv)
    setup_mitsuba()
    width, height = (int(v) for v in args.res.split("x"))
    print("| scene | region | pixels | footprint texels: 10th / 50th / 90th percentile |")
    print("|---|---|---|---|")
    for name in args.scenes:
        for g, (n, p10, p50, p90) in footprint_texels(name, width, height).items():
            print(f"| {name} | {g} | {n} | {p10:.3g} / {p50:.3g} / {p90:.3g} |", flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
