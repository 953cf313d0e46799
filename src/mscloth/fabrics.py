"""Named fabrics: complete, physically scaled parameter sets for the ``cloth`` BSDF.

A :class:`Fabric` states what a textile has (weave or knit, ends and picks per cm, yarn
diameter, ply and twist, the yarn's inclination, fibre roughness, colours, sheen) and turns
it into cloth maps at its true thread count (``meta['tile_size_mm']``) and into the BSDF's
parameters. The ``cloth`` plugin's ``fabric`` parameter names one; its other parameters
still override the preset's, and its UVs are then read in metres (``uv_unit``).

Where the numbers come from:

* Thread counts, yarn sizes and the weave of each fabric: textile references (Kadolph,
  *Textiles*, 11th ed.; Hollen & Saddler; mill specifications quoted in the ``source`` of
  each preset), rounded.
* Fibre twist (``fibre_twist_deg``) and the yarns' inclination (``inclination_deg``, Irawan's
  u_max): the cloth presets of Irawan & Marschner 2012, "Specular reflection from woven
  cloth" (ACM TOG 31(1)), as published under Apache-2.0 with LuxCoreRender for denim, silk
  charmeuse, silk shantung, cotton twill, wool gabardine and polyester lining. The
  inclination sets the maps' ``yarn_height`` (:meth:`Fabric.yarn_height`).
* Roughness, albedos and sheen: chosen within the model's form so each preset reads as its
  fabric under the look-development scenes (``docs/decisions.md``, "Fabric presets").

Colours are sRGB in [0, 1] as a colour picker gives them; the maps store them linear and
the BSDF multiplies every lobe's albedo by them.
"""
from __future__ import annotations

import contextvars
import dataclasses
import difflib
import functools
import json
import math
import numbers
import os
import warnings
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from .cloth_limits import ENERGY_PARAMETERS, FLOAT_PARAMETERS, reflected_bound
from .errors import ClothError, ParameterError, ResolutionError
from .maps.generator_support import srgb_to_linear, tile_resolution

#: Texels along one warp end (knits: one wale) in a preset's maps when the caller gives no
#: resolution: enough for the yarn's cross-section and its twisted fibres.
TEXELS_PER_THREAD = 16
#: Texels along u of a preset's tile are kept within these bounds.
MIN_TILE_TEXELS, MAX_TILE_TEXELS = 32, 512


@dataclass(frozen=True)
class Fabric:
    """One named fabric (see the module docstring for the sources)."""

    name: str
    title: str
    structure: str                    # "woven" or "knit"
    pattern: str                      # a named weave (``satin-8-3``) or knit (``rib-2-2``)
    ends_per_cm: float                # warp ends per cm (knits: wales per cm)
    picks_per_cm: float               # weft picks per cm (knits: courses per cm)
    yarn_diameter_mm: tuple           # (warp, weft) diameters in mm (knits: one yarn)
    fibre_twist_deg: float            # fibre angle to the yarn (ply) axis; > 0 S, < 0 Z
    inclination_deg: float            # the face yarn's largest angle to the cloth's plane
    warp_color: tuple                 # sRGB (knits: the yarn's colour)
    weft_color: tuple                 # sRGB
    roughness: float
    thickness: float
    specular_albedo: float
    specular_transmittance: float
    diffuse_albedo: float
    diffuse_transmittance: float
    sheen_color: tuple                # sRGB
    sheen_roughness: float
    sheen_thickness: float
    ply: int = 1                      # plies per yarn
    ply_twist_deg: float = 30.0       # ply angle to the yarn axis (ply > 1)
    slub: float | tuple = 0.0         # slubby yarns: a slub is 1 + slub times the yarn
                                      # between slubs (one for both, or (warp, weft))
    slub_length_mm: tuple = (2.0, 8.0)  # shortest and longest slub
    slub_spacing_mm: float = 12.0     # mean distance between slubs along a yarn
    slub_tone: float = 1.0            # albedo at a slub's peak / between slubs
    repeat: int | tuple = 1           # the weave's repeat tiled this often each way, or
                                      # (along u: ends, along v: picks); long for slubs
    profile_exponent: float = 2.0     # cross-section: 2 round, larger flatter (filament)
    float_arch: float = 1.0           # floats arch over their crossings (woven_maps)
    texels_per_thread: int = TEXELS_PER_THREAD
    source: str = ""
    look: str = ""                    # what makes it read as this fabric
    gap_fraction: float = field(init=False, default=0.0)

    def __post_init__(self):
        # Every value is checked here, before any map is built from it: a bad one would
        # otherwise surface deep in the map builders under another name (or not at all).
        loading = _LOADING.get()
        where, base = loading if loading else (f"fabric {self.name!r}", None)
        _check_fields(self, where, base)
        object.__setattr__(self, "gap_fraction", self._gap_fraction())

    # ------------------------------------------------------------------ geometry
    @property
    def warp_spacing_mm(self) -> float:
        return 10.0 / self.ends_per_cm

    @property
    def weft_spacing_mm(self) -> float:
        return 10.0 / self.picks_per_cm

    @property
    def cover(self) -> tuple[float, float]:
        """(warp, weft) yarn width / thread spacing of a woven fabric's mean yarn, at most
        1: a yarn flattens against its neighbours rather than overlapping them."""
        d_warp, d_weft = self._diameters()
        return (min(1.0, d_warp / self.warp_spacing_mm), min(1.0, d_weft / self.weft_spacing_mm))

    def _diameters(self) -> tuple[float, float]:
        d = tuple(self.yarn_diameter_mm)
        return (d[0], d[-1])

    def _gap_fraction(self) -> float:
        """Open area of the cloth seen along the normal: the mean open width of the warp
        ends times that of the weft picks (exact for uniform spacing and even yarns; slubby
        yarns count with their diameter all along them, which ignores the small correlation
        of a warp's and a weft's thickness at a crossing). Knits: 0, their holes depend on
        the loop shape."""
        if self.structure == "knit":
            return 0.0
        draft = _woven_draft(self)
        (f_warp, f_weft) = _slub_factors(self, draft, 512)
        open_warp = np.mean(1.0 - np.minimum(1.0, draft.warp_thickness[:, None] * f_warp
                                             / draft.warp_spacing[:, None]))
        open_weft = np.mean(1.0 - np.minimum(1.0, draft.weft_thickness[:, None] * f_weft
                                             / draft.weft_spacing[:, None]))
        return float(open_warp * open_weft)

    def _repeats(self) -> tuple[int, int]:
        """(along u, along v): how often the weave's repeat is tiled across and down."""
        r = self.repeat
        return (int(r[0]), int(r[-1])) if isinstance(r, (tuple, list)) else (int(r), int(r))

    def _slub_seed(self) -> int:
        return sum(map(ord, self.name))  # stable per fabric

    def yarn_height(self) -> float:
        """The woven maps' ``yarn_height`` (peak-to-peak undulation / yarn width) giving
        the face yarn this inclination: its centreline is a cosine between +-A over one
        thread spacing s, steepest at tan(u_max) = pi A / s, so 2A / w = 2 s tan(u_max) /
        (pi w)."""
        s, w = self.warp_spacing_mm, self.cover[0] * self.warp_spacing_mm
        return float(min(2.0, 2.0 * s * math.tan(math.radians(self.inclination_deg)) / (math.pi * w)))

    # ------------------------------------------------------------------ maps
    def default_resolution(self) -> int:
        """Texels along u: ``texels_per_thread`` per warp end (twice that per wale: a knit's
        loops need more), within [MIN_TILE_TEXELS, MAX_TILE_TEXELS]."""
        per = self.texels_per_thread * (2 if self.structure == "knit" else 1)
        return int(min(MAX_TILE_TEXELS, max(MIN_TILE_TEXELS, per * _pattern_columns(self))))

    def maps(self, resolution: int | None = None):
        """Cloth maps of one tile at the fabric's true thread count (cached)."""
        return _fabric_maps(self, resolution or self.default_resolution())

    # ------------------------------------------------------------------ BSDF
    def bsdf_parameters(self) -> dict:
        """The ``cloth`` parameters this preset sets (floats, and sRGB colours as Mitsuba
        ``rgb`` dictionaries); the maps carry the yarn colours."""
        rgb = {"type": "rgb", "value": [float(c) for c in srgb_to_linear(self.sheen_color)]}
        return {"roughness": self.roughness, "thickness": self.thickness,
                "specular_albedo": self.specular_albedo,
                "specular_transmittance": self.specular_transmittance,
                "diffuse_albedo": self.diffuse_albedo,
                "diffuse_transmittance": self.diffuse_transmittance,
                "sheen_color": rgb, "sheen_roughness": self.sheen_roughness,
                "sheen_thickness": self.sheen_thickness}


def _pattern_columns(fabric: Fabric) -> int:
    if fabric.structure == "knit":
        return _knit_pattern(fabric).n_wales
    from .patterns.named import named_pattern

    return named_pattern(fabric.pattern).n_warp * fabric._repeats()[0]


def _knit_pattern(fabric: Fabric):
    """The fabric's KnitPattern in its colour, repeated until its tile is about as tall as
    it is wide (a knit's repeat is often one course tall), at least 2 x 2 stitches."""
    from .patterns.knit import KnitPattern
    from .patterns.named import named_pattern

    base = named_pattern(fabric.pattern)
    width = base.n_wales / fabric.ends_per_cm
    height = base.n_courses / fabric.picks_per_cm
    courses = max(2 // base.n_courses, round(width / height), 1)
    wales = max(2 // base.n_wales, round(height * courses / width), 1)
    tiled = base.tiled(courses, wales)
    return KnitPattern(tiled.stitches, course_colors=fabric.warp_color, name=fabric.name)


def _woven_draft(fabric: Fabric):
    """The fabric's Draft: its weave tiled ``repeat`` times (across, down), its spacing,
    mean yarn diameters and colours (slubs vary the diameter along each yarn: the maps'
    ``slub``)."""
    from .patterns.draft import Draft
    from .patterns.named import named_pattern

    base = named_pattern(fabric.pattern)
    across, down = fabric._repeats()
    drawdown = np.tile(base.drawdown, (down, across))
    n_weft, n_warp = drawdown.shape
    d_warp, d_weft = fabric._diameters()
    return Draft(drawdown, warp_colors=fabric.warp_color, weft_colors=fabric.weft_color,
                 warp_spacing=fabric.warp_spacing_mm, weft_spacing=fabric.weft_spacing_mm,
                 warp_thickness=np.full(n_warp, d_warp), weft_thickness=np.full(n_weft, d_weft),
                 name=fabric.name)


def _slub_arguments(fabric: Fabric) -> dict:
    """The woven maps' slub arguments of a preset."""
    return {"slub": fabric.slub, "slub_length_mm": tuple(fabric.slub_length_mm),
            "slub_spacing_mm": fabric.slub_spacing_mm, "slub_seed": fabric._slub_seed(),
            "slub_tone": fabric.slub_tone}


def _slub_factors(fabric: Fabric, draft, samples: int):
    """(warp, weft) diameter / mean diameter along each yarn at ``samples`` points over the
    tile, as the woven maps draw them (:func:`mscloth.maps.woven.draft_slub_factors`)."""
    from .maps.woven import draft_slub_factors

    width_mm, height_mm = draft.size_mm
    along_u = (np.arange(samples) + 0.5) * (width_mm / samples)
    along_v = (np.arange(samples) + 0.5) * (height_mm / samples)
    return draft_slub_factors(draft, fabric.slub, along_u, along_v, length_mm=tuple(fabric.slub_length_mm),
                              spacing_mm=fabric.slub_spacing_mm, seed=fabric._slub_seed())


@functools.lru_cache(maxsize=8)
def _fabric_maps(fabric: Fabric, resolution: int):
    if fabric.structure == "woven":
        from .maps.woven import woven_maps

        maps = woven_maps(_woven_draft(fabric), resolution, yarn_height=fabric.yarn_height(),
                          profile_exponent=fabric.profile_exponent,
                          fibre_twist_deg=fabric.fibre_twist_deg, ply_count=fabric.ply,
                          ply_twist_deg=fabric.ply_twist_deg, float_arch=fabric.float_arch,
                          **_slub_arguments(fabric))
    else:
        from .maps.knit import knit_maps

        pattern = _knit_pattern(fabric)
        wale_mm = 10.0 / fabric.ends_per_cm
        maps = knit_maps(pattern, resolution, yarn_width=min(1.0, fabric._diameters()[0] / wale_mm),
                         loop_aspect=fabric.ends_per_cm / fabric.picks_per_cm,
                         fibre_twist_deg=fabric.fibre_twist_deg, wale_spacing_mm=wale_mm)
    maps.meta["fabric"] = fabric.name
    return maps


# ---------------------------------------------------------------------------- validation
def _plugin_range(name: str) -> tuple[float, float, bool, bool]:
    """The ``cloth`` plugin's range of its float parameter ``name``, as FIELD_RANGES holds one."""
    _, low, high, low_inclusive, _ = FLOAT_PARAMETERS[name]
    return low, high, not low_inclusive, False


#: Ranges of the number fields: (lowest, highest, lowest excluded, highest excluded). The
#: BSDF's are the ``cloth`` plugin's own (:mod:`.cloth_limits`), which takes a preset's
#: values unchecked; the maps' are what woven_maps / knit_maps accept.
FIELD_RANGES: dict[str, tuple[float, float, bool, bool]] = {
    "ends_per_cm": (0.0, math.inf, True, True),
    "picks_per_cm": (0.0, math.inf, True, True),
    "fibre_twist_deg": (-90.0, 90.0, False, False),
    "ply_twist_deg": (0.0, 90.0, True, True),
    "slub_spacing_mm": (0.0, math.inf, True, True),
    "slub_tone": (0.5, 2.0, False, False),
    "profile_exponent": (1.0, 16.0, False, False),
    "float_arch": (0.0, 1.0, False, False),
    "roughness": _plugin_range("roughness"),
    "thickness": _plugin_range("thickness"),
    "specular_albedo": (0.0, 1.0, False, False),  # (every spectrum parameter's range)
    "specular_transmittance": (0.0, 1.0, False, False),
    "diffuse_albedo": (0.0, 1.0, False, False),
    "diffuse_transmittance": (0.0, 1.0, False, False),
    "sheen_roughness": _plugin_range("sheen_roughness"),
    "sheen_thickness": _plugin_range("sheen_thickness"),
}
#: A knit's course / wale spacing (ends_per_cm / picks_per_cm): knit_maps' loop_aspect.
_KNIT_LOOP_ASPECT = (0.3, 3.0)
#: A yarn this many times wider than its spacing is flattened to the spacing by the maps:
#: more than a little is likely a unit slip (diameters are in mm), so it is warned about.
_WIDE_YARN = 2.0

#: While :func:`load_fabric_file` builds a Fabric: (how errors name it, the base preset
#: its structure came from, if any).
_LOADING: contextvars.ContextVar[tuple[str, str | None] | None] = contextvars.ContextVar(
    "mscloth_fabric_loading", default=None)
#: The .json files whose ``"base"`` is being loaded, outermost first: (resolved path, as
#: written), so that a chain of bases coming back to one of them is an error, not a recursion.
_BASE_CHAIN: contextvars.ContextVar[tuple[tuple[str, str], ...]] = contextvars.ContextVar(
    "mscloth_fabric_base_chain", default=())


def _bad(where: str, key: str, expected: str, value) -> ParameterError:
    return ParameterError(f"{where}: field {key!r} must be {expected}, got {value!r}")


def _interval(lo: float, hi: float, lo_open: bool, hi_open: bool) -> str:
    if hi == math.inf:
        return f"{'>' if lo_open else '>='} {lo:g}"
    return f"in {'(' if lo_open else '['}{lo:g}, {hi:g}{')' if hi_open else ']'}"


def _is_number(value) -> bool:
    return isinstance(value, numbers.Real) and not isinstance(value, bool)


def _real(where: str, key: str, value, lo: float, hi: float, lo_open: bool, hi_open: bool,
          note: str = "") -> float:
    """``value`` as a finite float in the interval, or a ParameterError naming ``key``."""
    expected = _interval(lo, hi, lo_open, hi_open) + note
    if not _is_number(value):
        raise _bad(where, key, f"a number {expected}", value)
    x = float(value)
    if not math.isfinite(x) or (x <= lo if lo_open else x < lo) or (x >= hi if hi_open else x > hi):
        raise _bad(where, key, expected, value)
    return x


def _integer(where: str, key: str, value, lo: int, hi: float) -> int:
    """A whole number in [lo, hi] (JSON's 2.0 too), as an int."""
    if not _is_number(value) or not float(value).is_integer() or not lo <= value <= hi:
        raise _bad(where, key, f"a whole number {_interval(lo, hi, False, False)}", value)
    return int(value)


def _sequence(value) -> tuple | None:
    return tuple(value) if isinstance(value, (tuple, list, np.ndarray)) else None


def _one_or_pair(where: str, key: str, value, check) -> float | int | tuple:
    """A number for both (warp, weft) / (across, down), or a pair of them, each through
    ``check``; a list becomes a tuple (a Fabric is hashed: its maps are cached)."""
    items = _sequence(value)
    if items is None:
        return check(value)
    if len(items) != 2:
        raise _bad(where, key, "a number or a pair of numbers", value)
    return tuple(check(v) for v in items)


def _colour(where: str, key: str, value) -> tuple[float, float, float]:
    items = _sequence(value)
    if (items is None or len(items) != 3 or not all(_is_number(c) and 0.0 <= c <= 1.0 for c in items)):
        raise _bad(where, key, "an sRGB triple [r, g, b] of numbers in [0, 1] (as a colour picker "
                               "gives them, divided by 255)", value)
    return tuple(float(c) for c in items)


def _pattern_kinds() -> dict[bool, str]:
    """{woven?: the named patterns of that kind}, for errors."""
    from .patterns.draft import Draft
    from .patterns.named import NAMED, named_pattern

    kinds = {True: [], False: []}
    for key, (_, _, help_text) in NAMED.items():
        kinds[isinstance(named_pattern(key), Draft)].append(help_text.split()[0].rstrip(","))
    kinds[True].append("a .wif file")
    return {woven: ", ".join(names) for woven, names in kinds.items()}


def _check_pattern(fabric: Fabric, where: str, base: str | None) -> None:
    """The pattern exists and is of the fabric's structure (a weave for woven, a knit)."""
    from .patterns.draft import Draft
    from .patterns.named import named_pattern

    if not isinstance(fabric.pattern, str) or not fabric.pattern:
        raise _bad(where, "pattern", "a pattern name such as 'twill-2-1' or 'rib-2-2', or a .wif file",
                   fabric.pattern)
    try:
        woven = isinstance(named_pattern(fabric.pattern), Draft)
    except ClothError as error:
        raise ParameterError(f"{where}: field 'pattern': {error}") from None
    if woven != (fabric.structure == "woven"):
        origin = f" (from base {base!r})" if base else ""
        want = fabric.structure == "woven"
        raise ParameterError(
            f"{where}: field 'pattern' {fabric.pattern!r} is a {'weave' if woven else 'knit'}, but field "
            f"'structure' is {fabric.structure!r}{origin}: give a {'weave' if want else 'knit'} "
            f"pattern ({_pattern_kinds()[want]}) or \"structure\": \"{'woven' if woven else 'knit'}\"")


def _check_tile(fabric: Fabric, where: str) -> None:
    """The maps of the fabric's tile can be built at its default resolution (enough texels
    for each thread or stitch, each way)."""
    from .patterns.named import named_pattern

    if fabric.structure == "woven":
        from .maps.woven import MIN_TEXELS_PER_THREAD as least

        n_weft, n_warp = named_pattern(fabric.pattern).drawdown.shape
        across, down = fabric._repeats()
        counts, kinds = (n_weft * down, n_warp * across), ("weft picks", "warp ends")
        aspect = (counts[0] / fabric.picks_per_cm) / (counts[1] / fabric.ends_per_cm)
    else:
        from .maps.knit import MIN_TEXELS_PER_STITCH as least

        counts, kinds = _knit_pattern(fabric).stitches.shape, ("courses", "wales")
        aspect = counts[0] * (fabric.ends_per_cm / fabric.picks_per_cm) / counts[1]
    try:
        tile_resolution(fabric.default_resolution(), aspect, tuple(counts), least, kinds)
    except ResolutionError as error:
        raise ParameterError(
            f"{where}: fields 'repeat', 'texels_per_thread', 'ends_per_cm' and 'picks_per_cm' give a "
            f"tile of {counts[1]} {kinds[1]} x {counts[0]} {kinds[0]} that its default maps "
            f"({fabric.default_resolution()} texels across) cannot hold: {error}") from None


def _check_fields(fabric: Fabric, where: str, base: str | None) -> None:
    """Raise a ParameterError naming the first field of ``fabric`` out of range (``where``:
    the fabric or its file), warn of yarns far wider than their spacing, and make lists
    tuples."""
    def keep(key: str, value) -> None:
        object.__setattr__(fabric, key, value)

    for key in ("name", "title", "source", "look"):
        value = getattr(fabric, key)
        if not isinstance(value, str) or (key == "name" and not value):
            raise _bad(where, key, "a non-empty string" if key == "name" else "a string", value)
    if fabric.structure not in ("woven", "knit"):
        raise _bad(where, "structure", "'woven' or 'knit'", fabric.structure)
    woven = fabric.structure == "woven"
    for key, (lo, hi, lo_open, hi_open) in FIELD_RANGES.items():
        _real(where, key, getattr(fabric, key), lo, hi, lo_open, hi_open)
    if not woven:
        lo, hi = _KNIT_LOOP_ASPECT
        ratio = fabric.ends_per_cm / fabric.picks_per_cm
        if not lo <= ratio <= hi:
            raise ParameterError(
                f"{where}: fields 'ends_per_cm' / 'picks_per_cm' (wales / courses per cm) of a knit must "
                f"be in [{lo:g}, {hi:g}] (the loops' shape), got {fabric.ends_per_cm:g} / "
                f"{fabric.picks_per_cm:g} = {ratio:.3g}")
    # Woven maps need a slope: an inclination of 0 would flatten the weave (yarn_height 0).
    _real(where, "inclination_deg", fabric.inclination_deg, 0.0, 90.0, woven, True, " degrees")
    _check_pattern(fabric, where, base)

    expected = ("one diameter in mm (warp and weft) or a (warp, weft) pair" if woven
                else "one diameter in mm (a knit has one yarn)")
    diameters = _sequence(fabric.yarn_diameter_mm)
    if diameters is None:
        diameters = (fabric.yarn_diameter_mm,)
    if not 1 <= len(diameters) <= (2 if woven else 1) or not all(_is_number(d) for d in diameters):
        raise _bad(where, "yarn_diameter_mm", expected, fabric.yarn_diameter_mm)
    keep("yarn_diameter_mm", tuple(_real(where, "yarn_diameter_mm", d, 0.0, math.inf, True, True, " mm")
                                   for d in diameters))
    spacings = (("warp", fabric.warp_spacing_mm), ("weft", fabric.weft_spacing_mm)) if woven else \
        (("yarn", fabric.warp_spacing_mm),)  # a knit's yarn against its wale spacing
    wide = [f"the {family} yarn ({diameter:g} mm) is {diameter / spacing:.3g}x its spacing ({spacing:.3g} mm)"
            for (family, spacing), diameter in zip(spacings, fabric._diameters()) if diameter > _WIDE_YARN * spacing]
    if wide:
        warnings.warn(f"{where}: field 'yarn_diameter_mm': {', '.join(wide)}; the maps flatten a yarn "
                      "to its spacing (diameters are in mm)", stacklevel=4)

    for key in ("warp_color", "weft_color", "sheen_color"):
        keep(key, _colour(where, key, getattr(fabric, key)))
    total = float(reflected_bound(*(getattr(fabric, name) for name in ENERGY_PARAMETERS)))
    if total > 1.0 + 1e-6:
        raise ParameterError(
            f"{where}: fields 'diffuse_albedo' + 'diffuse_transmittance' + max('specular_albedo', "
            f"'specular_transmittance') must be <= 1 (the cloth cannot reflect more light than it "
            f"receives), got {total:.3g}")

    keep("ply", _integer(where, "ply", fabric.ply, 1, 8))
    keep("texels_per_thread", _integer(where, "texels_per_thread", fabric.texels_per_thread, 2, MAX_TILE_TEXELS))
    keep("repeat", _one_or_pair(where, "repeat", fabric.repeat,
                                lambda v: _integer(where, "repeat", v, 1, math.inf)))
    keep("slub", _one_or_pair(where, "slub", fabric.slub,
                              lambda v: _real(where, "slub", v, 0.0, 4.0, False, False)))
    lengths = _sequence(fabric.slub_length_mm)
    if lengths is None or len(lengths) != 2:
        raise _bad(where, "slub_length_mm", "(shortest, longest) in mm", fabric.slub_length_mm)
    lengths = tuple(_real(where, "slub_length_mm", v, 0.0, math.inf, True, True, " mm") for v in lengths)
    if lengths[0] > lengths[1]:
        raise _bad(where, "slub_length_mm", "(shortest, longest) in mm", fabric.slub_length_mm)
    keep("slub_length_mm", lengths)
    _check_tile(fabric, where)


# ---------------------------------------------------------------------------- the presets
_SILK_LOOK = "a continuous lustre band along the long warp floats, moving with the light"

FABRICS: dict[str, Fabric] = {f.name: f for f in (
    Fabric(
        name="silk-charmeuse", title="Silk charmeuse", structure="woven", pattern="satin-5-2",
        ends_per_cm=120, picks_per_cm=45, yarn_diameter_mm=(0.09, 0.12),
        fibre_twist_deg=0.0, inclination_deg=40.0, profile_exponent=4.0,
        warp_color=(0.80, 0.70, 0.52), weft_color=(0.80, 0.70, 0.52),
        roughness=0.1, thickness=4.0, specular_albedo=0.85, specular_transmittance=0.05,
        diffuse_albedo=0.1, diffuse_transmittance=0.03,
        sheen_color=(0.9, 0.85, 0.75), sheen_roughness=0.5, sheen_thickness=0.05,
        source="5-end warp-faced satin of untwisted filament silk, ~300 x 115 threads/inch "
               "(16-19 momme charmeuse); twist 0 and warp/weft inclination 40/60 degrees from "
               "Irawan & Marschner 2012's silk charmeuse",
        look=_SILK_LOOK),
    Fabric(
        name="polyester-satin", title="Polyester satin", structure="woven", pattern="satin-8-3",
        ends_per_cm=90, picks_per_cm=38, yarn_diameter_mm=(0.12, 0.15),
        fibre_twist_deg=0.0, inclination_deg=22.0, profile_exponent=4.0,
        warp_color=(0.55, 0.05, 0.08), weft_color=(0.55, 0.05, 0.08),
        roughness=0.12, thickness=4.0, specular_albedo=0.85, specular_transmittance=0.05,
        diffuse_albedo=0.1, diffuse_transmittance=0.03,
        sheen_color=(0.9, 0.9, 0.9), sheen_roughness=0.5, sheen_thickness=0.05,
        source="8-end warp-faced satin of flat filament polyester (75-100 denier), ~230 x 95 "
               "threads/inch; twist 0 and inclination 22 degrees from Irawan & Marschner "
               "2012's polyester",
        look="a brighter, more uniform, slightly plastic lustre band than silk"),
    Fabric(
        name="cotton-poplin", title="Cotton poplin", structure="woven", pattern="plain",
        ends_per_cm=55, picks_per_cm=28, yarn_diameter_mm=(0.19, 0.30),
        fibre_twist_deg=-28.0, inclination_deg=30.0, ply=1,
        warp_color=(0.62, 0.74, 0.86), weft_color=(0.62, 0.74, 0.86),
        roughness=0.45, thickness=2.0, specular_albedo=0.2, specular_transmittance=0.1,
        diffuse_albedo=0.65, diffuse_transmittance=0.05,
        sheen_color=(0.9, 0.9, 0.9), sheen_roughness=0.6, sheen_thickness=0.15,
        source="dense plain weave of combed cotton, ~140 x 70 threads/inch (warp about twice "
               "the weft count: the fine weft-wise rib), Z-spun (twist -30 degrees as Irawan "
               "& Marschner 2012's cotton twill)",
        look="matte and even, a faint fine rib across the cloth, soft highlights on folds"),
    Fabric(
        name="denim", title="Denim", structure="woven", pattern="twill-3-1-Z",
        ends_per_cm=28, picks_per_cm=18, yarn_diameter_mm=(0.40, 0.45),
        fibre_twist_deg=-30.0, inclination_deg=12.0,
        warp_color=(0.10, 0.20, 0.52), weft_color=(0.70, 0.67, 0.60),
        roughness=0.4, thickness=2.0, specular_albedo=0.3, specular_transmittance=0.05,
        diffuse_albedo=0.6, diffuse_transmittance=0.02,
        sheen_color=(0.45, 0.55, 0.8), sheen_roughness=0.6, sheen_thickness=0.15,
        source="3/1 right-hand (Z) warp-faced twill, indigo warp and ecru weft, ~70 x 46 "
               "threads/inch (12-14 oz); twist -30 degrees and warp/weft inclination 12/38 "
               "degrees from Irawan & Marschner 2012's denim",
        look="the diagonal twill lines, indigo face with flecks of the white weft"),
    Fabric(
        name="wool-gabardine", title="Wool gabardine", structure="woven", pattern="twill-2-2",
        ends_per_cm=50, picks_per_cm=26, yarn_diameter_mm=(0.22, 0.30),
        fibre_twist_deg=30.0, inclination_deg=30.0, ply=2, ply_twist_deg=25.0,
        warp_color=(0.55, 0.45, 0.32), weft_color=(0.55, 0.45, 0.32),
        roughness=0.35, thickness=2.5, specular_albedo=0.3, specular_transmittance=0.05,
        diffuse_albedo=0.55, diffuse_transmittance=0.02,
        sheen_color=(0.8, 0.72, 0.6), sheen_roughness=0.55, sheen_thickness=0.5,
        source="2/2 twill of worsted two-ply wool, warp about twice the weft count (the steep "
               "~63-degree twill line), ~130 x 65 threads/inch; twist 30 degrees and "
               "inclination 30 degrees from Irawan & Marschner 2012's wool gabardine",
        look="a steep, fine twill line and a soft sheen"),
    Fabric(
        name="linen", title="Linen", structure="woven", pattern="plain", repeat=16, texels_per_thread=8,
        ends_per_cm=20, picks_per_cm=20, yarn_diameter_mm=(0.62, 0.62),
        slub=0.8, slub_length_mm=(2.0, 9.0), slub_spacing_mm=10.0, slub_tone=1.2,
        fibre_twist_deg=-15.0, inclination_deg=28.0,
        warp_color=(0.78, 0.72, 0.60), weft_color=(0.74, 0.68, 0.56),
        roughness=0.35, thickness=2.0, specular_albedo=0.25, specular_transmittance=0.1,
        diffuse_albedo=0.6, diffuse_transmittance=0.08,
        sheen_color=(0.85, 0.8, 0.7), sheen_roughness=0.6, sheen_thickness=0.1,
        source="plain weave of wet-spun flax, ~50 x 50 threads/inch, irregular (slubby) yarns: "
               "thick places 2-9 mm long, about 10 mm apart along a yarn, up to 1.8x the "
               "yarn between them (mean diameter 0.62 mm at 0.5 mm spacing: the yarns flatten "
               "and press together, so even two thin places crossing leave no hole; 0.55 "
               "mm left dark pinholes); flax is spun with a low Z twist",
        look="an uneven, slubby grid of natural-coloured yarns with a dry, low lustre"),
    Fabric(
        name="silk-shantung", title="Silk shantung", structure="woven", pattern="plain", repeat=(64, 16),
        # The weft's slubs repeat with the tile's width: 21 mm, 3.5 slub spacings (half
        # that lined the slubs up into arcs in the close view).
        texels_per_thread=4,
        ends_per_cm=60, picks_per_cm=26, yarn_diameter_mm=(0.17, 0.4),
        slub=(0.0, 0.7), slub_length_mm=(2.0, 6.0), slub_spacing_mm=6.0, slub_tone=1.2,
        fibre_twist_deg=0.0, inclination_deg=23.0, profile_exponent=3.0,
        warp_color=(0.62, 0.08, 0.12), weft_color=(0.85, 0.55, 0.12),
        roughness=0.15, thickness=3.0, specular_albedo=0.7, specular_transmittance=0.08,
        diffuse_albedo=0.2, diffuse_transmittance=0.04,
        sheen_color=(0.9, 0.8, 0.6), sheen_roughness=0.5, sheen_thickness=0.05,
        source="plain weave of fine filament silk warp and thick, slubbed (dupion) weft, "
               "~150 x 65 threads/inch, the weft's slubs 2-6 mm long, about 6 mm apart, up to "
               "1.7x the yarn between them; 'shot' warp and weft of two colours; twist 0 and "
               "warp/weft inclination 50/23 degrees from Irawan & Marschner 2012's silk shantung",
        look="crosswise slubs and a colour that turns from the warp's to the weft's with the light"),
    Fabric(
        name="silk-organza", title="Silk organza", structure="woven", pattern="plain",
        ends_per_cm=40, picks_per_cm=40, yarn_diameter_mm=(0.10, 0.10),
        fibre_twist_deg=12.0, inclination_deg=25.0,
        warp_color=(0.92, 0.90, 0.86), weft_color=(0.92, 0.90, 0.86),
        roughness=0.18, thickness=1.5, specular_albedo=0.35, specular_transmittance=0.3,
        diffuse_albedo=0.35, diffuse_transmittance=0.25,
        sheen_color=(0.95, 0.95, 0.95), sheen_roughness=0.5, sheen_thickness=0.02,
        source="sheer, open plain weave of fine, hard-twisted filament silk, ~100 x 100 "
               "threads/inch; the yarns cover about 40% of each thread spacing",
        look="see-through: the background shows through the open grid, with a crisp sheen"),
    Fabric(
        name="cotton-jersey", title="Cotton jersey", structure="knit", pattern="jersey",
        ends_per_cm=14, picks_per_cm=18, yarn_diameter_mm=(0.3,),
        fibre_twist_deg=-25.0, inclination_deg=0.0,
        warp_color=(0.45, 0.47, 0.50), weft_color=(0.45, 0.47, 0.50),
        roughness=0.5, thickness=2.0, specular_albedo=0.2, specular_transmittance=0.1,
        diffuse_albedo=0.6, diffuse_transmittance=0.1,
        sheen_color=(0.8, 0.8, 0.8), sheen_roughness=0.6, sheen_thickness=0.3,
        source="single jersey of ring-spun cotton (T-shirt), ~36 wales x 46 courses per inch",
        look="rows of small V-shaped loops, matte with a soft fuzzy sheen at grazing angles"),
    Fabric(
        name="wool-rib", title="Wool rib", structure="knit", pattern="rib-2-2",
        ends_per_cm=6, picks_per_cm=7, yarn_diameter_mm=(0.9,),
        fibre_twist_deg=25.0, inclination_deg=0.0,
        warp_color=(0.45, 0.08, 0.10), weft_color=(0.45, 0.08, 0.10),
        roughness=0.55, thickness=2.5, specular_albedo=0.15, specular_transmittance=0.05,
        diffuse_albedo=0.65, diffuse_transmittance=0.05,
        sheen_color=(0.85, 0.6, 0.6), sheen_roughness=0.7, sheen_thickness=0.5,
        source="2x2 rib knit of worsted-weight wool (sweater cuffs), ~15 wales x 18 courses per inch",
        look="raised vertical ribs and a strong fuzzy rim where the cloth turns away"),
)}


#: Number fields that also take a (warp, weft) or (across, down) pair.
_PAIR_FIELDS = ("slub", "repeat")


@functools.lru_cache(maxsize=16)
def _fabric_file(path: str, stamp: int) -> Fabric:
    # ``stamp`` (the file's mtime) is only part of the cache key: an edited file is re-read.
    return load_fabric_file(path)


def register_fabric(preset: Fabric, replace: bool = False) -> Fabric:
    """Make ``preset`` available by name to the ``cloth`` plugin's ``fabric`` parameter
    (e.g. a variant made with :func:`dataclasses.replace`); an existing name is an error
    unless ``replace``."""
    if not isinstance(preset, Fabric):
        raise ParameterError(f"register_fabric: expected a Fabric, got {type(preset).__name__}")
    if preset.name in FABRICS and not replace:
        raise ParameterError(f"fabric {preset.name!r} exists; pass replace=True to replace it")
    FABRICS[preset.name] = preset
    return preset


def fabric_names() -> list[str]:
    return list(FABRICS)


def load_fabric_file(path: str | os.PathLike) -> Fabric:
    """A preset from a JSON file: an object of :class:`Fabric` fields, optionally starting
    from ``"base"`` (a preset name, or a .json fabric file beside this one) so that it need
    only say what differs; ``name`` defaults to the file's stem. Every value is checked as
    the Fabric is built; errors name the file and the field."""
    path = Path(path)
    try:
        data = json.loads(path.read_text())
    except OSError as error:
        raise ParameterError(f"fabric file {path}: cannot read it ({error.strerror or error})") from None
    except json.JSONDecodeError as error:
        raise ParameterError(f"fabric file {path}: not valid JSON (line {error.lineno}: {error.msg})") from None
    if not isinstance(data, dict):
        raise ParameterError(f"fabric file {path}: expected a JSON object of Fabric fields")
    fields = {f.name: f for f in dataclasses.fields(Fabric) if f.init}
    base_name = data.pop("base", None)
    base = _load_base(path, base_name) if base_name is not None else None
    values = {"name": path.stem}
    for key, value in data.items():
        if key not in fields:
            close = difflib.get_close_matches(key, fields, n=1)
            hint = f" (did you mean {close[0]!r}?)" if close else ""
            raise ParameterError(f"fabric file {path}: unknown field {key!r}{hint}")
        reference = getattr(base, key) if base is not None else fields[key].default
        if isinstance(value, list):
            value = tuple(value)
        pair_ok = key in _PAIR_FIELDS and isinstance(value, tuple) and len(value) == 2 and all(
            isinstance(v, (int, float)) and not isinstance(v, bool) for v in value)
        if isinstance(reference, (int, float)) and not isinstance(reference, bool) and not pair_ok and (
                isinstance(value, bool) or not isinstance(value, (int, float))):
            kind = "a number or a pair of numbers" if key in _PAIR_FIELDS else "a number"
            raise ParameterError(f"fabric file {path}: field {key!r} must be {kind}, got {value!r}")
        values[key] = value
    # Fabric's own checks then name the file (and the base a mismatched pattern's
    # structure came from).
    token = _LOADING.set((f"fabric file {path}", base_name if "structure" not in data else None))
    try:
        return dataclasses.replace(base, **values) if base is not None else Fabric(**values)
    except TypeError as error:  # a field missing without a base
        raise ParameterError(f"fabric file {path}: {error} (or give \"base\": a preset name)") from None
    finally:
        _LOADING.reset(token)


def _load_base(path: Path, base_name) -> Fabric:
    """The ``"base"`` of the fabric file ``path``: a preset, or a .json file beside it (else
    in the working directory); a chain of files that comes back to one of them is an error
    naming the chain."""
    where = f"fabric file {path}"
    if not isinstance(base_name, str) or not base_name:
        raise _bad(where, "base", "a preset name or a .json fabric file", base_name)
    if not base_name.lower().endswith(".json"):
        try:
            return fabric(base_name)
        except ParameterError as error:
            raise ParameterError(f"{where}: field 'base': {error}") from None
    located = Path(base_name)
    if not located.is_absolute() and (path.parent / located).is_file():
        located = path.parent / located
    if not located.is_file():
        raise ParameterError(f"{where}: field 'base': fabric file {base_name!r} does not exist "
                             f"(beside {path.name} or in the working directory)")
    me, target = str(path.resolve()), str(located.resolve())
    chain = _BASE_CHAIN.get()
    if not chain or chain[-1][0] != me:  # not itself a base being loaded: a chain starts here
        chain = ((me, str(path)),)
    if any(target == loaded for loaded, _ in chain):
        cycle = " -> ".join([shown for _, shown in chain] + [base_name])
        raise ParameterError(f"fabric file {chain[0][1]}: field 'base' makes a cycle: {cycle}")
    token = _BASE_CHAIN.set(chain + ((target, base_name),))
    try:
        return fabric(str(located))
    finally:
        _BASE_CHAIN.reset(token)


def fabric(name: str, locate=None) -> Fabric:
    """The preset called ``name``, or read from ``name`` when it is a ``.json`` file
    (:func:`load_fabric_file`; ``locate`` maps a relative path to where it is, e.g. the
    scene file's directory); an unknown name is an error naming the closest ones."""
    if isinstance(name, (str, os.PathLike)) and os.fspath(name).lower().endswith(".json"):
        path = locate(os.fspath(name)) if locate else os.fspath(name)
        if not Path(path).is_file():
            raise ParameterError(f"fabric file {name!r} does not exist")
        return _fabric_file(str(Path(path).resolve()), Path(path).stat().st_mtime_ns)
    if not isinstance(name, str) or name not in FABRICS:
        # Presets whose name holds the word typed ("silk": its three), then the closest spellings.
        word = str(name).strip().lower()
        close = [n for n in FABRICS if word in n] if len(word) >= 3 else []
        close += [c for c in difflib.get_close_matches(str(name), FABRICS, n=2) if c not in close]
        shown = [repr(c) for c in close[:4]]
        hint = f" (did you mean {', '.join(shown[:-1]) + ' or ' if len(shown) > 1 else ''}{shown[-1]}?)" \
            if shown else ""
        raise ParameterError(f"unknown fabric {name!r}{hint}: expected one of {', '.join(FABRICS)}")
    return FABRICS[name]


__all__ = ["FABRICS", "Fabric", "fabric", "fabric_names", "load_fabric_file", "register_fabric"]
