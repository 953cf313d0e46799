"""What the woven and knit map generators share: argument checks, colour conversion and
normals from a periodic height field."""
from __future__ import annotations

import math
from numbers import Integral, Real
from typing import Any

import numpy as np

from ..errors import ParameterError


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
        pair = (max(1, int(round(w * aspect))), w)
    elif (isinstance(resolution, (tuple, list)) and len(resolution) == 2
          and all(isinstance(n, Integral) and not isinstance(n, bool) for n in resolution)):
        pair = (int(resolution[0]), int(resolution[1]))
    else:
        raise ParameterError(f"resolution must be an int (texels along u) or an (H, W) pair of "
                             f"ints, got {resolution!r}")
    for side, n, count, kind in (("H", pair[0], counts[0], kinds[0]), ("W", pair[1], counts[1], kinds[1])):
        lo = min_texels * count
        if not lo <= n <= MAX_RESOLUTION:
            raise ParameterError(f"resolution {side} must be in [{lo}, {MAX_RESOLUTION}] "
                                 f"({min_texels} texels for each of the {count} {kind}), got {n}")
    return pair
