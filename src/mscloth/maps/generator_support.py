"""What the woven and knit map generators share: argument checks, colour conversion and
normals from a periodic height field."""
from __future__ import annotations

import math
import os
from numbers import Integral, Real
from typing import Any

import numpy as np

from ..errors import ParameterError, ResolutionError


def real_in(name: str, value: Any, lo: float, hi: float, lo_open: bool, hi_open: bool) -> float:
    """Return ``value`` as a float inside the stated interval, or raise ParameterError."""
    interval = f"{'(' if lo_open else '['}{lo:g}, {hi:g}{')' if hi_open else ']'}"
    if isinstance(value, bool) or not isinstance(value, Real):
        raise ParameterError(f"{name} must be a real number in {interval}, got {value!r}")
    x = float(value)
    below = x <= lo if lo_open else x < lo
    above = x >= hi if hi_open else x > hi
    if math.isnan(x) or below or above:
        raise ParameterError(f"{name} must be in {interval}, got {value!r}")
    return x


def srgb_to_linear(c: Any) -> np.ndarray:
    """The standard sRGB EOTF: display colours in [0, 1] -> linear albedo in [0, 1]."""
    c = np.asarray(c, dtype=np.float64)
    return np.where(c <= 0.04045, c / 12.92, ((c + 0.055) / 1.055) ** 2.4)


def height_normal(height: np.ndarray, du: float, dv: float) -> np.ndarray:
    """Unit normals (z > 0) of a periodic height field by central differences; ``du``,
    ``dv`` are the texel sizes in the height's unit (tile widths)."""
    dhdu = (np.roll(height, -1, axis=1) - np.roll(height, 1, axis=1)) / (2.0 * du)
    dhdv = (np.roll(height, -1, axis=0) - np.roll(height, 1, axis=0)) / (2.0 * dv)
    n = np.stack([-dhdu, -dhdv, np.ones_like(height)], axis=-1)
    return n / np.linalg.norm(n, axis=-1, keepdims=True)


#: Largest tile side a generator makes, in texels: the ``cloth`` BSDF's ``resolution``
#: takes at most this too (bsdf/parameters.py), and a tile this large already needs tens of
#: GB to generate (BYTES_PER_TEXEL).
MAX_RESOLUTION = 8192


def tile_resolution(resolution: Any, aspect: float, counts: tuple[int, int],
                    min_texels: int, kinds: tuple[str, str]) -> tuple[int, int]:
    """(H, W) texels of a tile: an int is the width (the height follows ``aspect`` =
    height / width), an (H, W) pair is exact. Each side needs ``min_texels`` for each of its
    ``counts`` (rows, columns) of threads or stitches, named by ``kinds`` (plural)."""
    if isinstance(resolution, Integral) and not isinstance(resolution, bool):
        w = int(resolution)
        pair = _height_width(w, aspect)
    elif (isinstance(resolution, (tuple, list)) and len(resolution) == 2
          and all(isinstance(n, Integral) and not isinstance(n, bool) for n in resolution)):
        pair = (int(resolution[0]), int(resolution[1]))
    else:
        raise ParameterError(f"resolution must be an int (texels along u) or an (H, W) pair of "
                             f"ints, got {resolution!r}")
    for side, n, count, kind in (("H", pair[0], counts[0], kinds[0]), ("W", pair[1], counts[1], kinds[1])):
        lo = min_texels * count
        if lo <= n <= MAX_RESOLUTION:
            continue
        need = _texels_for(min_texels, count, kind)
        if isinstance(resolution, tuple | list):
            raise ResolutionError(f"resolution {side} must be in [{lo}, {MAX_RESOLUTION}] ({need}), got {n}")
        low, high = width_range(aspect, counts, min_texels)
        if low > high:
            raise no_fit_error(aspect, counts, min_texels, kinds)
        # An int is the width only: say which widths work, whichever side failed (a width
        # in range whose height, at the tile's aspect, is not, is no help to anyone).
        bound = f"it needs {need}" if n < lo else f"a tile side has at most {MAX_RESOLUTION} texels"
        reason = bound if side == "W" else \
            f"its height would be {n} texels at the tile's aspect H/W = {_ratio(aspect)}; {bound}"
        raise ResolutionError(f"resolution (texels along u) must be in [{low}, {high}] for this tile, "
                              f"got {w}: {reason}", low, high, reason)
    return pair


def fit_width(preferred: int, aspect: float, counts: tuple[int, int], min_texels: int,
              kinds: tuple[str, str]) -> int:
    """``preferred`` texels along u moved into the widths :func:`tile_resolution` accepts
    (a default must always fit its tile); ResolutionError if no width does."""
    low, high = width_range(aspect, counts, min_texels)
    if low > high:
        raise no_fit_error(aspect, counts, min_texels, kinds)
    return min(max(int(preferred), low), high)


def no_fit_error(aspect: float, counts: tuple[int, int], min_texels: int,
                 kinds: tuple[str, str]) -> ResolutionError:
    """The error for a tile that no width fits: why, and what would fit, in terms of the
    pattern (not of any resolution, which cannot help)."""
    low, high = width_range(aspect, counts, min_texels)
    for count, kind in zip(counts, kinds):
        if min_texels * count > MAX_RESOLUTION:
            reason = (f"it needs {_texels_for(min_texels, count, kind)} ({min_texels * count} in all), more "
                      f"than the {MAX_RESOLUTION} a tile side may have; a repeat of at most "
                      f"{MAX_RESOLUTION // min_texels} {kind} fits")
            break
    else:
        # Each count fits a side, but not both at the tile's aspect: one side, made just
        # large enough for its threads, makes the other too long.
        lo_h, lo_w = min_texels * counts[0], min_texels * counts[1]
        tallest = _height_width(lo_w, aspect)[0]
        if tallest > MAX_RESOLUTION:
            rows, too = kinds[0], f"as wide as its {counts[1]} {kinds[1]} need ({lo_w} texels) would be " \
                                  f"{tallest} texels tall"
        else:
            rows, too = kinds[1], f"as tall as its {counts[0]} {kinds[0]} need ({lo_h} texels) would be " \
                                  f"{lo_h / aspect:.0f} texels wide"
        reason = (f"at its aspect H/W = {_ratio(aspect)}, a tile {too}, more than the {MAX_RESOLUTION} a tile "
                  f"side may have; fewer {rows} per repeat, or {rows} spaced more closely, would fit")
    return ResolutionError(f"no resolution (texels along u) fits this tile: {reason}", low, high, reason)


def _ratio(x: float) -> str:
    """3 significant digits, without an exponent for large ratios (1250, not 1.25e+03)."""
    return f"{x:.3g}" if x < 1000 else f"{x:.0f}"


def _texels_for(min_texels: int, count: int, kind: str) -> str:
    """"4 texels for each of the 3 courses", "4 texels for its 1 course"."""
    if count == 1:
        return f"{min_texels} texels for its 1 {kind.removesuffix('s')}"
    return f"{min_texels} texels for each of the {count} {kind}"


#: Peak memory of generating a tile, bytes per texel: woven and knit maps peaked at
#: 425-533 bytes per texel at 512^2 and 1024^2 (tracemalloc; plies and slubs the most, the
#: process's RSS grew alike), plus a fixed ~40 MiB (the knit's guess table), so this
#: leaves ~20% headroom.
BYTES_PER_TEXEL, FIXED_BYTES = 640, 64 << 20


def available_memory() -> int | None:
    """Bytes of memory the system can give without swapping (Linux MemAvailable, else free
    pages); None if unknown."""
    try:
        with open("/proc/meminfo") as f:
            for line in f:
                if line.startswith("MemAvailable:"):
                    return int(line.split()[1]) * 1024
    except (OSError, ValueError, IndexError):
        pass
    try:
        return os.sysconf("SC_AVPHYS_PAGES") * os.sysconf("SC_PAGE_SIZE")
    except (AttributeError, OSError, ValueError):
        return None


def memory_estimate(shape: tuple[int, int]) -> int:
    """Bytes a generator needs at its peak for a tile of ``shape`` (H, W) texels."""
    return BYTES_PER_TEXEL * shape[0] * shape[1] + FIXED_BYTES


def check_memory(shape: tuple[int, int], aspect: float, counts: tuple[int, int], min_texels: int) -> None:
    """ResolutionError, before any array is made, if a tile of ``shape`` (H, W) would need
    more memory than is available (else NumPy fails deep inside, or the OOM killer ends the
    process). The error carries ``needed``, ``available`` (bytes) and ``largest``: the most
    texels along u that fit this tile (``aspect``, ``counts``, ``min_texels`` as for
    :func:`tile_resolution`), None if none does, so that callers can say it in their terms."""
    available = available_memory()
    needed = memory_estimate(shape)
    if available is None or needed <= available:
        return
    h, w = shape
    largest = int(math.sqrt(max(0, available - FIXED_BYTES) / (BYTES_PER_TEXEL * aspect)))
    while largest > 0 and memory_estimate(_height_width(largest, aspect)) > available:
        largest -= 1  # (the height is rounded)
    low, high = width_range(aspect, counts, min_texels)
    largest = min(largest, high) if largest >= low else None
    hint = (f"resolution {largest} (texels along u) or less fits" if largest is not None else
            f"no resolution fits (this tile needs at least {low} texels along u)")
    error = ResolutionError(f"maps of {w}x{h} texels need about {format_bytes(needed)} of memory to "
                            f"generate ({BYTES_PER_TEXEL} bytes per texel), but {format_bytes(available)} "
                            f"is available: {hint}")
    error.needed, error.available, error.largest = needed, available, largest
    raise error


def format_bytes(n: int) -> str:
    """1.5 GiB, 300 MiB."""
    return f"{n / 2**30:.1f} GiB" if n >= 2**30 else f"{n / 2**20:.0f} MiB"


class MapsWarning(UserWarning):
    """Maps that will not look as asked (a yarn thinner than a texel...). ``template`` has
    ``{res}`` where the resolution is named and ``{along}`` after its value: the message says
    "resolution N (texels along u)"; :meth:`naming` names a flag instead (the CLI's --res)."""

    def __init__(self, template: str):
        super().__init__(template.format(res="resolution", along=" (texels along u)"))
        self.template = template

    def naming(self, flag: str) -> str:
        return self.template.format(res=flag, along="")


def _height_width(w: int, aspect: float) -> tuple[int, int]:
    """(H, W) of a tile ``w`` texels wide whose height / width is ``aspect``."""
    return max(1, int(round(w * aspect))), w


def width_range(aspect: float, counts: tuple[int, int], min_texels: int) -> tuple[int, int]:
    """The widths (texels along u) :func:`tile_resolution` accepts as an int for a tile of
    ``aspect`` with ``counts`` (rows, columns) of threads: (low, high), low > high if none."""
    lo_h, lo_w = min_texels * counts[0], min_texels * counts[1]

    def fits(w):
        h, _ = _height_width(w, aspect)
        return lo_h <= h <= MAX_RESOLUTION

    # The height is monotonic in w: start from the real-valued bounds, step over rounding.
    low = max(lo_w, math.ceil((lo_h - 0.5) / aspect) - 1)
    while low <= MAX_RESOLUTION and not fits(low):
        low += 1
    high = min(MAX_RESOLUTION, math.floor((MAX_RESOLUTION + 0.5) / aspect) + 1)
    while high >= low and not fits(high):
        high -= 1
    return low, high
