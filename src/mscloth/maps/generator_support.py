"""What the woven and knit map generators share: argument checks, colour conversion and
normals from a periodic height field."""
from __future__ import annotations

import math
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


#: Largest tile side a generator makes, in texels.
MAX_RESOLUTION = 16384


def tile_resolution(resolution: Any, aspect: float, counts: tuple[int, int],
                    min_texels: int, kinds: tuple[str, str]) -> tuple[int, int]:
    """(H, W) texels of a tile: an int is the width (the height follows ``aspect`` =
    height / width), an (H, W) pair is exact. Each side needs ``min_texels`` for each of its
    ``counts`` (rows, columns) of threads or stitches, named by ``kinds``."""
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
        need = f"{min_texels} texels for each of the {count} {kind}"
        if isinstance(resolution, tuple | list):
            raise ResolutionError(f"resolution {side} must be in [{lo}, {MAX_RESOLUTION}] ({need}), got {n}")
        # An int is the width only: say which widths work, whichever side failed (a width
        # in range whose height, at the tile's aspect, is not, is no help to anyone).
        low, high = width_range(aspect, counts, min_texels)
        bound = f"it needs {need}" if n < lo else f"a tile side has at most {MAX_RESOLUTION} texels"
        reason = bound if side == "W" else \
            f"its height would be {n} texels at the tile's aspect H/W = {aspect:.3g}; {bound}"
        if low > high:
            raise ResolutionError(f"no resolution (texels along u) fits this tile: {reason}", low, high, reason)
        raise ResolutionError(f"resolution (texels along u) must be in [{low}, {high}] for this tile, "
                              f"got {w}: {reason}", low, high, reason)
    return pair


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
