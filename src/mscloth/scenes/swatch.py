"""Look-development scene: one fabric preset draped over a rounded form, in metres.

A 50 cm square of cloth lies over a 12 cm-radius ball on a grey table and falls in folds;
its UVs are the sheet's rest lengths in metres, so a preset shows its true thread count.
Lighting is a studio rig (a warm key, a cool fill and a strong rim behind the cloth, each a
rectangular area light, over a dim environment) or Mitsuba's ``sunsky``. Three views:
``close`` (about 2.5 cm across, yarns and fibres, parallax on), ``arm`` (arm's length, the
whole swatch) and ``room`` (from about 4.5 m away).
"""
from __future__ import annotations

import os
from pathlib import Path

import mitsuba as mi

from ..errors import ClothError
from .pixel_sampler import sampler_dict

#: Sheet side and the ball's radius, metres.
SWATCH_SIZE, FORM_RADIUS = 0.5, 0.12

#: view -> (camera origin, target, horizontal field of view in degrees).
VIEWS = {
    "close": ([0.0, 0.30, 0.075], [0.0, 0.232, 0.0], 16.0),
    "arm": ([0.0, 0.55, 0.62], [0.0, 0.10, 0.0], 42.0),
    "room": ([0.0, 1.3, 4.4], [0.0, 0.12, 0.0], 12.0),
}
LIGHTS = ("studio", "sunsky")
#: ``sunsky``'s sun and sky scale (:func:`sunsky_lights`).
SUNSKY_SCALE = 1.8


def _area_light(origin, target, size: float, radiance) -> dict:
    T = mi.ScalarTransform4f
    return {"type": "rectangle",
            "to_world": T().look_at(origin=origin, target=target, up=[0, 1, 0]) @ T().scale(size / 2.0),
            "emitter": {"type": "area", "radiance": {"type": "rgb", "value": list(radiance)}}}


def studio_lights() -> dict:
    """Key (warm, above left front), fill (cool, low right) and rim (behind, above) area
    lights aimed at the cloth, and a dim grey environment."""
    centre = [0.0, 0.15, 0.0]
    return {
        "key": _area_light([-0.35, 1.0, 0.6], centre, 0.5, (9.0, 8.3, 7.0)),
        "fill": _area_light([0.9, 0.35, 0.7], centre, 0.6, (0.9, 1.0, 1.15)),
        "rim": _area_light([0.35, 0.75, -0.9], centre, 0.3, (14.0, 14.0, 14.0)),
        "environment": {"type": "constant", "radiance": {"type": "rgb", "value": [0.04, 0.04, 0.045]}},
    }


def sunsky_lights() -> dict:
    """Mitsuba's Hosek-Wilkie ``sunsky``, the sun 35 degrees up to the left front, scaled
    to the studio rig's exposure: at 1.8 the arm's-length view's mean matches the studio's
    (denim, silk charmeuse; Mitsuba 3.9.1's ``sunsky``, whose radiance a 0.06 made about 30x
    too dark)."""
    return {"sunsky": {"type": "sunsky", "sun_direction": [-0.55, 0.57, 0.6], "turbidity": 3.0,
                       "sun_scale": SUNSKY_SCALE, "sky_scale": SUNSKY_SCALE}}


def swatch_ply(mesh_dir: str | os.PathLike | None = None) -> str:
    """The draped 50 cm sheet (UVs in metres) as a PLY file, written once to ``mesh_dir``
    (default: the cache's ``scenes/``). 512 x 512 vertices (1 mm): coarser meshes show the
    shadow terminator's stair steps in the close view."""
    from ..cache import default_cache_dir
    from .drape import drape_ply

    mesh_dir = Path(mesh_dir) if mesh_dir is not None else default_cache_dir() / "scenes"
    mesh_dir.mkdir(parents=True, exist_ok=True)
    return drape_ply(mesh_dir, name="swatch", radius=FORM_RADIUS, size=SWATCH_SIZE, folds=7,
                     resolution=512, uv_size=SWATCH_SIZE, fold_depth=0.3)


def swatch_scene(width: int = 480, height: int = 360, fabric: str = "silk-charmeuse",
                 view: str = "arm", light: str = "studio", mesh_dir: str | os.PathLike | None = None,
                 **cloth) -> dict:
    """The swatch scene dictionary for ``fabric`` (a preset name, see
    :mod:`mscloth.fabrics`) seen from ``view`` (``close``, ``arm``, ``room``) under
    ``light`` (``studio``, ``sunsky``); ``cloth`` overrides the BSDF's parameters."""
    from ..fabrics import fabric as preset

    T = mi.ScalarTransform4f

    structure = preset(fabric).structure  # an unknown name fails here, naming the closest presets
    if view not in VIEWS:
        raise ClothError(f"unknown swatch view {view!r}: expected one of {', '.join(VIEWS)}")
    if light not in LIGHTS:
        raise ClothError(f"unknown swatch lighting {light!r}: expected one of {', '.join(LIGHTS)}")
    origin, target, fov = VIEWS[view]
    ply = swatch_ply(mesh_dir)
    bsdf = {"type": "cloth", "fabric": fabric, "uv_unit": 1.0}
    if view == "close":
        bsdf["parallax"] = True
    bsdf.update(cloth)
    scene = {
        "type": "scene",
        "integrator": {"type": "clothpath", "max_depth": 8, "uv_filter": "tent"},
        "sensor": {"type": "perspective", "fov": fov, "fov_axis": "x",
                   "near_clip": 0.005, "far_clip": 100.0,
                   "to_world": T().look_at(origin=origin, target=target, up=[0, 1, 0]),
                   "film": {"type": "hdrfilm", "width": width, "height": height,
                            "rfilter": {"type": "box"}},
                   "sampler": sampler_dict()},
        "table": {"type": "rectangle", "to_world": T().rotate([1, 0, 0], -90) @ T().scale(6.0),
                  "bsdf": {"type": "diffuse", "reflectance": {"type": "rgb", "value": [0.28, 0.28, 0.27]}}},
        # The rounded form under the cloth: seen through sheer fabrics and through gaps.
        # (Smaller than the ball the drape was shaped on: beyond its cap the sheet is pulled in.)
        "form": {"type": "sphere", "center": [0.0, 1.25 * FORM_RADIUS, 0.0], "radius": 0.72 * FORM_RADIUS,
                 "bsdf": {"type": "diffuse", "reflectance": {"type": "rgb", "value": [0.55, 0.5, 0.45]}}},
        # A weave turned so the warp runs left to right: the key above the camera then lights
        # the warp floats' lustre band along the folds. A knit's wales stay upright, as a
        # garment's: its ribs and columns of loops run up the picture.
        "cloth": {"type": "ply", "filename": ply, "face_normals": False, "bsdf": bsdf,
                  "to_world": T().rotate([0, 1, 0], 90.0 if structure == "woven" else 0.0)},
    }
    scene.update(studio_lights() if light == "studio" else sunsky_lights())
    return scene
