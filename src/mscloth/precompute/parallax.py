"""Parallax offsets (supplement Algorithm 3, our reading; docs/design.md §4.4).

For texel (r, c) and viewer direction w (centre of an upper-hemisphere bin of
:mod:`.direction_bins`, pointing toward the viewer, tile frame x = u, y = v, z = normal): the
view ray travels along -w and enters the cloth at the top, i.e. at (c, r, max height) right
above the macro-surface point; it is marched (steps <= ``max_step`` texels along its
horizontal path; bilinear, periodic height field) to the first point where it meets the
surface, and the crossing is refined between the two samples around it by linear
interpolation. The table holds that point's offset (dx, dy) in texels (dx along columns/u,
dy along rows/v): shift the lookup from (x, y) to (x + dx, y + dy).

As in Algorithm 3 the ray enters right above the shading point at the maximum height. If the
shading point is instead taken to lie on a mesh at height ``h_ref`` (e.g. 0), the entry point
moves by (max_height - h_ref) * w.xy / w.z (converted to texels) for every texel alike: add
that per-direction constant at lookup time.
"""
from __future__ import annotations

import numpy as np

from ._march import first_hit_offsets
from ._util import as_pitch, map_ordered
from .direction_bins import bin_centres

__all__ = ["parallax_table"]


def parallax_table(height, n_dirs_side: int, *, pitch=None, max_step: float = 0.5,
                   workers: int | None = None, progress=None) -> np.ndarray:
    """float32 (H, W, n*n, 2): (dx, dy) texel offsets of the first hit, per viewer bin.

    height: (H, W) in tile-width units; pitch: texel size (x, y) in tile-width units
    (default (1/W, 1/H)). ``progress(done, total)`` is called per direction.
    """
    height = np.asarray(height, dtype=np.float64)
    if height.ndim != 2 or 0 in height.shape:
        raise ValueError(f"parallax_table: expected height (H, W), got {height.shape}")
    if not np.all(np.isfinite(height)):
        raise ValueError("parallax_table: height has NaN or inf")
    px, py = as_pitch(pitch, height.shape)
    h_t = height / px
    h_t = (h_t - h_t.mean()).astype(np.float32)
    dirs = bin_centres(n_dirs_side)

    def one(w):
        # The ray goes away from the viewer: along -w. Heights are in x-texel units.
        return first_hit_offsets(h_t, (-w[0] / px, -w[1] / py, -w[2] / px), max_step=max_step)

    res = map_ordered(one, dirs, workers, progress)
    out = np.empty(height.shape + (len(dirs), 2), dtype=np.float32)
    for b, (ox, oy) in enumerate(res):
        out[:, :, b, 0] = ox
        out[:, :, b, 1] = oy
    return out
