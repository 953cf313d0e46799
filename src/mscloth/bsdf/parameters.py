"""Reading and validating the ``cloth`` plugin's parameters.

Errors name the parameter and the allowed range (``ParameterError``); nothing
is clamped silently.
"""
from __future__ import annotations

import difflib
import math
from dataclasses import dataclass, replace

import drjit as dr
import mitsuba as mi
import numpy as np

from ..cloth_limits import ENERGY_PARAMETERS, FLOAT_PARAMETERS, SPECTRUM_PARAMETERS, reflected_bound
from ..errors import ParameterError

#: Switches and table sizes of multi-scale shading: name -> (default, low, high, meaning).
INT_PARAMETERS = {
    "direction_bins": (0, 0, 64, "half-vector bins per side of the directional SAT (dr; 0: from the "
                                 "roughness, 16 at 0.2 and above, 32 down to 0.08, 48 below)"),
    "visibility_bins": (8, 2, 32, "direction bins per side of the visibility tables"),
    "clusters": (8, 1, 32, "visibility clusters for the control variates"),
    "direction_rank": (0, 0, 4096, "rank of the compressed directional SAT (0: full, dr^2 channels, "
                                   "or rank 64 over max_table_mib)"),
    "max_table_mib": (256, 16, 1 << 20, "memory budget (MiB) of a full directional SAT; larger ones "
                                        "are compressed to rank 64"),
    # Accepted for scenes written before footprints were shaded as the pixel's parallelogram.
    "footprint_slices": (1, 1, 4, "no longer used: footprints are the pixel's parallelogram"),
}
BOOL_PARAMETERS = {
    "multiscale": (True, "shade whole pixel footprints (summed-area tables + CCV)"),
    "visibility": (True, "shadowing and masking by the cloth's height field"),
    "unbiased_ccv": (False, "per-cluster base of the control variates (less noise below a tile, 8x the SAT memory, ~2x the time)"),
    "parallax": (False, "shift lookups to where the view ray meets the height field (not reciprocal)"),
}

#: Every parameter the plugin reads: each has one row in the docs' table
#: (:data:`.parameter_docs.PARAMETER_DOCS`; tests/test_parameter_docs.py).
PARAMETER_NAMES = ("fabric", "pattern", "resolution", *FLOAT_PARAMETERS, *SPECTRUM_PARAMETERS, *BOOL_PARAMETERS,
                   *INT_PARAMETERS)


def check_parameter_names(names) -> None:
    """Raise ParameterError naming the first of ``names`` the plugin does not read, with the
    closest parameter it does (Mitsuba's own 'unreferenced property' error is several lines,
    and comes only after the plugin has been built)."""
    for name in names:
        if name in PARAMETER_NAMES:
            continue
        close = difflib.get_close_matches(name, PARAMETER_NAMES, n=1, cutoff=0.6)
        hint = f"did you mean '{close[0]}'?" if close else f"expected one of {', '.join(PARAMETER_NAMES)}"
        raise ParameterError(f"cloth: unknown parameter '{name}': {hint}")


#: How ``traverse`` exposes each parameter, in the letters of Mitsuba's plugin docs: "P"
#: exposed (change it in ``mi.traverse``, then ``params.update()``), "∂" differentiable, "D"
#: discontinuous (none here): name -> (with ``multiscale`` false, with it true). The rule:
#: a parameter is differentiable where everything that *evaluates* the BSDF reads it live;
#: one baked into a table that eval reads (roughness: the footprint's mean D comes from the
#: directional SAT) carries no gradient there, so it is not. Tables that only steer
#: sampling (the sheen samplers, the lobe calibration) do not count: ``pdf`` is the density
#: of ``sample`` whatever they hold. Parameters missing here are build-time only (maps,
#: switches, table sizes, ``uv_unit``): not exposed; reload the scene to change them.
EXPOSED = {
    "uv_scale": ("P", "P"),
    "uv_scale_v": ("P", "P"),
    "roughness": ("P, ∂", "P"),
    "thickness": ("P, ∂", "P, ∂"),
    "sheen_roughness": ("P, ∂", "P, ∂"),
    "sheen_thickness": ("P, ∂", "P, ∂"),
    "specular_albedo": ("P, ∂", "P, ∂"),
    "specular_transmittance": ("P, ∂", "P, ∂"),
    "diffuse_albedo": ("P, ∂", "P, ∂"),
    "diffuse_transmittance": ("P, ∂", "P, ∂"),
    "sheen_color": ("P, ∂", "P, ∂"),
}
#: The docs' cell of a parameter that is not exposed.
NOT_EXPOSED = "—"


def exposure_flags(name: str, multiscale: bool):
    """The ``mi.ParamFlags`` that ``traverse`` gives parameter ``name`` (see :data:`EXPOSED`)."""
    letters = EXPOSED[name][1 if multiscale else 0]
    flags = mi.ParamFlags.Differentiable if "∂" in letters else mi.ParamFlags.NonDifferentiable
    if "D" in letters:
        flags = flags | mi.ParamFlags.Discontinuous
    return flags


def exposure_text(name: str) -> str:
    """The "exposed / differentiable" cell of parameter ``name`` in the docs (the plugin
    docstring and README.md), from :data:`EXPOSED`."""
    if name not in EXPOSED:
        return NOT_EXPOSED
    fibre, multiscale = EXPOSED[name]
    if fibre == multiscale:
        return fibre
    return f"{fibre} at fibre level, {multiscale} multi-scale"


def with_flags_column(docstring: str) -> str:
    """``docstring`` with a "Flags" column (:func:`exposure_text`) added to its list-table
    of parameters: the table in one place, the flags in another (a row naming several
    parameters needs them to agree)."""
    start = docstring.index("\n   * - ", docstring.index(".. list-table::"))
    end = docstring.index("\n\n", start)  # the first blank line after the first row
    head, table, tail = docstring[:start], docstring[start:end], docstring[end:]
    rows = table.split("\n   * - ")
    out = [rows[0]]
    for row in rows[1:]:
        names = [n.strip() for n in row.split("\n", 1)[0].split(",")]
        if names == ["Parameter"]:
            cell = "Flags"
        else:
            cells = {exposure_text(n) for n in names}
            if len(cells) != 1:
                raise ValueError(f"cloth docstring: the row for {names} mixes flags {sorted(cells)}")
            cell = cells.pop()
        out.append(f"{row}\n     - {cell}")
    return head + "\n   * - ".join(out) + tail


@dataclass(frozen=True)
class BuildParameters:
    """What a ``cloth`` BSDF's tables (and its lobe calibration, measured on them) are built
    from, as given: validated once, here (a changed value is a new instance, validated
    again). Of these only ``roughness`` is exposed (see ``parameters_changed``); everything
    else is read when the scene loads."""

    roughness: float = FLOAT_PARAMETERS["roughness"][0]
    multiscale: bool = True
    visibility: bool = True
    unbiased_ccv: bool = False
    parallax: bool = False
    direction_bins: int = 0    # 0: from the roughness (:attr:`bins`)
    visibility_bins: int = 8
    clusters: int = 8
    direction_rank: int = 0    # 0: the full table, or a rank by max_table_mib
    max_table_mib: int = 256

    def __post_init__(self):
        _check_float("roughness", self.roughness)
        if 0 < self.direction_bins < 4:
            raise ParameterError(f"cloth: parameter 'direction_bins' must be 0 (from the roughness) or in "
                                 f"[4, 64], got {self.direction_bins}")
        if self.direction_rank > self.bins ** 2:
            raise ParameterError(f"cloth: parameter 'direction_rank' must be at most direction_bins^2 = "
                                 f"{self.bins ** 2} (0: the full directional SAT), got {self.direction_rank}"
                                 + ("" if self.direction_bins else f" (roughness {self.roughness:g} gives "
                                    f"{self.bins} direction bins)"))

    @property
    def bins(self) -> int:
        """Half-vector bins per side of the directional SAT."""
        from ..precompute.direction_bins import bins_for_roughness
        return self.direction_bins or bins_for_roughness(self.roughness)

    @property
    def needs_tables(self) -> bool:
        return self.multiscale or self.visibility or self.parallax

    @property
    def tables_read_roughness(self) -> bool:
        """Whether shading reads a table built from the roughness (the directional SATs)."""
        return self.multiscale

    def with_roughness(self, roughness: float) -> "BuildParameters":
        return replace(self, roughness=float(roughness))

    def table_key(self, height: int, width: int):
        """(TableKey, why) of the tables for a (height, width) tile: ``why`` is non-empty
        when the memory budget chose the rank (see ``choose_direction_rank``)."""
        from ..precompute.tables import TableKey, choose_direction_rank

        rank, why = choose_direction_rank(height, width, self.bins, self.direction_rank, self.max_table_mib)
        key = TableKey(self.roughness, dr=self.bins, dv=self.visibility_bins, clusters=self.clusters,
                       per_cluster_sat=self.unbiased_ccv, d_rank=rank, parallax=self.parallax)
        return key, why


@dataclass
class ClothParameters:
    """Every parameter of a ``cloth`` BSDF as read: the maps' source, the shading values
    (exposed by ``traverse``) and the :class:`BuildParameters`."""
    pattern: str
    resolution: int | None
    uv_scale: float
    uv_scale_v: float
    uv_unit: float
    thickness: float
    sheen_roughness: float
    sheen_thickness: float
    textures: dict  # name -> mi.Texture
    build: BuildParameters
    footprint_slices: int = 1
    fabric: object = None           # the Fabric the defaults came from (mscloth.fabrics)
    pattern_given: bool = True      # False: the maps are the fabric's own

    @property
    def roughness(self) -> float:
        return self.build.roughness


def _check_float(name, value, where="cloth"):
    """``value`` as a float if parameter ``name`` allows it, else a ParameterError naming
    ``where`` (the plugin, or which cloth), the parameter and its range."""
    _, low, high, low_inclusive, meaning = FLOAT_PARAMETERS[name]
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        raise ParameterError(f"{where}: parameter '{name}' ({meaning}) must be a number, got {value!r}")
    value = float(value)
    ok_low = value >= low if low_inclusive else value > low
    if not (math.isfinite(value) and ok_low and value <= high):
        bracket = "[" if low_inclusive else "("
        raise ParameterError(
            f"{where}: parameter '{name}' ({meaning}) must be in {bracket}{low:g}, {high:g}], got {value:g}")
    return value


def _read_float(props, name, default=None):
    if name not in props:
        return FLOAT_PARAMETERS[name][0] if default is None else default
    return _check_float(name, props.get(name))


def constant_channels(texture) -> np.ndarray:
    """The three channels of a texture that does not vary in space."""
    value = np.asarray(texture.eval(dr.zeros(mi.SurfaceInteraction3f)), dtype=float).reshape(-1)
    return value[:3] if value.size >= 3 else np.full(3, value[0])


#: Procedural textures each of whose values is one of their child textures' values (Mitsuba's
#: ``checkerboard`` selects ``color0`` or ``color1`` per point, nothing in between):
#: class name -> those children. Their range is the union of the children's.
SELECTING_TEXTURES = {"Checkerboard": ("color0", "color1")}

#: Textures whose values come from the shape they are on, yet that say they do not vary in
#: space (so evaluating them anywhere would give a bound of 0): their range is unknown.
SHAPE_TEXTURES = {"MeshAttribute"}

#: What a texture must be for its range to be known (the end of an error's hint).
BOUNDED_TEXTURES = "a float, RGB, bitmap or checkerboard"

def texture_name(texture) -> str:
    """A texture's class name (``Checkerboard``, ``BitmapTexture``), for one-line messages:
    its ``str()`` spans several lines."""
    try:
        return texture.class_name()
    except (AttributeError, RuntimeError):
        return type(texture).__name__


def _child_textures(texture) -> dict:
    """The textures a texture's ``traverse`` hands over, by name (``color0``, ...)."""

    class Children(mi.TraversalCallback):
        def __init__(self):
            super().__init__()
            self.textures = {}

        def put(self, name, value, flags, cpptype=None):
            if isinstance(value, mi.Texture):
                self.textures[name] = value

    children = Children()
    texture.traverse(children)
    return children.textures


class UnboundedTexture(Exception):
    """A texture whose range cannot be known cheaply: ``path`` names it, inside the textures
    that hold it (``Checkerboard > MeshAttribute``)."""

    def __init__(self, path: str):
        super().__init__(path)
        self.path = path


def texture_channel_range(texture):
    """(lowest value, per-channel upper bound) of a texture's values: exact when it does
    not vary in space, a bitmap's data, a checkerboard's children's. UnboundedTexture
    where it cannot be known cheaply (procedural textures other than
    :data:`SELECTING_TEXTURES`, :data:`SHAPE_TEXTURES`)."""
    name = texture_name(texture)
    with dr.suspend_grad():
        if name in SHAPE_TEXTURES:
            raise UnboundedTexture(name)
        if not texture.is_spatially_varying():
            channels = constant_channels(texture)
            return float(channels.min()), channels
        if name in SELECTING_TEXTURES:
            found = _child_textures(texture)
            ranges = []
            for child in SELECTING_TEXTURES[name]:
                try:
                    ranges.append(texture_channel_range(found[child]))
                except UnboundedTexture as error:
                    raise UnboundedTexture(f"{name} > {error.path}") from None
            return min(r[0] for r in ranges), np.maximum.reduce([r[1] for r in ranges])
        data = next((np.array(value) for key, value in mi.traverse(texture).items() if key.endswith("data")), None)
        try:
            upper = np.full(3, float(texture.max()))
        except RuntimeError:
            # Bitmaps do not implement max(): read their data.
            if data is None:
                raise UnboundedTexture(name) from None
            upper = data.reshape(-1, data.shape[-1]).max(axis=0)[:3] if data.ndim >= 3 else np.full(3, data.max())
        # Textures without data (procedural) are checked against their max only.
        return (0.0 if data is None else float(data.min())), upper


def check_spectrum(name, texture, where="cloth") -> np.ndarray:
    """The per-channel upper bound of spectrum parameter ``name``'s ``texture``, if its
    values lie in [0, 1] and are finite, else a ParameterError naming ``where`` (the
    plugin, or which cloth), the parameter and its range."""
    meaning = SPECTRUM_PARAMETERS[name][1]
    try:
        lower, upper = texture_channel_range(texture)
    except UnboundedTexture as error:
        raise ParameterError(f"{where}: parameter '{name}' ({meaning}): cannot bound the values of texture "
                             f"{error.path}; use {BOUNDED_TEXTURES}") from None
    if not (math.isfinite(lower) and lower >= 0.0 and np.all(np.isfinite(upper)) and np.all(upper <= 1.0)):
        raise ParameterError(f"{where}: parameter '{name}' ({meaning}) must lie in [0, 1] in every channel, "
                             f"got values in [{lower:g}, {upper.max():g}]")
    return upper


def check_energy(bounds, where="cloth") -> None:
    """Raise ParameterError if the upper ``bounds`` (name -> per-channel bound) of the
    :data:`ENERGY_PARAMETERS` let the cloth reflect more light than it receives
    (:func:`.cloth_limits.reflected_bound` over 1)."""
    total = reflected_bound(*(bounds[name] for name in ENERGY_PARAMETERS))
    if np.any(total > 1.0 + 1e-6):
        ch = int(np.argmax(total))
        raise ParameterError(
            f"{where}: diffuse_albedo + diffuse_transmittance + max(specular_albedo, specular_transmittance) "
            f"must be <= 1 in every channel so the cloth cannot reflect more light than it receives; "
            f"got {total[ch]:.3g} in channel {'RGB'[ch]} (defaults: 0.4 + 0.1 + max(0.4, 0.2) = 0.9)")


def _preset_texture(value):
    """A preset's spectrum value (a float or an ``rgb`` dictionary) as a texture, made as
    the scene parser makes one (``srgb`` for an RGB reflectance, ``uniform`` for a float).
    Through the plugin manager, not ``mi.load_dict``: this runs inside the ``cloth``
    constructor, on one of the parallel loader's threads, and a nested ``mi.load_dict``
    there (Mitsuba 3.9.1) corrupts the file resolver other plugins (``sunsky``, meshes)
    are reading at that moment (docs/decisions.md, "No scene loading inside a plugin")."""
    if isinstance(value, dict):
        if value.get("type") != "rgb" or set(value) != {"type", "value"}:
            raise ParameterError(f"cloth: a preset colour must be {{'type': 'rgb', 'value': [r, g, b]}}, got {value!r}")
        props = mi.Properties("srgb")
        props["color"] = mi.ScalarColor3f(*(float(c) for c in value["value"]))
    else:
        props = mi.Properties("uniform")
        props["value"] = float(value)
    return mi.PluginManager.instance().create_object(props)


def read_parameters(props) -> ClothParameters:
    """Read every ``cloth`` parameter from Mitsuba Properties, validating each. A ``fabric``
    supplies the defaults of the others (and the maps when no ``pattern`` is given); its
    UVs are read in metres unless ``uv_unit`` or ``uv_scale`` says otherwise."""
    check_parameter_names(props.keys())
    preset = None
    if "fabric" in props:
        from ..fabrics import fabric
        from ..loading import resolve_scene_path

        # A preset's name, or a .json preset file found as Mitsuba finds its own files.
        preset = fabric(props.get("fabric"), locate=resolve_scene_path)
    preset_values = preset.bsdf_parameters() if preset else {}
    pattern = props.get("pattern", preset.pattern if preset else "plain")
    if not isinstance(pattern, str) or not pattern:
        raise ParameterError(f"cloth: parameter 'pattern' must be a pattern name or a maps directory, got {pattern!r}")
    resolution = props.get("resolution", 0)
    if isinstance(resolution, bool) or not isinstance(resolution, int) or resolution < 0 or resolution > 8192:
        raise ParameterError(f"cloth: parameter 'resolution' (texels per tile side of a built-in pattern) "
                             f"must be an integer in [8, 8192] (0: the pattern's default), got {resolution!r}")
    if 0 < resolution < 8:
        raise ParameterError(f"cloth: parameter 'resolution' must be in [8, 8192] (0: default), got {resolution}")

    floats = {name: _read_float(props, name, preset_values.get(name)) for name in FLOAT_PARAMETERS}
    if floats["uv_unit"] > 0.0 and "uv_unit" in props and ("uv_scale" in props or "uv_scale_v" in props):
        raise ParameterError("cloth: give uv_unit (the UVs' length unit, for physical UVs) or "
                             "uv_scale / uv_scale_v (tiles per UV unit), not both")
    if preset and not any(name in props for name in ("uv_unit", "uv_scale", "uv_scale_v")):
        floats["uv_unit"] = 1.0  # a fabric's mesh has UVs in metres unless told otherwise

    textures = {}
    bounds = {}
    for name, (default, meaning) in SPECTRUM_PARAMETERS.items():
        try:
            if name not in props and name in preset_values:
                texture = _preset_texture(preset_values[name])
            else:
                texture = props.get_texture(name, default)
        except RuntimeError as error:  # e.g. Mitsuba refusing an RGB reflectance > 1
            reason = str(error).strip().splitlines()[-1]
            raise ParameterError(f"cloth: parameter '{name}' ({meaning}) must lie in [0, 1] "
                                 f"in every channel: {reason}") from None
        bounds[name] = check_spectrum(name, texture)
        textures[name] = texture
    check_energy(bounds)

    switches = {}
    for name, (default, meaning) in BOOL_PARAMETERS.items():
        value = props.get(name, default)
        if not isinstance(value, bool):
            raise ParameterError(f"cloth: parameter '{name}' ({meaning}) must be a boolean, got {value!r}")
        switches[name] = value
    for name, (default, low, high, meaning) in INT_PARAMETERS.items():
        value = props.get(name, default)
        if isinstance(value, bool) or not isinstance(value, int) or not low <= value <= high:
            raise ParameterError(f"cloth: parameter '{name}' ({meaning}) must be an integer in "
                                 f"[{low}, {high}], got {value!r}")
        switches[name] = value

    footprint_slices = switches.pop("footprint_slices")
    build = BuildParameters(roughness=floats.pop("roughness"), **switches)
    return ClothParameters(pattern=pattern, resolution=resolution or None, textures=textures, build=build,
                           footprint_slices=footprint_slices, fabric=preset,
                           pattern_given=preset is None or "pattern" in props, **floats)


def cloth_maps(p: ClothParameters):
    """The maps a ``cloth`` BSDF shades: its fabric's own, or its ``pattern``'s."""
    if not p.pattern_given:
        return p.fabric.maps(p.resolution)
    from ..loading import resolve_scene_path
    from ..maps.builtin import resolve_pattern

    # Relative paths are the scene file's, as for Mitsuba's own plugins.
    return resolve_pattern(p.pattern, p.resolution, locate=resolve_scene_path)


def uv_scales(p: ClothParameters, maps) -> tuple[float, float]:
    """Pattern tiles per UV unit along u and v. With ``uv_unit`` (metres per UV unit) the
    tile's physical size sets them; otherwise ``uv_scale`` does, and ``uv_scale_v`` or,
    when 0, the tile's aspect (square UV units see the tile at its physical aspect)."""
    width_mm, height_mm = maps.meta.get("tile_size_mm", (1.0, 1.0))
    if p.uv_unit > 0.0:
        return p.uv_unit * 1000.0 / width_mm, p.uv_unit * 1000.0 / height_mm
    return p.uv_scale, p.uv_scale_v or p.uv_scale * width_mm / height_mm
