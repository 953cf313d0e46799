"""Built-in scenes, rendered with ``clothpath`` so the cloth is shaded multi-scale.

``plane`` (the moiré test), ``sphere`` (near, middle, far) and ``drape`` (backlit draped
cloth) hold woven and knitted cloth under an environment light and a sun. ``satin`` (shiny
satin spheres near, middle, far), ``satin-plane`` (shiny satin to the horizon) and ``denim``
(a 3/1 twill plane) hold dense cloth, whose maps they generate once (:func:`scene_maps`),
under a low sun and a dim environment, where the cloth's own highlights are the noise."""
from __future__ import annotations

import math
import os
from pathlib import Path

import mitsuba as mi

from ..errors import ClothError
from .names import SCENE_NAMES
from .pixel_sampler import sampler_dict
from .drape import drape_ply
from .swatch import swatch_scene

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
                   "sampler": sampler_dict()},
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


# --------------------------------------------------------------------------- shiny satin, denim
#
# Real satin and denim are dense: neighbouring yarns touch, so no light passes between them
# and no dark channels show (the generated maps' default yarn width, 0.8 of the thread
# spacing, leaves 3.5% of the tile as gaps). These scenes generate their maps with
# ``yarn_width`` 1 (gap fraction 0 at texel centres) once into the cache and name the maps
# directory as the BSDF's ``pattern``. Lighting: a low sun (15 degrees above the horizon) and
# a dim sky, so the cloth's own highlights, not the sky's sampling noise, dominate.

#: The dim sky of these scenes, relative to ``_base``'s.
DIM_SKY = 0.08
#: Their low, strong sun: elevation in degrees and irradiance.
LOW_SUN_ELEVATION = 15.0
LOW_SUN_IRRADIANCE = [7.0, 6.5, 5.8]
#: Texels per thread of their maps (128 x 128 for satin-8-3, 64 x 64 for twill-3-1): with
#: footprints of a few texels near the camera, a thread is then ~5 pixels wide there.
TEXELS_PER_THREAD = 16

#: The side of one tile of the maps on the satin spheres and on the satin and denim planes,
#: in scene units: near footprints cover a few texels at 320x180, far ones hundreds to
#: thousands (and more towards the planes' horizon).
SATIN_SPHERE_TILE, SATIN_PLANE_TILE, DENIM_TILE = 0.6, 0.4, 0.4

#: Shiny satin: a warp-faced 8-shaft satin of flat, low-twist filament yarns, packed densely.
SATIN_MAPS = {"pattern": "satin-8-3", "resolution": 8 * TEXELS_PER_THREAD, "yarn_width": 1.0,
              "profile_exponent": 4.0, "fibre_twist_deg": 10.0}
#: Denim: a warp-faced 3/1 Z twill, indigo warp and ecru weft (linear RGB), dense cotton.
DENIM_MAPS = {"pattern": "twill-3-1", "resolution": 4 * TEXELS_PER_THREAD, "yarn_width": 1.0,
              "warp_colors": [0.02, 0.035, 0.12], "weft_colors": [0.7, 0.62, 0.45]}


def _maps_key(spec: dict) -> str:
    """Hash of a maps specification and of the generator's sources (so that a changed
    generator never reuses old maps)."""
    import hashlib

    root = Path(__file__).resolve().parents[1]
    digest = hashlib.sha256(repr(sorted(spec.items())).encode())
    for sub in ("maps", "patterns"):
        for path in sorted((root / sub).glob("*.py")):
            digest.update(path.name.encode() + b"\0" + path.read_bytes())
    return digest.hexdigest()[:12]


def scene_maps(label: str, spec: dict, maps_dir: str | os.PathLike | None = None) -> str:
    """Generate the maps of ``spec`` (``pattern``, ``resolution`` and the other arguments of
    :func:`~mscloth.maps.generate.generate_maps`) once into ``maps_dir`` (default: the
    cache's ``scenes/``), as ``<label>-<key>`` keyed by the specification, and return the
    directory's absolute path, which the ``cloth`` BSDF's ``pattern`` takes. The directory
    appears whole or not at all (written beside it, then renamed)."""
    import shutil

    from ..atomic import temporary_directory
    from ..cache import default_cache_dir, mark_used
    from ..maps.cloth_maps import JSON_NAME, NPZ_NAME
    from ..maps.generate import generate_maps

    parent = Path(maps_dir) if maps_dir is not None else default_cache_dir() / "scenes"
    path = (parent / f"{label}-{_maps_key(spec)}").resolve()
    files = [path / NPZ_NAME, path / JSON_NAME]
    if all(f.is_file() for f in files):
        mark_used(*files)  # for `mscloth cache --clear --older-than`
        return str(path)
    parent.mkdir(parents=True, exist_ok=True)
    params = dict(spec)
    maps = generate_maps(params.pop("pattern"), params.pop("resolution"), **params)
    tmp = temporary_directory(parent, prefix=f".{path.name}.")  # mkdtemp's would be 0700
    try:
        maps.save(tmp, overwrite=True)
        try:
            os.rename(tmp, path)
        except OSError:
            if not all(f.is_file() for f in files):  # not another process's finished copy
                raise
    finally:
        shutil.rmtree(tmp, ignore_errors=True)
    return str(path)


def _low_sun_base(width: int, height: int, origin, target, fov: float, sun_azimuth: float) -> dict:
    """``_base`` with a dim sky and a strong sun LOW_SUN_ELEVATION degrees above the
    horizon, shining towards ``sun_azimuth`` degrees (0: along -z, away from the camera's
    side of the scene; 90: along +x)."""
    el, az = math.radians(LOW_SUN_ELEVATION), math.radians(sun_azimuth)
    direction = [math.cos(el) * math.sin(az), -math.sin(el), -math.cos(el) * math.cos(az)]
    scene = _base(width, height, origin, target, fov, direction)
    sky = scene["sky"]["radiance"]["value"]
    scene["sky"]["radiance"]["value"] = [DIM_SKY * v for v in sky]
    scene["sun"]["irradiance"]["value"] = list(LOW_SUN_IRRADIANCE)
    return scene


def _satin_cloth(maps: str, colour, uv_scale: float, uv_scale_v: float = 0.0) -> dict:
    """Shiny satin: low fibre roughness, a strong specular lobe, little diffuse light, little
    light through the cloth, a light sheen."""
    return _cloth(maps, colour, uv_scale, uv_scale_v, roughness=0.12, specular_albedo=0.8,
                  specular_transmittance=0.05, diffuse_transmittance=0.02, sheen_thickness=0.1)


def satin_scene(width: int = 512, height: int = 288, maps_dir: str | os.PathLike | None = None) -> dict:
    """Shiny satin spheres (``satin-8-3``, roughness 0.12) 6, 14 and 40 units from the camera
    (radii 1, 1.5 and 3, tiles of one size on all three) on a dull floor, under a low sun from
    the right and a dim sky: the satin's glossy highlights close up (single floats), in the
    middle distance and far away (a lustrous band on the lit side)."""
    maps = scene_maps("satin_maps", SATIN_MAPS, maps_dir)
    scene = _low_sun_base(width, height, origin=[0, 1.3, 0], target=[0, 1.0, -14.0], fov=40,
                          sun_azimuth=-70.0)
    scene["floor"] = {"type": "rectangle", "to_world": T().translate([0, 0, -40]) @ T().rotate([1, 0, 0], -90) @ T().scale(80.0),
                      "bsdf": {"type": "diffuse", "reflectance": {"type": "rgb", "value": [0.2, 0.2, 0.19]}}}
    # (name, distance, degrees right of the view axis, radius, colour): champagne, wine, navy.
    balls = (("near", 6.0, -11.0, 1.0, (0.12, 0.09, 0.05)),
             ("middle", 14.0, 4.0, 1.5, (0.12, 0.02, 0.035)),
             ("far", 40.0, 15.0, 3.0, (0.02, 0.035, 0.12)))
    for name, distance, angle, radius, colour in balls:
        a = math.radians(angle)
        centre = [distance * math.sin(a), radius, -distance * math.cos(a)]
        # u spans the equator (2 pi r), v a meridian (pi r); poles up and down.
        tiles = 2.0 * math.pi * radius / SATIN_SPHERE_TILE
        scene[name] = {"type": "sphere",
                       "to_world": T().translate(centre) @ T().rotate([1, 0, 0], -90) @ T().scale(radius),
                       "bsdf": _satin_cloth(maps, colour, tiles, tiles / 2.0)}
    return scene


def satin_plane_scene(width: int = 512, height: int = 288, maps_dir: str | os.PathLike | None = None) -> dict:
    """Shiny satin (``satin-8-3``, roughness 0.12) from the camera's feet to the horizon at a
    grazing view, under a low sun ahead of the camera and a dim sky: the satin's lustre is a
    glossy band from the camera towards the sun's reflection."""
    maps = scene_maps("satin_maps", SATIN_MAPS, maps_dir)
    scene = _low_sun_base(width, height, origin=[0, 0.35, 3.0], target=[0, 0.05, -6.0], fov=70,
                          sun_azimuth=170.0)  # the sun shines towards the camera
    scene["satin"] = {"type": "rectangle",
                      "to_world": T().translate([0.0, 0.0, -40.0]) @ T().rotate([1, 0, 0], -90) @ T().scale([60.0, 45.0, 1.0]),
                      "bsdf": _satin_cloth(maps, (0.12, 0.1, 0.07), 120.0 / SATIN_PLANE_TILE, 90.0 / SATIN_PLANE_TILE)}
    return scene


def denim_scene(width: int = 512, height: int = 288, maps_dir: str | os.PathLike | None = None) -> dict:
    """Denim: a warp-faced 3/1 twill (``twill-3-1``) of indigo warp and ecru weft, roughness
    0.33, from near the camera to the horizon, under a low sun and a dim sky."""
    maps = scene_maps("denim_maps", DENIM_MAPS, maps_dir)
    scene = _low_sun_base(width, height, origin=[0, 1.0, 3.0], target=[0, 0.0, -5.0], fov=70,
                          sun_azimuth=120.0)
    scene["denim"] = {"type": "rectangle",
                      "to_world": T().translate([0.0, 0.0, -40.0]) @ T().rotate([1, 0, 0], -90) @ T().scale([60.0, 45.0, 1.0]),
                      "bsdf": _cloth(maps, (0.6, 0.6, 0.6), 120.0 / DENIM_TILE, 90.0 / DENIM_TILE,
                                     roughness=0.33, specular_albedo=0.35, specular_transmittance=0.1,
                                     diffuse_transmittance=0.05, sheen_thickness=0.15,
                                     sheen_color={"type": "rgb", "value": [0.3, 0.35, 0.5]})}
    return scene


SCENES = {"swatch": swatch_scene, "plane": plane_scene, "sphere": sphere_scene, "drape": drape_scene,
          "satin": satin_scene, "satin-plane": satin_plane_scene, "denim": denim_scene}
if tuple(SCENES) != SCENE_NAMES:  # (the command line lists SCENE_NAMES without importing this module)
    raise ImportError(f"scenes.names.SCENE_NAMES {SCENE_NAMES} differs from the builders {tuple(SCENES)}")


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


def builtin_scene(name: str, width: int = 512, height: int = 288, **options) -> dict:
    """The scene dictionary of a built-in scene (needs ``mscloth.register()`` to load);
    ``options`` go to the scene's function (the swatch's fabric, view and light)."""
    if name not in SCENES:
        raise ClothError(f"unknown scene {name!r}: expected one of {', '.join(SCENES)} or a .xml file")
    return SCENES[name](width, height, **options)
