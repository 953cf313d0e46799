"""Make the README's pattern gallery: contact sheets of the maps and a render of each
pattern with the `cloth` BSDF (docs/images/). Run: .venv/bin/python scripts/gallery.py"""
from __future__ import annotations

import sys
from pathlib import Path

import mitsuba as mi

import mscloth
from mscloth.loading import load_dict
from mscloth.maps.builtin import resolve_pattern
from mscloth.maps.preview import contact_sheet, preview_images
from mscloth.render import render_progressive, write_images

OUT = Path(__file__).resolve().parents[1] / "docs" / "images"
SHARED = Path(__file__).resolve().parents[2] / "shared" / "data" / "wif"

PATTERNS = {
    "twill": ("twill-2-1-S", {"type": "rgb", "value": [0.35, 0.08, 0.06]}, 14),
    "satin": ("satin-8-3", {"type": "rgb", "value": [0.42, 0.33, 0.08]}, 6),
    "wif": (str(SHARED / "2229.wif"), None, 2),
    "jersey": ("jersey", {"type": "rgb", "value": [0.08, 0.2, 0.4]}, 20),
}


def swatch_scene(pattern: str, color, tiles: float, resolution: int = 320) -> dict:
    T = mi.ScalarTransform4f
    albedo = color or 0.5
    return {
        "type": "scene",
        "integrator": {"type": "path", "max_depth": 8},
        "sensor": {"type": "perspective", "fov": 30,
                   "to_world": T().look_at(origin=[0, 1.1, 4.4], target=[0, 0, 0], up=[0, 1, 0]),
                   "film": {"type": "hdrfilm", "width": resolution, "height": resolution}},
        "sky": {"type": "constant", "radiance": {"type": "rgb", "value": [0.5, 0.55, 0.65]}},
        "sun": {"type": "directional", "direction": [-0.4, -0.5, -0.75],
                "irradiance": {"type": "rgb", "value": [3.0, 2.8, 2.5]}},
        # A cloth-covered cylinder lying across the view: the curvature sweeps the highlight.
        "swatch": {"type": "cylinder", "radius": 0.6,
                   "to_world": T().translate([-1.2, 0, 0]) @ T().rotate([0, 1, 0], 90) @ T().scale([1, 1, 2.4]),
                   "bsdf": {"type": "cloth", "pattern": pattern, "uv_scale": tiles,
                            "uv_scale_v": tiles * 2.4 / (2 * 3.14159 * 0.6) * 1.0,
                            "diffuse_albedo": albedo, "specular_albedo": 0.45, "diffuse_transmittance": 0.05,
                            "roughness": 0.25}},
    }


def main() -> int:
    mi.set_variant(mscloth.default_variant())
    mscloth.register()
    OUT.mkdir(parents=True, exist_ok=True)
    wanted = sys.argv[1:] or list(PATTERNS)
    for label, (pattern, color, tiles) in PATTERNS.items():
        if label not in wanted:
            continue
        maps = resolve_pattern(pattern, 256 if label == "jersey" else None)
        contact_sheet(preview_images(maps)).save(OUT / f"{label}_maps.png")
        image = render_progressive(load_dict(swatch_scene(pattern, color, tiles)), 64, label=label)
        write_images(image, OUT / f"{label}_render.exr")
        (OUT / f"{label}_render.exr").unlink()
        print(f"{label}: {OUT / (label + '_maps.png')}, {OUT / (label + '_render.png')}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
