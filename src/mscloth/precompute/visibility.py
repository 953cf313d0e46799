"""Per-texel visibility of the cloth's own height field, and its k-means clusters (docs/design.md §4.3).

``visibility_table(height, n)[r, c, b]`` is 255 where the ray from texel (r, c)'s surface
point (its centre, at height[r, c]) along the centre direction of bin b (an upper-hemisphere
bin of :mod:`.direction_bins`, in the tile frame x = u, y = v, z = normal) leaves the periodic
height field without hitting it, else 0. The surface between texel centres is the bilinear
interpolation of the heights. ``back=True`` gives the same for the mirrored field (-height):
bin b then stands for the direction (wx, wy, -wz) below the cloth (light leaving below).

Marching (:mod:`._march`): every texel at once, one direction at a time, in steps of at most
``max_step`` texels along the ray's horizontal path, until the ray is above the tile's highest
point; a hit is a sample where the surface is more than ``eps`` (texels) above the ray.
``fast=True`` marches only the first block (>= 16 texels) of each ray sample by sample and
joins blocks at texel centres farther on (direction rounded to a rational slope, typically
< 0.1 degree off; see :func:`._march.escape_mask`).
"""
from __future__ import annotations

import numpy as np

from ._march import escape_mask
from ._util import as_pitch, map_ordered
from .direction_bins import bin_centres

__all__ = ["visibility_table", "cluster_visibility"]

#: Fields of fewer texels march their directions on one thread unless told otherwise: a
#: step's NumPy calls on them are too short for two threads to gain from releasing the GIL,
#: and handing it over costs more than it saves (measured: performance log L43).
THREADED_TEXELS = 256 * 256


def _texel_direction(w, pitch):
    px, py = pitch
    return (w[0] / px, w[1] / py, w[2] / px)


def visibility_table(height, n_dirs_side: int, *, back: bool = False, pitch=None,
                     max_step: float = 0.5, eps: float = 1e-4, fast: bool = False,
                     workers: int | None = None, progress=None) -> np.ndarray:
    """uint8 (H, W, n*n): 255 = the ray along bin b's centre escapes, 0 = it hits the field.

    height: (H, W) in tile-width units. pitch: texel size (x, y) in tile-width units
    (default (1/W, 1/H): a physically square tile). ``fast``: march the first >= 16 texels of
    each ray sample by sample, farther ones along the direction rounded to a rational slope
    (see :func:`._march.escape_mask`). ``progress(done, total)`` is called per direction.
    ``workers``: threads (default: one below :data:`THREADED_TEXELS` texels, else the CPUs').
    """
    height = np.asarray(height, dtype=np.float64)
    if height.ndim != 2 or 0 in height.shape:
        raise ValueError(f"visibility_table: expected height (H, W), got {height.shape}")
    if not np.all(np.isfinite(height)):
        raise ValueError("visibility_table: height has NaN or inf")
    pitch = as_pitch(pitch, height.shape)
    h_t = (-height if back else height) / pitch[0]         # texel units
    h_t = (h_t - h_t.mean()).astype(np.float32)             # centred: smaller float32 error
    dirs = bin_centres(n_dirs_side)
    if workers is None and height.size < THREADED_TEXELS:
        workers = 1

    def one(w):
        return escape_mask(h_t, _texel_direction(w, pitch), max_step=max_step, eps=eps,
                           fast=fast)

    masks = map_ordered(one, dirs, workers, progress)
    out = np.empty(height.shape + (len(dirs),), dtype=np.uint8)
    for b, m in enumerate(masks):
        out[..., b] = np.where(m, 255, 0)
    return out


def _sqdist(X: np.ndarray, C: np.ndarray, xx: np.ndarray) -> np.ndarray:
    """Squared distances (U, k), float64, clipped at 0."""
    d = xx[:, None] - 2.0 * (X @ C.T) + np.einsum("kd,kd->k", C, C)[None, :]
    return np.maximum(d, 0.0)


def _cluster_sums(labels: np.ndarray, Xw: np.ndarray, k: int) -> np.ndarray:
    """(k, D): the sum of the rows of ``Xw`` per label. A one-hot product: ``np.add.at`` took
    a third of the k-means time at 256^2. Visibility rows are 0/1 times integer weights, so
    the sums are exact in any order."""
    onehot = np.zeros((k, len(labels)))
    onehot[labels, np.arange(len(labels))] = 1.0
    return onehot @ Xw


def _kmeans_weighted(X, w, k, rng, iters):
    """Weighted k-means++ then Lloyd; returns (labels (U,), centres (k, D), inertia)."""
    U = X.shape[0]
    xx = np.einsum("ud,ud->u", X, X)
    Xw = X * w[:, None]
    p = w / w.sum()
    centres = np.empty((k, X.shape[1]))
    centres[0] = X[rng.choice(U, p=p)]
    d2 = _sqdist(X, centres[:1], xx)[:, 0]
    for j in range(1, k):
        q = w * d2
        tot = q.sum()
        idx = rng.choice(U, p=q / tot) if tot > 0 else rng.choice(U, p=p)
        centres[j] = X[idx]
        d2 = np.minimum(d2, _sqdist(X, centres[j:j + 1], xx)[:, 0])
    labels = None
    for _ in range(max(1, iters)):
        d = _sqdist(X, centres, xx)
        new = np.argmin(d, axis=1)
        if labels is not None and np.array_equal(new, labels):
            break
        labels = new
        sums = _cluster_sums(labels, Xw, k)
        counts = np.bincount(labels, weights=w, minlength=k)
        for j in range(k):
            if counts[j] > 0:
                centres[j] = sums[j] / counts[j]
            else:
                # Empty cluster: re-seed at the point worst served by its centre.
                far = d[np.arange(U), labels] * (w > 0)
                i = int(np.argmax(far))
                centres[j] = X[i]
                d[i, :] = 0.0                       # do not pick it twice
    d = _sqdist(X, centres, xx)
    labels = np.argmin(d, axis=1)
    inertia = float(np.sum(w * d[np.arange(U), labels]))
    return labels, centres, inertia


def cluster_visibility(vis, gap, k: int = 8, seed: int = 0, iters: int = 30, n_init: int = 3):
    """k-means of the per-texel visibility vectors of yarn texels (gap == 1).

    vis: (H, W, D) (uint8 0..255 or float); gap: (H, W) {0, 1}.
    Returns (cluster_id int8 (H, W), -1 in gaps; cluster_mean float32 (k, D)), where
    cluster_mean[c] is the mean of vis/255 over the texels of cluster c (for float input:
    the mean of vis). Deterministic: k-means++ seeding from ``numpy.random.default_rng(seed)``,
    ``n_init`` restarts (lowest inertia wins), identical vectors merged (weighted) first,
    empty clusters re-seeded at the worst-served point. Clusters are numbered by increasing
    mean visibility (cluster 0 is the most shadowed). A cluster that ends empty gets the mean
    of all yarn texels.
    """
    vis = np.asarray(vis)
    gap = np.asarray(gap)
    if vis.ndim != 3 or gap.shape != vis.shape[:2]:
        raise ValueError(f"cluster_visibility: expected vis (H, W, D) and gap (H, W), got "
                         f"{vis.shape} and {gap.shape}")
    k = int(k)
    if not 1 <= k <= 127:
        raise ValueError(f"cluster_visibility: k must be in [1, 127] (int8 ids), got {k}")
    H, W, D = vis.shape
    scale = 255.0 if vis.dtype == np.uint8 else 1.0
    yarn = gap.astype(bool).ravel() if gap.dtype == bool else (gap.ravel() != 0)
    ids = np.full(H * W, -1, dtype=np.int8)
    rows = vis.reshape(H * W, D)[yarn]
    if rows.shape[0] == 0:
        return ids.reshape(H, W), np.ones((k, D), dtype=np.float32)
    # Merge identical vectors: visibility rows are binary, so there are few distinct ones.
    rows_c = np.ascontiguousarray(rows)
    key = rows_c.view(np.dtype((np.void, rows_c.dtype.itemsize * D))).ravel()
    _, first, inverse, counts = np.unique(key, return_index=True, return_inverse=True,
                                          return_counts=True)
    X = rows_c[first].astype(np.float64) / scale
    w = counts.astype(np.float64)
    rng = np.random.default_rng(seed)
    best = None
    for _ in range(max(1, int(n_init))):
        labels, centres, inertia = _kmeans_weighted(X, w, k, rng, iters)
        if best is None or inertia < best[2] - 1e-12:
            best = (labels, centres, inertia)
    labels = best[0]
    # Per-cluster means over texels, then renumber by increasing mean visibility.
    sums = _cluster_sums(labels, X * w[:, None], k)
    counts_k = np.bincount(labels, weights=w, minlength=k)
    overall = (X * w[:, None]).sum(axis=0) / w.sum()
    means = np.where(counts_k[:, None] > 0, sums / np.maximum(counts_k, 1e-300)[:, None],
                     overall[None, :])
    order = np.lexsort((-counts_k, means.mean(axis=1)))     # by mean visibility, then size
    rank = np.empty(k, dtype=np.int64)
    rank[order] = np.arange(k)
    ids[yarn] = rank[labels[inverse.ravel()]].astype(np.int8)
    return ids.reshape(H, W), means[order].astype(np.float32)
