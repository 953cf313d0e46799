"""Built-in scenes: ``plane`` (the moiré test), ``sphere`` (near, middle, far) and
``drape`` (backlit draped cloth). Each holds woven and knitted cloth under an environment
light and a sun, rendered with ``clothpath`` so the cloth is shaded multi-scale."""
from __future__ import annotations

import os
from pathlib import Path

import mitsuba as mi

from ..errors import ClothError
from .drape import drape_ply

def T():
    """An identity transform of the active variant (resolved at call time)."""
    return mi.ScalarTransform4f()


def _cloth(pattern: str, colour, uv_scale: float, uv_scale_v: float = 0.0, **extra) -> dict:
    bsdf = {"type": "cloth", "pattern": pattern, "uv_scale": uv_scale,
            "diffuse_albedo": {"type": "rgb", "value": list(colour)},
            "specular_albedo": 0.45, "specular_transmittance": 0.25, "diffuse_transmittance": 0.05,
            "roughness": 0.3, "sheen_thickness": 0.3}
    if uv_scale_v:
        bsdf["uv_scale_v"] = uv_scale_v
    bsdf.update(extra)
    return bsdf


def _base(width: int, height: int, origin, target, fov: float, sun_direction, max_depth: int = 8) -> dict:
    return {
        "type": "scene",
        "integrator": {"type": "clothpath", "max_depth": max_depth},
        "sensor": {"type": "perspective", "fov": fov, "fov_axis": "x",
                   "to_world": T().look_at(origin=origin, target=target, up=[0, 1, 0]),
                   "film": {"type": "hdrfilm", "width": width, "height": height,
                            "rfilter": {"type": "box"}},
                   "sampler": {"type": "independent"}},
        "sky": {"type": "constant", "radiance": {"type": "rgb", "value": [0.5, 0.58, 0.72]}},
        "sun": {"type": "directional", "direction": list(sun_direction),
                "irradiance": {"type": "rgb", "value": [3.0, 2.8, 2.5]}},
    }


def plane_scene(width: int = 512, height: int = 288) -> dict:
    """Cloth from the camera's feet to the horizon at a grazing view: twill on the left,
    jersey on the right. Distant rows are where aliasing and moiré show."""
    scene = _base(width, height, origin=[0, 0.35, 3.0], target=[0, 0.05, -6.0], fov=70,
                  sun_direction=[0.3, -0.35, 0.9])
    for name, x, pattern, colour, scale in (("woven", -20.0, "twill-2-1-S", (0.42, 0.1, 0.08), 500.0),
                                            ("knit", 20.0, "jersey", (0.08, 0.2, 0.42), 600.0)):
        scene[name] = {"type": "rectangle",
                       "to_world": T().translate([x, 0.0, -35.0]) @ T().rotate([1, 0, 0], -90) @ T().scale([20.0, 40.0, 1.0]),
                       "bsdf": _cloth(pattern, colour, scale, scale * 2.0)}
    return scene


def sphere_scene(width: int = 512, height: int = 288) -> dict:
    """Cloth-covered spheres near, in the middle and far away in one frame, woven and
    knitted, on a grey floor."""
    scene = _base(width, height, origin=[0, 0.9, 4.0], target=[0, 0.6, -4.0], fov=55,
                  sun_direction=[0.5, -0.5, -0.7])
    scene["floor"] = {"type": "rectangle", "to_world": T().translate([0, 0, -20]) @ T().rotate([1, 0, 0], -90) @ T().scale(40.0),
                      "bsdf": {"type": "diffuse", "reflectance": {"type": "rgb", "value": [0.35, 0.35, 0.33]}}}
    balls = (("near", [-0.9, 0.6, 1.5], 0.6, "twill-2-2", (0.4, 0.12, 0.1)),
             ("middle", [0.8, 0.6, -3.0], 0.6, "jersey", (0.1, 0.25, 0.4)),
             ("far", [-1.6, 0.6, -12.0], 0.6, "satin-5-2", (0.45, 0.38, 0.1)))
    for name, centre, radius, pattern, colour in balls:
        scene[name] = {"type": "sphere",
                       "to_world": T().translate(centre) @ T().rotate([1, 0, 0], -90) @ T().scale(radius),
                       "bsdf": _cloth(pattern, colour, 40.0, 20.0)}
    return scene


def drape_scene(width: int = 512, height: int = 288, mesh_dir: str | os.PathLike | None = None) -> dict:
    """Woven and knitted cloth draped over two spheres, lit from behind so light passes
    through the gaps between yarns."""
    from ..cache import default_cache_dir

    mesh_dir = Path(mesh_dir) if mesh_dir is not None else default_cache_dir() / "scenes"
    mesh_dir.mkdir(parents=True, exist_ok=True)
    scene = _base(width, height, origin=[0, 1.3, 3.2], target=[0, 0.45, 0], fov=50,
                  sun_direction=[0.0, -0.45, 1.0])  # the sun shines towards the camera
    scene["floor"] = {"type": "rectangle", "to_world": T().rotate([1, 0, 0], -90) @ T().scale(10.0),
                      "bsdf": {"type": "diffuse", "reflectance": {"type": "rgb", "value": [0.3, 0.3, 0.3]}}}
    for name, x, pattern, colour in (("woven", -0.75, "plain", (0.45, 0.1, 0.08)),
                                     ("knit", 0.75, "rib-1-1", (0.1, 0.3, 0.45))):
        ply = drape_ply(mesh_dir, centre=(x, 0.0, 0.0), name=name)
        scene[name] = {"type": "ply", "filename": ply, "face_normals": False,
                       "bsdf": _cloth(pattern, colour, 30.0, diffuse_transmittance=0.1)}
    return scene


SCENES = {"plane": plane_scene, "sphere": sphere_scene, "drape": drape_scene}


def set_cloth_parameters(node, **params) -> int:
    """Set ``params`` on every ``cloth`` BSDF of a scene dictionary (in place); return how
    many there are."""
    count = 0
    if isinstance(node, dict):
        if node.get("type") == "cloth":
            node.update(params)
            count += 1
        for child in node.values():
            count += set_cloth_parameters(child, **params)
    return count


def builtin_scene(name: str, width: int = 512, height: int = 288) -> dict:
    """The scene dictionary of a built-in scene (needs ``mscloth.register()`` to load)."""
    if name not in SCENES:
        raise ClothError(f"unknown scene {name!r}: expected one of {', '.join(SCENES)} or a .xml file")
    return SCENES[name](width, height)
