"""All per-tile tables of the multi-scale BSDF (docs/design.md §4), their build, and an on-disk cache.

Coordinates of every SAT query are texel units: x = u*W along columns, y = v*H along rows;
texel (r, c) covers [c, c+1) x [r, r+1); queries are periodic (see :mod:`.summed_area`).
Direction bins come from :mod:`.direction_bins` (flat index b*n + a, tile frame x = u,
y = v, z = macro normal).

Tables (``X_sat`` is a residual SAT float32 (C, H+1, W+1), ``X_mean`` its per-channel mean,
float64; the integral of channel c over a rectangle is ``rect_sum(X_sat, X_mean, ...)``):

=====================  =====================================================================
d_sat / d_mean         (dr*dr channels) D(h_b, t(p)) * gap(p), h_b = bin centres of dr x dr
                       bins on the upper hemisphere (D is even, so fold h to z >= 0); with
                       d_rank = K > 0: (K channels) the coefficients c_k(p) of D's rank-K
                       expansion D(h_b, t(p)) gap(p) ~ sum_k d_basis[b, k] c_k(p)
d_basis                optional (dr*dr, K) float32: orthonormal basis over the bins (PCA of
                       D(h_b, t) gap over a sample of the tile's texels)
gap_sat / gap_mean     (1) gap indicator I(p)
albedo_sat / _mean     (3) albedo(p) * gap(p)
moment_sat / _mean     (6) t t^T * gap as [xx, xy, xz, yy, yz, zz]
cluster_sat / _mean    (clusters) one-hot(cluster_id(p)) * gap(p): cluster histogram
d_sat_cluster          optional (clusters, dr*dr or K, H+1, W+1) D * gap * [cluster_id == c]
 / d_cluster_mean      (clusters, dr*dr): the unbiased CCV base sum_c vbar_c int_{P∩c} D
d_cluster_tile         float32 (dr*dr, clusters): mean of D * gap over each cluster's yarn in the
                       tile, per bin: weights of the clusters' visibilities in the default base
visibility             uint8 (H, W, dv*dv): 255 = the ray from the texel along bin b escapes
visibility_back        the same for the mirrored field (bin b = direction (wx, wy, -wz))
cluster_id             int8 (H, W), -1 in gaps: k-means of the front visibility vectors
cluster_vis / _back    float32 (clusters, dv*dv): mean of visibility/255 over each cluster
parallax               optional float32 (H, W, dv*dv, 2): texel offset (dx, dy) of the first hit of the
                       view ray entering above the texel at max height (viewer bin b)
=====================  =====================================================================

``params`` holds the build inputs (those that enter ``key``) plus derived facts ("shape",
"pitch", "height_range", "build_seconds"); ``key`` is the SHA-256 cache key.
"""
from __future__ import annotations

import hashlib
import json
import math
import threading
import time
import warnings
import zipfile
from dataclasses import dataclass, field, fields
from pathlib import Path

import numpy as np

from ..atomic import atomic_write
from ..cache import default_cache_dir, mark_used
from ..errors import ParameterError
from ._util import Progress, map_ordered, texel_pitch
from ..scattering.fibre_ndf import fibre_ndf_of_cosines, fibre_ndf_of_unit_cosine_inplace
from .direction_bins import bin_centres, fold_upper, hemisphere_to_square, triangle_bins
from .parallax import parallax_table
from .summed_area import _residual_cumsum, build_sat, rect_mean, rect_sum
from .visibility import cluster_visibility, visibility_table

__all__ = ["FORMAT_VERSION", "MultiscaleTables", "TableKey", "build_tables", "load_or_build", "table_key",
           "default_cache_dir", "sggx_fibre_ndf"]

FORMAT_VERSION = 2
_MAPS_FIELDS = ("tangent", "normal", "height", "gap", "yarn_id", "albedo")
# Channels of D computed per chunk (float64 temporaries: chunk * H * W * 8 bytes).
_D_CHUNK_BYTES = 8 << 20


def sggx_fibre_ndf(m: np.ndarray, t: np.ndarray, alpha: float) -> np.ndarray:
    """D(m) = alpha^3 / (pi ((m.t)^2 + alpha^2 (1 - (m.t)^2))^2) for unit m and t (float64).

    The fibre-like SGGX of :mod:`mscloth.scattering.sggx` (S = alpha^2 t t^T + I - t t^T).
    """
    m = np.asarray(m, dtype=np.float64)
    mt = np.sum(m * np.asarray(t, dtype=np.float64), axis=-1)
    return fibre_ndf_of_cosines(mt * mt, np.sum(m * m, axis=-1), alpha)


def fibre_ndf_of_cosine(mt: np.ndarray, alpha: float, out: np.ndarray | None = None) -> np.ndarray:
    """:func:`sggx_fibre_ndf` as a function of the cosine m.t of a unit m (any shape,
    float64): :func:`mscloth.scattering.fibre_ndf.fibre_ndf_of_unit_cosine_inplace`, the
    in-place form of the formula shading evaluates. ``out``: where to compute it, ``mt``
    itself allowed (the directional SAT's chunks reuse their product's memory)."""
    if out is None:
        out = np.array(mt, dtype=np.float64)
    elif out is not mt:
        out[...] = mt
    return fibre_ndf_of_unit_cosine_inplace(out, alpha, np.divide)


# ---------------------------------------------------------------------------- the tables
@dataclass(eq=False)
class MultiscaleTables:
    """Precomputed tables of one cloth tile (see the module docstring for each field)."""

    d_sat: np.ndarray
    d_mean: np.ndarray
    gap_sat: np.ndarray
    gap_mean: np.ndarray
    albedo_sat: np.ndarray
    albedo_mean: np.ndarray
    moment_sat: np.ndarray
    moment_mean: np.ndarray
    cluster_sat: np.ndarray
    cluster_mean: np.ndarray
    visibility: np.ndarray
    visibility_back: np.ndarray
    cluster_id: np.ndarray
    cluster_vis: np.ndarray
    cluster_vis_back: np.ndarray
    parallax: np.ndarray | None = None
    d_sat_cluster: np.ndarray | None = None
    d_cluster_mean: np.ndarray | None = None
    d_basis: np.ndarray | None = None
    d_cluster_tile: np.ndarray | None = None
    params: dict = field(default_factory=dict)
    key: str = ""

    # ---------------------------------------------------------------- introspection
    @classmethod
    def array_fields(cls) -> tuple[str, ...]:
        return tuple(f.name for f in fields(cls) if f.name not in ("params", "key"))

    def arrays(self) -> dict[str, np.ndarray]:
        """name -> array, for every table present (optional ones may be None)."""
        return {n: getattr(self, n) for n in self.array_fields() if getattr(self, n) is not None}

    @property
    def resolution(self) -> tuple[int, int]:
        return tuple(int(s) for s in self.visibility.shape[:2])

    @property
    def dr(self) -> int:
        return int(self.params["dr"])

    @property
    def dv(self) -> int:
        return int(self.params["dv"])

    def memory_report(self) -> dict[str, int]:
        """name -> bytes of every table present."""
        return {n: int(a.nbytes) for n, a in self.arrays().items()}

    def summary(self) -> str:
        """One line per table (shape, dtype, MiB) and the total."""
        rep = self.memory_report()
        arrs = self.arrays()
        H, W = self.resolution
        p = self.params
        lines = [f"MultiscaleTables {H}x{W}, roughness {p.get('roughness')}, dr {p.get('dr')}, "
                 f"dv {p.get('dv')}, clusters {p.get('clusters')}, key {self.key[:12]}"]
        for n, b in sorted(rep.items(), key=lambda kv: -kv[1]):
            a = arrs[n]
            lines.append(f"  {n:<18} {str(a.shape):<26} {a.dtype!s:<8} {b / 2**20:10.2f} MiB")
        lines.append(f"  {'total':<18} {'':<26} {'':<8} {sum(rep.values()) / 2**20:10.2f} MiB")
        if "build_seconds" in p:
            lines.append(f"  built in {p['build_seconds']:.2f} s")
        return "\n".join(lines)

    # ---------------------------------------------------------------- reference queries
    def sat(self, name: str):
        """(sat, mean) of the SAT called ``name``: d, gap, albedo, moment, cluster."""
        if name not in ("d", "gap", "albedo", "moment", "cluster"):
            raise KeyError(f"no SAT named {name!r} (d, gap, albedo, moment, cluster)")
        return getattr(self, f"{name}_sat"), getattr(self, f"{name}_mean")

    def footprint_sum(self, name: str, x0, y0, x1, y1, channels=None) -> np.ndarray:
        """Integral over texel rectangles of SAT ``name`` (see :func:`.summed_area.rect_sum`)."""
        s, m = self.sat(name)
        return rect_sum(s, m, x0, y0, x1, y1, channels)

    def footprint_mean(self, name: str, x0, y0, x1, y1, channels=None) -> np.ndarray:
        """Mean over texel rectangles of SAT ``name`` (area > 0)."""
        s, m = self.sat(name)
        return rect_mean(s, m, x0, y0, x1, y1, channels)

    def d_footprint_mean(self, h, x0, y0, x1, y1) -> np.ndarray:
        """Footprint mean of D(h, t(p)) * gap(p) for half vectors h (..., 3), interpolating
        over the triangle of the three nearest h bins, as the BSDF does (reference version)."""
        h = np.asarray(h, dtype=np.float64)
        h = h / np.linalg.norm(h, axis=-1, keepdims=True)
        idx, wts = triangle_bins(hemisphere_to_square(fold_upper(h)), self.dr)
        if self.d_basis is not None:  # rank-K: the K coefficient means, then the basis rows
            coef = rect_mean(self.d_sat, self.d_mean, *(np.asarray(a, dtype=np.float64) for a in (x0, y0, x1, y1)))
            rows = self.d_basis.astype(np.float64)[idx]                  # (..., 3, K)
            return np.sum(wts * np.einsum("...bk,...k->...b", rows, coef), axis=-1)
        x0, y0, x1, y1 = (np.asarray(a, dtype=np.float64)[..., None] for a in (x0, y0, x1, y1))
        vals = rect_mean(self.d_sat, self.d_mean, x0, y0, x1, y1, channels=idx)
        return np.sum(vals * wts, axis=-1)


# ---------------------------------------------------------------------------- parameters
def _int_param(name, value, lo, hi):
    if isinstance(value, bool) or not isinstance(value, (int, np.integer)) or not lo <= value <= hi:
        raise ParameterError(f"{name} must be an integer in [{lo}, {hi}], got {value!r}")
    return int(value)


#: Rank of the compressed directional SAT when the full one is over its memory budget:
#: footprint means within ~0.5% of the full table at roughness 0.3 (tests/test_precompute.py).
AUTO_RANK = 64


def choose_direction_rank(height: int, width: int, dr: int, requested: int, max_mib: float) -> tuple[int, str]:
    """The directional SAT's rank for a (height, width) tile: ``requested`` if set (> 0),
    else 0 (the full dr^2 channels) when that fits in ``max_mib`` MiB, else
    :data:`AUTO_RANK`, or the largest multiple of 4 that fits (at least 4).

    Returns (rank, why): ``why`` is empty unless the budget chose the rank. The per-cluster
    tables of ``unbiased_ccv`` (8x more) are not counted: asking for them asks for their
    memory, and a rank-K per-cluster base reads K channels per cluster and corner, which
    makes kernels too large to compile in reasonable time."""
    if requested:
        return requested, ""
    per_channel = (height + 1) * (width + 1) * 4 / 2**20
    full = dr * dr * per_channel
    if full <= max_mib:
        return 0, ""
    fits = int(max_mib // per_channel) // 4 * 4
    rank = max(4, min(AUTO_RANK, fits, dr * dr))
    return rank, (f"the full directional SAT of a {width}x{height} tile at {dr}x{dr} bins would take "
                  f"{full:.0f} MiB > max_table_mib {max_mib:g}: using rank {rank} "
                  f"({rank * per_channel:.0f} MiB; set direction_rank or max_table_mib to choose)")


@dataclass(frozen=True)
class TableKey:
    """What the tables of one tile are built from besides its maps: with them, all of the
    cache key (:func:`table_key`). Validated once, here; a changed value is a new key.

    roughness: fibre SGGX alpha in (0, 1] (the directional SATs, their basis and the
    clusters' mean D). dr: h bins per side of the directional SAT. d_rank: 0 (full) or the
    rank of its compression. dv: direction bins per side of the visibility and parallax
    tables. clusters: k of the visibility k-means. per_cluster_sat: the per-cluster SATs.
    parallax: the parallax table. seed, iters: k-means. max_step, vis_eps, fast_visibility:
    the visibility march (see :func:`build_tables`)."""

    roughness: float
    dr: int = 16
    dv: int = 8
    clusters: int = 8
    per_cluster_sat: bool = False
    seed: int = 0
    iters: int = 30
    max_step: float = 0.5
    vis_eps: float = 1e-4
    fast_visibility: bool = True
    d_rank: int = 0
    parallax: bool = False

    def __post_init__(self):
        try:
            alpha = float(self.roughness)
        except (TypeError, ValueError):
            raise ParameterError(f"roughness must be a number in (0, 1], got {self.roughness!r}") from None
        if not (math.isfinite(alpha) and 0.0 < alpha <= 1.0):
            raise ParameterError(f"roughness must be a number in (0, 1], got {self.roughness!r}")
        step = float(self.max_step)
        if not (math.isfinite(step) and 0.0 < step <= 1.0):
            raise ParameterError(f"max_step must be in (0, 1] texels, got {self.max_step!r}")
        eps = float(self.vis_eps)
        if not (math.isfinite(eps) and eps >= 0.0):
            raise ParameterError(f"vis_eps must be >= 0, got {self.vis_eps!r}")
        dr = _int_param("dr", self.dr, 1, 256)
        d_rank = _int_param("d_rank", self.d_rank, 0, dr * dr)
        normalised = {
            "roughness": alpha,
            "dr": dr,
            # 0 or dr*dr: the full directional SAT; a rank equal to the bin count saves nothing.
            "d_rank": 0 if d_rank == dr * dr else d_rank,
            "dv": _int_param("dv", self.dv, 1, 64),
            "clusters": _int_param("clusters", self.clusters, 1, 127),
            "per_cluster_sat": bool(self.per_cluster_sat),
            "seed": _int_param("seed", self.seed, 0, 2**63 - 1),
            "iters": _int_param("iters", self.iters, 1, 10000),
            "max_step": step,
            "vis_eps": eps,
            "fast_visibility": bool(self.fast_visibility),
            "parallax": bool(self.parallax),
        }
        for name, value in normalised.items():
            object.__setattr__(self, name, value)

    def as_params(self) -> dict:
        """The build inputs as :attr:`MultiscaleTables.params` holds them (hashed by
        :func:`table_key`)."""
        return {f.name: getattr(self, f.name) for f in fields(self)}


def _table_key(roughness, **kw) -> TableKey:
    """``roughness`` if it is a TableKey (then no other build inputs), else a TableKey of it
    and ``kw``."""
    if isinstance(roughness, TableKey):
        if kw:
            raise TypeError(f"build inputs {sorted(kw)} given with a TableKey")
        return roughness
    return TableKey(roughness, **kw)


def _params(roughness, **kw) -> dict:
    return _table_key(roughness, **kw).as_params()


def table_key(maps, params: dict) -> str:
    """SHA-256 (hex) of the maps' arrays and meta, the build parameters and FORMAT_VERSION."""
    hs = hashlib.sha256()
    hs.update(f"mscloth-multiscale-tables/{FORMAT_VERSION}\n".encode())
    for name in _MAPS_FIELDS:
        a = np.ascontiguousarray(getattr(maps, name))
        hs.update(f"{name}:{a.dtype.str}:{a.shape}\n".encode())
        hs.update(memoryview(a).cast("B"))
    hs.update(json.dumps(getattr(maps, "meta", {}), sort_keys=True).encode())
    hs.update(json.dumps(params, sort_keys=True).encode())
    return hs.hexdigest()


# ---------------------------------------------------------------------------- building
def _sat_parallel(n_channels, H, W, produce, workers, progress_cb, chunk, out=None, mean=None):
    """Residual SAT of channels produced chunk by chunk (on worker threads), into ``out``."""
    if out is None:
        out = np.empty((n_channels, H + 1, W + 1), dtype=np.float32)
    if mean is None:
        mean = np.empty(n_channels, dtype=np.float64)
    ranges = [(c0, min(n_channels, c0 + chunk)) for c0 in range(0, n_channels, chunk)]

    def task(rng):
        c0, c1 = rng
        block = produce(c0, c1)
        _residual_cumsum(block, out[c0:c1], mean[c0:c1])

    def on_done(i, n):                               # i chunks of n finished
        if progress_cb is not None:
            progress_cb(n_channels if i == n else min(n_channels, i * chunk), n_channels)

    map_ordered(task, ranges, workers, on_done)
    return out, mean


def build_tables(maps, roughness, dr: int = 16, dv: int = 8, clusters: int = 8,
                 per_cluster_sat: bool = False, progress: bool = True, *, seed: int = 0,
                 iters: int = 30, max_step: float = 0.5, vis_eps: float = 1e-4,
                 fast_visibility: bool = True, d_rank: int = 0, parallax: bool = False,
                 workers: int | None = None, label: str = "") -> MultiscaleTables:
    """Build every table of :class:`MultiscaleTables` for ``maps`` (a ClothMaps).

    roughness: fibre SGGX alpha in (0, 1], or a :class:`TableKey` (which then gives every
    build input below, from dr to parallax). dr: h bins per side of the directional SAT.
    dv: direction bins per side of the visibility and parallax tables. clusters: k of the
    visibility k-means (<= 127). per_cluster_sat: also build d_sat_cluster (clusters x the
    memory of d_sat). progress: progress lines on stderr. seed, iters: k-means.
    max_step: march step (texels). vis_eps: hit tolerance (texels). fast_visibility (default):
    march only the first 16+ texels of each visibility ray sample by sample, then blocks (see
    :func:`mscloth.precompute._march.escape_mask`; 512^2 plain weave: front 2.6 s instead of
    6.7 s, back 2.3 s instead of 15.5 s, 0.001 % / 0.02 % of entries differ); False: every
    sample of every ray (docs/performance-log.md L12). d_rank: 0 for the full directional SAT (dr*dr
    channels), K > 0 for its rank-K compression (K channels plus a dr*dr x K basis, see
    :func:`_d_basis`).
    parallax: also build the parallax table (a quarter of the build time and, at dr = 32, more
    memory than everything but the directional SAT; only the ``parallax`` option reads it).
    workers: threads (default: CPUs, <= 8). label: whose tables these are (e.g. a cloth's id
    and pattern), at the start of every progress line.
    """
    if isinstance(roughness, TableKey):
        params = roughness.as_params()  # the key's own inputs, not this function's defaults
    else:
        params = _params(roughness, dr=dr, dv=dv, clusters=clusters, per_cluster_sat=per_cluster_sat,
                         seed=seed, iters=iters, max_step=max_step, vis_eps=vis_eps,
                         fast_visibility=fast_visibility, d_rank=d_rank, parallax=parallax)
    # Everything below reads the validated inputs only.
    dr, dv, clusters, seed, iters = (params[n] for n in ("dr", "dv", "clusters", "seed", "iters"))
    per_cluster_sat = params["per_cluster_sat"]
    key = table_key(maps, params)
    prog = Progress(progress, label=label)
    t_start = time.perf_counter()
    H, W = (int(s) for s in maps.tangent.shape[:2])
    N = H * W
    alpha = params["roughness"]
    pitch = texel_pitch((H, W), getattr(maps, "meta", None))
    tangent = np.asarray(maps.tangent, dtype=np.float64).reshape(N, 3)
    tangent = tangent / np.linalg.norm(tangent, axis=1, keepdims=True)
    tangent_t = np.ascontiguousarray(tangent.T)      # (3, N) for the bin x texel products
    gap = np.asarray(maps.gap, dtype=np.float64).reshape(N)
    height = np.asarray(maps.height, dtype=np.float64)
    timings = {}

    g2 = gap.reshape(H, W)

    # Visibility, front and back (first: the directional SAT's pass also sums D per cluster).
    t0 = time.perf_counter()
    vis_kw = dict(pitch=pitch, max_step=params["max_step"], eps=params["vis_eps"],
                  workers=workers, fast=params["fast_visibility"])
    visibility = visibility_table(
        height, dv, progress=lambda d, n: prog("visibility (front)", d, n, "directions"),
        **vis_kw)
    visibility_back = visibility_table(
        height, dv, back=True,
        progress=lambda d, n: prog("visibility (back)", d, n, "directions"), **vis_kw)
    timings["visibility"] = time.perf_counter() - t0

    # Clusters of the front visibility.
    t0 = time.perf_counter()
    prog.note(f"k-means of visibility ({clusters} clusters)")
    cluster_id, cluster_vis = cluster_visibility(visibility, g2, k=clusters, seed=seed,
                                                 iters=iters)
    ids = cluster_id.astype(np.int64).reshape(N)
    back_f = visibility_back.reshape(N, -1)
    cluster_vis_back = np.empty_like(cluster_vis)
    yarn = ids >= 0
    overall_back = (back_f[yarn].mean(axis=0) / 255.0) if yarn.any() else np.ones(dv * dv)
    for c in range(clusters):
        sel = ids == c
        cluster_vis_back[c] = (back_f[sel].mean(axis=0, dtype=np.float64) / 255.0
                               if sel.any() else overall_back)
    onehot = np.stack([(ids == c).reshape(H, W) * g2 for c in range(clusters)]).astype(np.float64)
    cluster_sat, cluster_mean = build_sat(onehot)
    # Each cluster's texels as columns: D * gap of a chunk of bins times this gives the
    # clusters' sums (see d_cluster_tile).
    cluster_columns = (ids[:, None] == np.arange(clusters)[None, :]).astype(np.float64)
    timings["clusters"] = time.perf_counter() - t0

    # Directional SAT of D(h_b, t) * gap.
    t0 = time.perf_counter()
    bins = bin_centres(dr)
    B = len(bins)
    chunk = max(1, min(B, _D_CHUNK_BYTES // (8 * N)))

    def produce_d(c0, c1, mask=None):
        weight = gap if mask is None else gap * mask
        c = _d_times_gap(bins[c0:c1], tangent_t, weight, alpha)
        if mask is None:  # each chunk writes its own rows: safe from worker threads
            d_cluster_sum[c0:c1] = c @ cluster_columns
        return c.reshape(c1 - c0, H, W)

    d_cluster_sum = np.zeros((B, clusters))
    K = params["d_rank"]
    d_basis = coef = None
    if K:
        d_basis = _d_basis(bins, tangent, gap, alpha, K, seed)
        # The coefficients basis^T D, a slab of texels at a time over every bin: one
        # (K x B) x (B x slab) product per slab. Bins at a time over every texel (as the full
        # table goes) made each product a rank-4 update of the whole (K x N) coefficient
        # array: 15 s of memory traffic at 512^2, dr = 32 and K = 64; 5 s this way, basis
        # included.
        coef = np.empty((K, N))
        slab = max(1, _D_CHUNK_BYTES // (8 * B))
        slabs = [(t0, min(N, t0 + slab)) for t0 in range(0, N, slab)]

        def coefficients(texels):
            t0, t1 = texels
            d = _d_times_gap(bins, tangent_t[:, t0:t1], gap[t0:t1], alpha)
            coef[:, t0:t1] = d_basis.T @ d  # each slab writes its own columns
            return d @ cluster_columns[t0:t1]

        parts = map_ordered(coefficients, slabs, workers,
                            lambda d, n: prog("building rank-%d directional SAT" % K, d, n, "texel slabs"))
        d_cluster_sum = np.sum(parts, axis=0)
        d_sat, d_mean = build_sat(coef.reshape(K, H, W))
        d_basis = d_basis.astype(np.float32)
    else:
        d_sat, d_mean = _sat_parallel(
            B, H, W, produce_d, workers,
            lambda d, n: prog("building directional SAT", d, n, "bins"), chunk)
    timings["d_sat"] = time.perf_counter() - t0
    # Mean of D * gap over each cluster's yarn, per bin (clusters of no yarn: the tile's).
    cluster_yarn = onehot.reshape(clusters, N).sum(axis=1)
    tile_mean = d_cluster_sum.sum(axis=1, keepdims=True) / max(float(gap.sum()), 1e-30)
    d_cluster_tile = np.where(cluster_yarn > 0.0, d_cluster_sum / np.maximum(cluster_yarn, 1e-30), tile_mean)

    # Small SATs.
    t0 = time.perf_counter()
    gap_sat, gap_mean = build_sat(g2[None])
    albedo = np.asarray(maps.albedo, dtype=np.float64) * g2[..., None]
    albedo_sat, albedo_mean = build_sat(np.moveaxis(albedo, -1, 0))
    tt = tangent.reshape(H, W, 3)
    comps = [(0, 0), (0, 1), (0, 2), (1, 1), (1, 2), (2, 2)]
    moment = np.stack([tt[..., i] * tt[..., j] * g2 for i, j in comps])
    moment_sat, moment_mean = build_sat(moment)
    timings["small_sats"] = time.perf_counter() - t0

    d_sat_cluster = d_cluster_mean = None
    if per_cluster_sat and K:
        # The basis is per bin, the cluster mask per texel: the coefficients just get masked.
        t0 = time.perf_counter()
        d_sat_cluster = np.empty((clusters, K, H + 1, W + 1), dtype=np.float32)
        d_cluster_mean = np.empty((clusters, K), dtype=np.float64)
        for c in range(clusters):
            mask = (ids == c).astype(np.float64)
            d_sat_cluster[c], d_cluster_mean[c] = build_sat((coef * mask).reshape(K, H, W))
            prog("building rank-%d directional SATs of the clusters" % K, c + 1, clusters, "clusters")
        timings["d_sat_cluster"] = time.perf_counter() - t0
    elif per_cluster_sat:
        t0 = time.perf_counter()
        d_sat_cluster = np.empty((clusters, B, H + 1, W + 1), dtype=np.float32)
        d_cluster_mean = np.empty((clusters, B), dtype=np.float64)
        for c in range(clusters):
            mask = (ids == c).astype(np.float64)
            _sat_parallel(
                B, H, W, lambda c0, c1, mask=mask: produce_d(c0, c1, mask), workers,
                lambda d, n, c=c: prog(f"building directional SAT of cluster {c + 1}/{clusters}",
                                       d, n, "bins"), chunk,
                out=d_sat_cluster[c], mean=d_cluster_mean[c])
        timings["d_sat_cluster"] = time.perf_counter() - t0

    # Parallax.
    parallax = None
    if params["parallax"]:
        t0 = time.perf_counter()
        parallax = parallax_table(height, dv, pitch=pitch, max_step=params["max_step"],
                                  workers=workers,
                                  progress=lambda d, n: prog("parallax", d, n, "directions"))
        timings["parallax"] = time.perf_counter() - t0

    total = time.perf_counter() - t_start
    info = dict(params)
    info.update({
        "format_version": FORMAT_VERSION,
        "shape": [H, W],
        "pitch": [pitch[0], pitch[1]],
        "height_range": [float(height.min()), float(height.max())],
        "build_seconds": total,
        "timings": timings,
    })
    tables = MultiscaleTables(
        d_sat=d_sat, d_mean=d_mean, gap_sat=gap_sat, gap_mean=gap_mean,
        albedo_sat=albedo_sat, albedo_mean=albedo_mean, moment_sat=moment_sat,
        moment_mean=moment_mean, cluster_sat=cluster_sat, cluster_mean=cluster_mean,
        visibility=visibility, visibility_back=visibility_back, cluster_id=cluster_id,
        cluster_vis=cluster_vis.astype(np.float32),
        cluster_vis_back=cluster_vis_back.astype(np.float32), parallax=parallax,
        d_sat_cluster=d_sat_cluster, d_cluster_mean=d_cluster_mean, d_basis=d_basis,
        d_cluster_tile=d_cluster_tile.astype(np.float32), params=info, key=key)
    mib = sum(tables.memory_report().values()) / 2**20
    prog.note(f"tables built in {total:.2f} s, {mib:.1f} MiB")
    return tables


def _d_times_gap(bins, tangent_t, weight, alpha):
    """D(h_b, t(p)) weight(p) of a fibre SGGX of roughness ``alpha`` for the (c, 3) bin
    centres h_b and the (3, n) tangents: (c, n), float64. Explicit sums over the three
    components beat a k = 3 BLAS product by ~5x here."""
    c = np.multiply(bins[:, 0, None], tangent_t[0])
    c += bins[:, 1, None] * tangent_t[1]
    c += bins[:, 2, None] * tangent_t[2]
    fibre_ndf_of_cosine(c, alpha, out=c)
    c *= weight
    return c


def _d_basis(bins, tangent, gap, alpha, K, seed, samples=8192):
    """(B, K) orthonormal basis of D(h_b, t(p)) gap(p) over the B bins: the top-K
    eigenvectors of its Gram matrix over a random sample of the tile's yarn texels (PCA
    without centring). D of a fibre SGGX is smooth in (h, t) over a 2-D family of
    tangents, so few components suffice: rank 64 keeps footprint means of a 192^2 twill at
    alpha = 0.3 within 0.4% (median over bins' maxima), at dr = 16 and 32 alike."""
    yarn = np.flatnonzero(gap > 0.0)
    if len(yarn) == 0:
        yarn = np.arange(len(gap))
    rng = np.random.default_rng(seed)
    pick = yarn if len(yarn) <= samples else rng.choice(yarn, samples, replace=False)
    m = fibre_ndf_of_cosine(bins @ tangent[pick].T, alpha) * gap[pick]   # (B, S)
    _, vecs = np.linalg.eigh(m @ m.T)
    return np.ascontiguousarray(vecs[:, ::-1][:, :K])


# ---------------------------------------------------------------------------- expected shapes
def _expected_shapes(params: dict, shape) -> dict:
    H, W = shape
    B, D, k = params["dr"] ** 2, params["dv"] ** 2, params["clusters"]
    K = params.get("d_rank", 0)
    Bd = K or B  # channels of the directional SATs
    sat = (H + 1, W + 1)
    exp = {
        "d_sat": ((Bd,) + sat, "float32"), "d_mean": ((Bd,), "float64"),
        "gap_sat": ((1,) + sat, "float32"), "gap_mean": ((1,), "float64"),
        "albedo_sat": ((3,) + sat, "float32"), "albedo_mean": ((3,), "float64"),
        "moment_sat": ((6,) + sat, "float32"), "moment_mean": ((6,), "float64"),
        "cluster_sat": ((k,) + sat, "float32"), "cluster_mean": ((k,), "float64"),
        "visibility": ((H, W, D), "uint8"), "visibility_back": ((H, W, D), "uint8"),
        "cluster_id": ((H, W), "int8"), "cluster_vis": ((k, D), "float32"),
        "cluster_vis_back": ((k, D), "float32"),
    }
    if params.get("parallax"):
        exp["parallax"] = ((H, W, D, 2), "float32")
    if params["per_cluster_sat"]:
        exp["d_sat_cluster"] = ((k, Bd) + sat, "float32")
        exp["d_cluster_mean"] = ((k, Bd), "float64")
    if K:
        exp["d_basis"] = ((B, K), "float32")
    exp["d_cluster_tile"] = ((B, k), "float32")
    return exp


# ---------------------------------------------------------------------------- cache
def _sha256(a: np.ndarray) -> str:
    return hashlib.sha256(memoryview(np.ascontiguousarray(a)).cast("B")).hexdigest()


def cache_paths(cache_dir, key: str) -> tuple[Path, Path]:
    d = Path(cache_dir)
    return d / f"tables-{key}.npz", d / f"tables-{key}.json"


class _BadCache(Exception):
    def __init__(self, path, reason):
        super().__init__(f"{path}: {reason}")
        self.path, self.reason = path, reason


def save_tables(tables: MultiscaleTables, cache_dir) -> tuple[Path, Path]:
    """Write ``tables-<key>.npz`` then its ``.json`` sidecar (key, params, per-array shape,
    dtype and SHA-256), each atomically; the sidecar is written last, so a reader that finds
    it finds a complete .npz."""
    npz_path, json_path = cache_paths(cache_dir, tables.key)
    arrays = tables.arrays()
    atomic_write(npz_path, lambda f: np.savez(f, **arrays))
    side = {
        "format_version": FORMAT_VERSION,
        "key": tables.key,
        "params": tables.params,
        "arrays": {n: {"shape": list(a.shape), "dtype": a.dtype.str, "sha256": _sha256(a)}
                   for n, a in arrays.items()},
    }
    atomic_write(json_path, lambda f: f.write((json.dumps(side, indent=1) + "\n").encode()))
    return npz_path, json_path


def load_tables(cache_dir, key: str, params: dict, shape) -> MultiscaleTables:
    """Load and verify cached tables; raise _BadCache naming the file that is wrong."""
    npz_path, json_path = cache_paths(cache_dir, key)
    if not json_path.is_file():
        raise _BadCache(json_path, "sidecar missing (interrupted write?)")
    try:
        side = json.loads(json_path.read_text(encoding="utf-8"))
    except (OSError, UnicodeDecodeError, ValueError) as exc:
        raise _BadCache(json_path, f"unreadable ({exc})") from None
    if not isinstance(side, dict) or side.get("format_version") != FORMAT_VERSION \
            or side.get("key") != key or not isinstance(side.get("arrays"), dict):
        raise _BadCache(json_path, "wrong format version or key")
    expected = _expected_shapes(params, shape)
    listed = side["arrays"]
    if set(listed) != set(expected):
        raise _BadCache(json_path, f"lists arrays {sorted(listed)}, expected {sorted(expected)}")
    for name, (shp, dt) in expected.items():
        info = listed[name]
        try:
            ok = (isinstance(info, dict) and list(info.get("shape")) == list(shp)
                  and np.dtype(info.get("dtype")) == np.dtype(dt)
                  and isinstance(info.get("sha256"), str))
        except (TypeError, ValueError):
            ok = False
        if not ok:
            raise _BadCache(json_path, f"lists array {name!r} as {info!r}, expected shape "
                                       f"{list(shp)} {dt} with a sha256")
    arrays = {}
    try:
        with np.load(npz_path, allow_pickle=False) as npz:
            for name, (shp, dt) in expected.items():
                if name not in npz.files:
                    raise _BadCache(npz_path, f"has no array {name!r}")
                a = npz[name]
                info = listed[name]
                if tuple(a.shape) != tuple(shp) or a.dtype != np.dtype(dt):
                    raise _BadCache(npz_path, f"array {name!r} has shape {a.shape} {a.dtype}, "
                                              f"expected {shp} {dt}")
                if _sha256(a) != info["sha256"]:
                    raise _BadCache(npz_path, f"checksum mismatch in array {name!r}")
                arrays[name] = a
    except _BadCache:
        raise
    except (zipfile.BadZipFile, OSError, ValueError, EOFError, KeyError, TypeError,
            RuntimeError) as exc:
        raise _BadCache(npz_path, f"corrupt or truncated ({type(exc).__name__}: {exc})") from None
    stored = side.get("params") if isinstance(side.get("params"), dict) else {}
    return MultiscaleTables(**arrays, params=stored, key=key)


#: One table build at a time in a process. A build spreads its directions over every core
#: (:func:`map_ordered`), so two at once (Mitsuba's parallel loader constructing two cloths)
#: each took about three times as long as one alone (performance log L42). Builds hold no
#: Dr.Jit call, so a loader thread waiting here never holds up a kernel.
_BUILD_LOCK = threading.Lock()


def load_or_build(maps, roughness, cache_dir=None, **kw) -> MultiscaleTables:
    """Cached :func:`build_tables`: load ``tables-<key>`` from ``cache_dir`` (default
    $MSCLOTH_CACHE or ~/.cache/mscloth) when present and intact, else build and store.

    Any problem with a cached file (missing sidecar, truncated or corrupt .npz, checksum or
    shape mismatch) gives a warning naming the file, and the tables are rebuilt and rewritten;
    a bad cache is never used. If the cache cannot be written the tables are still returned
    (with a warning). ``roughness``: the fibre roughness with the other build inputs of
    :class:`TableKey` as keywords, or a TableKey. ``progress``, ``workers`` and ``label`` go
    to :func:`build_tables`.
    ``build_warning``: a warning about how the tables are built (e.g. the ``why`` of
    :func:`choose_direction_rank`), given only when they are built, not on every load of
    the cached tables. Threads build one at a time (``_BUILD_LOCK``); one that waited for
    tables another thread built meanwhile loads them.
    """
    build_kw = dict(kw)
    build_warning = build_kw.pop("build_warning", "")
    progress = build_kw.pop("progress", True)
    workers = build_kw.pop("workers", None)
    label = build_kw.pop("label", "")
    build_key = _table_key(roughness, **build_kw)
    params = build_key.as_params()
    key = table_key(maps, params)
    cache_dir = default_cache_dir() if cache_dir is None else Path(cache_dir)
    npz_path, json_path = cache_paths(cache_dir, key)
    shape = tuple(int(s) for s in maps.tangent.shape[:2])

    def cached():
        try:
            tables = load_tables(cache_dir, key, params, shape)
            mark_used(npz_path, json_path)  # for `mscloth cache --clear --older-than`
            return tables
        except _BadCache as bad:
            warnings.warn(f"mscloth: ignoring cached tables {bad.path}: {bad.reason}; "
                          "rebuilding", RuntimeWarning, stacklevel=3)
            return None

    stored = npz_path.exists() or json_path.exists()
    tables = cached() if stored else None
    if tables is not None:
        return tables
    with _BUILD_LOCK:
        # Another thread may have built these very tables while this one waited (a bad
        # cache file found above is not read, and warned about, twice).
        if not stored and npz_path.exists() and (tables := cached()) is not None:
            return tables
        if build_warning:
            warnings.warn(f"mscloth: {build_warning}", RuntimeWarning, stacklevel=2)
        tables = build_tables(maps, build_key, progress=progress, workers=workers, label=label)
        try:
            save_tables(tables, cache_dir)
        except OSError as exc:
            warnings.warn(f"mscloth: cannot write table cache {npz_path}: {exc}", RuntimeWarning,
                          stacklevel=2)
    return tables
