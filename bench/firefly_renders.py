"""Where a swatch view's fireflies come from: render it (the gallery's settings) under
variants of the cloth's parameters and count outlier pixels (luminance over 3x the median
of their 3x3 neighbourhood plus 0.05), in all and in the image's centre columns (where the
view runs along a tile axis).

    .venv/bin/python bench/firefly_renders.py --fabric cotton-jersey \\
        --variant "no parallax: --set parallax=false" --variant "fibre level: --set multiscale=false"
"""
from __future__ import annotations

import argparse
import sys

import numpy as np

from common import set_class_attributes, setup_mitsuba
from region_terms import parse_variant


def outliers(rgb: np.ndarray) -> np.ndarray:
    """Mask of pixels far brighter than the median of their 3x3 neighbourhood."""
    lum = rgb @ np.array([0.2126, 0.7152, 0.0722])
    padded = np.pad(lum, 1, mode="edge")
    h, w = lum.shape
    stack = np.stack([padded[dy:dy + h, dx:dx + w] for dy in range(3) for dx in range(3)])
    return lum > 3.0 * np.median(stack, axis=0) + 0.05


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--fabric", default="cotton-jersey")
    parser.add_argument("--view", default="close")
    parser.add_argument("--res", default="240x180")
    parser.add_argument("--spp", type=int, default=64)
    parser.add_argument("--variant", action="append", default=[])
    args = parser.parse_args(argv)
    mi = setup_mitsuba()
    from mscloth.loading import load_dict
    from mscloth.scenes.swatch import swatch_scene

    width, height = (int(v) for v in args.res.split("x"))
    centre = slice(width // 2 - 3, width // 2 + 3)
    print(f"| {args.fabric} {args.view} ({args.res}, {args.spp} spp) | outlier pixels | in the 6 centre columns "
          "| mean luminance |")
    print("|---|---|---|---|")
    for spec in ["as is"] + args.variant:
        label, attrs, params = parse_variant(spec)
        saved = set_class_attributes(attrs)
        try:
            scene = load_dict(swatch_scene(width, height, args.fabric, args.view, **params))
            rgb = np.array(mi.render(scene, spp=args.spp, seed=0))[..., :3].astype(np.float64)
        finally:
            set_class_attributes(saved)
        mask = outliers(rgb)
        print(f"| {label} | {int(mask.sum())} | {int(mask[:, centre].sum())} | "
              f"{float((rgb @ np.array([0.2126, 0.7152, 0.0722])).mean()):.4f} |", flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
