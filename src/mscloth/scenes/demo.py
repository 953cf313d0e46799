"""The default scene of ``make demo``: a cloth-covered sphere on a cloth plane
that recedes toward the horizon, under an environment light and a sun."""
from __future__ import annotations

import mitsuba as mi


def demo_scene(resolution: int = 512, max_depth: int = 8) -> dict:
    """Scene dictionary for ``mi.load_dict`` (needs ``mscloth.register()`` first)."""
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
            "sampler": {"type": "independent"},
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
