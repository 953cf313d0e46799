"""The default scene of ``make demo`` (real fabrics: a silk charmeuse and a denim drape)
and the scene ``make bench`` measures the BSDF's cost in (a cloth-covered sphere on a
cloth plane that recedes toward the horizon, under an environment light and a sun)."""
from __future__ import annotations

import os

import mitsuba as mi

from .pixel_sampler import sampler_dict

#: The demo's fabrics, left and right.
DEMO_FABRICS = ("silk-charmeuse", "denim")


def demo_scene(resolution: int = 512, max_depth: int = 8, mesh_dir: str | os.PathLike | None = None) -> dict:
    """Two fabric presets draped over rounded forms on a table, side by side, at a little
    more than arm's length under the swatch scene's studio rig: silk charmeuse (lustre bands
    along its folds) and denim (indigo twill). Scene dictionary for ``mi.load_dict`` (needs
    ``mscloth.register()`` first); meshes are written once to ``mesh_dir`` (default: the
    cache's ``scenes/``)."""
    from .swatch import studio_lights, swatch_ply

    T = mi.ScalarTransform4f
    ply = swatch_ply(mesh_dir)
    scene = {
        "type": "scene",
        # The tent filter: the denim's twill is about a pixel's period on the far drape,
        # where the box beat it into rings (clothpath's uv_filter).
        "integrator": {"type": "clothpath", "max_depth": max_depth, "uv_filter": "tent"},
        "sensor": {"type": "perspective", "fov": 50, "fov_axis": "x", "near_clip": 0.01,
                   "to_world": T().look_at(origin=[0.0, 0.5, 0.82], target=[0.0, 0.09, 0.0], up=[0, 1, 0]),
                   "film": {"type": "hdrfilm", "width": resolution, "height": resolution,
                            "rfilter": {"type": "box"}},
                   "sampler": sampler_dict()},
        "table": {"type": "rectangle", "to_world": T().rotate([1, 0, 0], -90) @ T().scale(6.0),
                  "bsdf": {"type": "diffuse", "reflectance": {"type": "rgb", "value": [0.28, 0.28, 0.27]}}},
    }
    for name, x, angle in (("charmeuse", -0.27, 90.0), ("denim", 0.27, 30.0)):
        scene[name] = {"type": "ply", "filename": ply, "face_normals": False,
                       "to_world": T().translate([x, 0.0, 0.0]) @ T().rotate([0, 1, 0], angle),
                       "bsdf": {"type": "cloth", "fabric": DEMO_FABRICS[0] if name == "charmeuse" else DEMO_FABRICS[1],
                                "uv_unit": 1.0}}
    scene.update(studio_lights())
    return scene


def cost_scene(resolution: int = 512, max_depth: int = 8) -> dict:
    """The scene ``make bench`` measures per-sample cost in: a plain-weave cloth sphere on
    a cloth plane to the horizon, sky and sun (the demo of earlier versions, kept so the
    performance log stays comparable). Scene dictionary for ``mi.load_dict``."""
    T = mi.ScalarTransform4f
    return {
        "type": "scene",
        "integrator": {"type": "clothpath", "max_depth": max_depth},
        "sensor": {
            "type": "perspective",
            "fov": 40,
            "to_world": T().look_at(origin=[0.0, 1.15, 4.2], target=[0.0, 0.62, 0.0], up=[0, 1, 0]),
            "film": {"type": "hdrfilm", "width": resolution, "height": resolution,
                     "rfilter": {"type": "box"}},
            "sampler": sampler_dict(),
        },
        "sky": {"type": "constant", "radiance": {"type": "rgb", "value": [0.55, 0.62, 0.75]}},
        "sun": {"type": "directional", "direction": [0.55, -0.45, 0.7],
                "irradiance": {"type": "rgb", "value": [3.2, 2.9, 2.5]}},
        # Ground cloth: 60 x 60 units, one tile (two yarns) every 0.2 units.
        "plane": {
            "type": "rectangle",
            "to_world": T().translate([0.0, 0.0, -25.0]) @ T().rotate([1, 0, 0], -90) @ T().scale(30.0),
            "bsdf": {
                "type": "cloth", "pattern": "plain", "uv_scale": 300.0,
                "roughness": 0.25, "thickness": 2.0,
                "specular_albedo": {"type": "rgb", "value": [0.45, 0.2, 0.15]},
                "specular_transmittance": {"type": "rgb", "value": [0.3, 0.12, 0.1]},
                "diffuse_albedo": {"type": "rgb", "value": [0.45, 0.08, 0.06]},
                "diffuse_transmittance": {"type": "rgb", "value": [0.1, 0.02, 0.02]},
                "sheen_color": {"type": "rgb", "value": [0.6, 0.35, 0.3]},
            },
        },
        # Sphere: u spans the equator (2 pi r), v a meridian (pi r): half the tiles along v.
        "ball": {
            "type": "sphere",
            # Poles up and down, so the seam-free side of the weave faces the camera.
            "to_world": T().translate([0.0, 0.75, 0.0]) @ T().rotate([1, 0, 0], -90) @ T().scale(0.75),
            "bsdf": {
                "type": "cloth", "pattern": "plain", "uv_scale": 36.0, "uv_scale_v": 18.0,
                "roughness": 0.3, "thickness": 2.5,
                "specular_albedo": {"type": "rgb", "value": [0.35, 0.4, 0.45]},
                "specular_transmittance": {"type": "rgb", "value": [0.3, 0.35, 0.45]},
                "diffuse_albedo": {"type": "rgb", "value": [0.1, 0.22, 0.42]},
                "diffuse_transmittance": {"type": "rgb", "value": [0.05, 0.1, 0.12]},
                "sheen_color": {"type": "rgb", "value": [0.5, 0.55, 0.65]},
            },
        },
    }
