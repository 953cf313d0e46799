"""The README's fabric gallery: every preset in the swatch scene, close up, at arm's length
and across a room, as small PNGs and one contact sheet.

    .venv/bin/python scripts/fabric_gallery.py           # docs/images/gallery/
    .venv/bin/python scripts/fabric_gallery.py --fabrics denim --views close --out /tmp/g

Renders multi-scale with clothpath under the studio rig (``mscloth.scenes.swatch``).
"""
from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "src"))


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", default=str(ROOT / "docs" / "images" / "gallery"))
    parser.add_argument("--fabrics", nargs="*", default=None, help="presets (default: all)")
    parser.add_argument("--views", nargs="*", default=["close", "arm", "room"])
    parser.add_argument("--light", default="studio", choices=("studio", "sunsky"))
    parser.add_argument("--res", default="240x180", help="WIDTHxHEIGHT of each picture")
    parser.add_argument("--spp", type=int, default=64)
    parser.add_argument("--sheet-only", action="store_true",
                        help="only compose the contact sheet from the PNGs already in --out")
    args = parser.parse_args(argv)

    import mitsuba as mi

    import mscloth

    mi.set_variant("llvm_ad_rgb")
    mscloth.register()
    from PIL import Image, ImageDraw

    from mscloth.fabrics import FABRICS
    from mscloth.loading import load_dict
    from mscloth.scenes.swatch import swatch_scene

    width, height = (int(v) for v in args.res.split("x"))
    names = args.fabrics or list(FABRICS)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    tiles = {}
    for name in names:
        for view in args.views:
            if args.sheet_only:
                tiles[name, view] = Image.open(out / f"{name}-{view}.png").convert("RGB")
                continue
            started = time.perf_counter()
            scene = load_dict(swatch_scene(width, height, name, view, args.light))
            image = mi.render(scene, spp=args.spp, seed=0)
            rgb = mi.TensorXf(image)[..., :3]  # clothpath appends footprint AOVs
            if not np.all(np.isfinite(np.array(rgb))):
                raise SystemExit(f"gallery: {name} ({view}) rendered non-finite values")
            srgb = mi.Bitmap(rgb).convert(mi.Bitmap.PixelFormat.RGB, mi.Struct.Type.UInt8, srgb_gamma=True)
            png = Image.fromarray(np.array(srgb))
            path = out / f"{name}-{view}.png"
            png.save(path, optimize=True)
            tiles[name, view] = png
            print(f"{path} in {time.perf_counter() - started:.1f} s", flush=True)

    # Contact sheet: one row per fabric, one column per view, names on the left.
    label_w = 130
    sheet = Image.new("RGB", (label_w + width * len(args.views), height * len(names)), (24, 24, 24))
    draw = ImageDraw.Draw(sheet)
    for row, name in enumerate(names):
        draw.text((8, row * height + height // 2 - 6), FABRICS[name].title, fill=(230, 230, 230))
        for col, view in enumerate(args.views):
            sheet.paste(tiles[name, view], (label_w + col * width, row * height))
    sheet.save(out / "contact_sheet.png", optimize=True)
    print(f"wrote {out / 'contact_sheet.png'}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
