"""How fine must the directional SAT's h bins be, and how far can rank-K compression go?

Issue 20 item 1. For a texel rectangle P (a footprint) the BSDF needs

    m(h) = (1/|P|) sum_{p in P} D(h . t(p)) I(p)

(D: the fibre-like SGGX of ``mscloth.precompute.tables.fibre_ndf_of_cosine``, t the tangent
map, I the gap map; gap texels count in |P| with I = 0). The tables store m at the centres of
dr x dr bins (``direction_bins``) and the BSDF interpolates bilinearly between the four bins
around h, optionally from a rank-K PCA of the bins (``tables._d_basis``). This script measures
the relative error of that lookup against the exact m(h), and what it costs.

Error metric (one footprint, a set of half vectors h_1..h_n drawn from a distribution q):

    E = sqrt( sum_i (m_approx(h_i) - m(h_i))^2 / sum_i m(h_i)^2 )

with two choices of q: ``U``: h uniform in solid angle over the upper hemisphere (E is then
the L2 error of m over the hemisphere relative to m's L2 norm); ``M``: h drawn with density
proportional to m(h) itself (a texel p of P with probability I(p), then h from D(. . t(p)),
folded to z >= 0), i.e. E^2 = int m (m_approx - m)^2 / int m^3: it weights the error by
where the footprint reflects. Per footprint size, the table reports the RMS of E over the
footprints (random integer positions on the periodic tile; the whole tile is one footprint).

Everything is computed directly (no SAT): the bin values are the footprint means at the bin
centres, evaluated only for the bins the sampled h need (bilinear: 4 per h).

Also: bicubic (Catmull-Rom, 16 bins) reads (``--interp bicubic``); two alternatives
(``--moments J``: per tangent-cluster moments, no h bins; ``--cv DR K``: noise of the unbiased
estimator that uses the rank-K table as a control variate); build cost of the rank-K table
(``--time-build DR K``, ``--build-tables DR K``).

Run ``python bench/direction_binning.py --help``; results are appended to a JSON file
(``--out``) that ``--summary`` / ``--table`` turn into the markdown tables of
bench/DIRECTION_BINNING.md (which lists the commands behind every number).
"""
from __future__ import annotations

import argparse
import json
import math
import os
import sys
import time
from pathlib import Path

import numpy as np

from mscloth.maps.generate import generate_maps
from mscloth.patterns.named import named_pattern
from mscloth.precompute.direction_bins import (bilinear_bins, bin_centres, fold_upper,
                                               hemisphere_to_square, square_to_hemisphere)

#: name -> (pattern, generate_maps parameters). ``satin``: a dense warp-faced 8-shaft satin
#: with 1% gaps; ``twill``: the package's default pattern with its default yarn widths.
PATTERNS = {
    "satin": ("satin-8-3", {"gap_fraction": 0.01}),
    "twill": ("twill-2-1", {}),
}

# Texel chunk x direction chunk of one float32 block (~1 MiB: stays in cache).
_H_CHUNK, _T_CHUNK = 128, 2048


# ---------------------------------------------------------------------------- inputs
def make_maps(name: str, resolution: int = 512):
    """(tangent (H, W, 3) float64 unit, gap (H, W) float64) of the named test pattern."""
    pattern, kw = PATTERNS[name]
    maps = generate_maps(named_pattern(pattern), resolution, **kw)
    t = np.asarray(maps.tangent, dtype=np.float64)
    t = t / np.linalg.norm(t, axis=-1, keepdims=True)
    return t, np.asarray(maps.gap, dtype=np.float64)


def footprint_texels(tangent, gap, x0: int, y0: int, size: int):
    """Tangents (n, 3) and weights (n,) of the yarn texels of the periodic size x size
    rectangle at (x0, y0), and the rectangle's texel count (the mean's denominator)."""
    H, W = gap.shape
    size_y, size_x = min(size, H), min(size, W)
    rows = (y0 + np.arange(size_y)) % H
    cols = (x0 + np.arange(size_x)) % W
    t = tangent[np.ix_(rows, cols)].reshape(-1, 3)
    w = gap[np.ix_(rows, cols)].reshape(-1)
    keep = w > 0
    return t[keep], w[keep], size_y * size_x


# ---------------------------------------------------------------------------- exact means

def _footprint_cases(tangent, gap, H, W, sizes, positions, rng, n_h, sampler, alpha):
    """Per random footprint with yarn: (size, x0, y0, tangents, weights, texel count, the
    half-vector sets {"U", "M"}, their exact means, the start time)."""
    for size, x0, y0 in footprints(H, W, sizes, positions, rng):
        t0 = time.perf_counter()
        t, w, count = footprint_texels(tangent, gap, x0, y0, size)
        if len(t) == 0:
            continue
        hsets = {"U": sample_h_uniform(n_h, rng), "M": sample_h_by_m(n_h, t, w, sampler, rng)}
        exact = {k: ndf_means(h, t, w, count, alpha) for k, h in hsets.items()}
        yield size, x0, y0, t, w, count, hsets, exact, t0

def ndf_means(dirs, t, w, count, alpha: float) -> np.ndarray:
    """m(dirs) = sum_p D(dirs . t_p) w_p / count for unit dirs (n, 3): (n,) float64.

    float32 blocks of 128 directions x 2048 texels (about 1e9 texel-directions/s on one core
    here), sums in float64; agrees with float64 to ~1e-7 relative."""
    dirs = np.asarray(dirs, dtype=np.float64).reshape(-1, 3)
    out = np.zeros(len(dirs))
    if len(t) == 0:
        return out
    a2 = np.float32(alpha * alpha)
    # (c^2 (1 - a^2) + a^2)^2 = ((c sqrt(1 - a^2))^2 + a^2)^2: scale h once.
    hs = (dirs * math.sqrt(1.0 - alpha * alpha)).astype(np.float32)
    tt = np.ascontiguousarray(np.asarray(t, dtype=np.float32).T)
    ww = np.asarray(w, dtype=np.float32)
    for i in range(0, len(hs), _H_CHUNK):
        acc = np.zeros(min(_H_CHUNK, len(hs) - i))
        for j in range(0, tt.shape[1], _T_CHUNK):
            c = hs[i:i + _H_CHUNK] @ tt[:, j:j + _T_CHUNK]
            np.square(c, out=c)
            c += a2
            np.square(c, out=c)
            np.reciprocal(c, out=c)
            acc += c @ ww[j:j + _T_CHUNK]
        out[i:i + len(acc)] = acc
    return out * (alpha ** 3 / math.pi / count)


class CosineSampler:
    """Cosines c = h . t distributed on the sphere with density proportional to D(c)."""

    def __init__(self, alpha: float, n: int = 400001):
        c = np.linspace(-1.0, 1.0, n)
        d = 1.0 / np.square(c * c * (1 - alpha * alpha) + alpha * alpha)
        cdf = np.concatenate([[0.0], np.cumsum(0.5 * (d[1:] + d[:-1]) * np.diff(c))])
        self.c, self.cdf = c, cdf / cdf[-1]

    def __call__(self, u):
        return np.interp(u, self.cdf, self.c)


def sample_h_uniform(n: int, rng) -> np.ndarray:
    """n directions uniform in solid angle over the upper hemisphere."""
    return square_to_hemisphere(rng.random((n, 2)))


def sample_h_by_m(n: int, t, w, sampler: CosineSampler, rng) -> np.ndarray:
    """n directions with density proportional to m(h) (folded to the upper hemisphere)."""
    p = rng.choice(len(t), size=n, p=w / w.sum())
    tp = t[p]
    c = sampler(rng.random(n))
    phi = 2 * np.pi * rng.random(n)
    # Orthonormal frame around each tangent.
    helper = np.where(np.abs(tp[:, 2:3]) < 0.9, [[0.0, 0.0, 1.0]], [[1.0, 0.0, 0.0]])
    u = np.cross(tp, helper)
    u /= np.linalg.norm(u, axis=1, keepdims=True)
    v = np.cross(tp, u)
    s = np.sqrt(np.maximum(0.0, 1.0 - c * c))[:, None]
    h = c[:, None] * tp + s * (np.cos(phi)[:, None] * u + np.sin(phi)[:, None] * v)
    return fold_upper(h / np.linalg.norm(h, axis=1, keepdims=True))


# ---------------------------------------------------------------------------- interpolation
def bicubic_bins(p_square, n: int):
    """16 bins and Catmull-Rom weights around square coordinates (..., 2), clamped at the
    edges like :func:`direction_bins.bilinear_bins` (an alternative to bilinear reads)."""
    p = np.asarray(p_square, dtype=np.float64)
    x = p * n - 0.5
    i0 = np.floor(x)
    f = x - i0
    i0 = i0.astype(np.int64)

    def cr(f):  # Catmull-Rom weights of taps -1, 0, 1, 2
        f2, f3 = f * f, f * f * f
        return np.stack([-0.5 * f3 + f2 - 0.5 * f, 1.5 * f3 - 2.5 * f2 + 1.0,
                         -1.5 * f3 + 2.0 * f2 + 0.5 * f, 0.5 * f3 - 0.5 * f2], axis=-1)

    wa, wb = cr(f[..., 0]), cr(f[..., 1])
    ia = np.clip(i0[..., 0, None] + np.arange(-1, 3), 0, n - 1)
    ib = np.clip(i0[..., 1, None] + np.arange(-1, 3), 0, n - 1)
    idx = (ib[..., :, None] * n + ia[..., None, :]).reshape(*p.shape[:-1], 16)
    wts = (wb[..., :, None] * wa[..., None, :]).reshape(*p.shape[:-1], 16)
    return idx, wts


def lookup_weights(h, dr: int, interp: str = "bilinear"):
    p = hemisphere_to_square(fold_upper(h))
    return bilinear_bins(p, dr) if interp == "bilinear" else bicubic_bins(p, dr)


def binned_values(h, t, w, count, alpha, dr, interp="bilinear") -> np.ndarray:
    """The full table's lookup at h: bin-centre footprint means, interpolated."""
    idx, wts = lookup_weights(h, dr, interp)
    used, inv = np.unique(idx, return_inverse=True)
    vals = ndf_means(bin_centres(dr)[used], t, w, count, alpha)
    return np.sum(vals[inv.reshape(idx.shape)] * wts, axis=-1)


def interpolate(values, h, dr, interp="bilinear") -> np.ndarray:
    """Interpolate per-bin values (B,) at h."""
    idx, wts = lookup_weights(h, dr, interp)
    return np.sum(values[idx] * wts, axis=-1)


# ---------------------------------------------------------------------------- PCA basis
def sample_texels(tangent, gap, samples=8192, seed=0):
    """The texels ``tables._d_basis`` samples: (tangents (S, 3), gaps (S,))."""
    t = tangent.reshape(-1, 3)
    g = gap.reshape(-1)
    yarn = np.flatnonzero(g > 0.0)
    if len(yarn) == 0:
        yarn = np.arange(len(g))
    rng = np.random.default_rng(seed)
    pick = yarn if len(yarn) <= samples else rng.choice(yarn, samples, replace=False)
    return t[pick], g[pick]


def pca_basis(tangent, gap, alpha, dr, K, seed=0, method="auto"):
    """(B, K) orthonormal basis of D(h_b . t) I over the bins, from the texels
    ``tables._d_basis`` samples. ``eigh``: its method (top eigenvectors of the B x B Gram
    matrix, O(B^3)); ``rsvd``: randomized SVD of the B x S sample matrix (the same subspace
    to ~1e-6 for these spectra, O(B S K)); ``auto``: eigh up to B = 4096.
    Returns (basis, seconds, method used)."""
    t0 = time.perf_counter()
    bins = bin_centres(dr)
    B = len(bins)
    ts, gs = sample_texels(tangent, gap, seed=seed)
    a = alpha
    m = (a ** 3 / math.pi) / np.square(np.square(bins @ ts.T) * (1 - a * a) + a * a) * gs  # (B, S)
    if method == "auto":
        method = "eigh" if B <= 4096 else "rsvd"
    if method == "eigh":
        _, vecs = np.linalg.eigh(m @ m.T)
        basis = np.ascontiguousarray(vecs[:, ::-1][:, :K])
    else:
        rng = np.random.default_rng(seed + 1)
        m = m.astype(np.float32)  # the products in float32: 2x faster, ample for a basis
        q, _ = np.linalg.qr(m @ rng.standard_normal((m.shape[1], K + 32)).astype(np.float32))
        for _ in range(3):  # power iterations
            q, _ = np.linalg.qr(m @ (m.T @ q))
        u, _, _ = np.linalg.svd((q.T @ m).astype(np.float64), full_matrices=False)
        basis = np.ascontiguousarray((q.astype(np.float64) @ u)[:, :K])
    return basis, time.perf_counter() - t0, method


# ---------------------------------------------------------------------------- errors
def rel_err(approx, exact) -> float:
    return float(np.sqrt(np.sum((approx - exact) ** 2) / max(np.sum(exact ** 2), 1e-300)))


def footprints(H, W, sizes, positions, rng):
    """[(size, x0, y0)]: ``positions`` random integer positions per size; one whole tile."""
    out = []
    for s in sizes:
        if s >= min(H, W):
            out.append((max(H, W), 0, 0))
        else:
            for _ in range(positions):
                out.append((s, int(rng.integers(W)), int(rng.integers(H))))
    return out


def measure(pattern, alpha, drs, ranks=(), rank_drs=(), interps=("bilinear",), sizes=(16, 64, 512),
            positions=6, n_h=2048, resolution=512, seed=0, log=print, basis_method="auto"):
    """Error records for one pattern and roughness (see the module docstring)."""
    tangent, gap = make_maps(pattern, resolution)
    H, W = gap.shape
    rng = np.random.default_rng(seed)
    sampler = CosineSampler(alpha)
    bases = {}
    for dr in rank_drs:
        if ranks:
            basis, secs, how = pca_basis(tangent, gap, alpha, dr, max(ranks), seed=0,
                                         method=basis_method)
            bases[dr] = basis
            log(f"  basis dr {dr} K {max(ranks)}: {secs:.1f} s ({how})")
    sums = {}  # key -> list of per-footprint squared errors
    for size, x0, y0, t, w, count, hsets, exact, t0 in _footprint_cases(
            tangent, gap, H, W, sizes, positions, rng, n_h, sampler, alpha):
        for interp in interps:
            for dr in drs:
                for k, h in hsets.items():
                    e = rel_err(binned_values(h, t, w, count, alpha, dr, interp), exact[k])
                    sums.setdefault((size, k, interp, dr, 0), []).append(e * e)
        for dr, basis in bases.items():
            full = ndf_means(bin_centres(dr), t, w, count, alpha)
            coef = basis.T @ full
            for K in ranks:
                approx = basis[:, :K] @ coef[:K]
                for interp in interps:
                    for k, h in hsets.items():
                        a_h = interpolate(approx, h, dr, interp)
                        e = rel_err(a_h, exact[k])
                        sums.setdefault((size, k, interp, dr, K), []).append(e * e)
                        # The rank-K table against the full one at the same dr (normalised by
                        # the exact m): the bias left when the residual texels' control
                        # variate is their full-binned D (bsdf/footprint_estimator.py).
                        f_h = interpolate(full, h, dr, interp)
                        e = np.sqrt(np.sum((a_h - f_h) ** 2) / max(np.sum(exact[k] ** 2), 1e-300))
                        sums.setdefault((size, k, interp + "-vs-full", dr, K), []).append(e * e)
        log(f"  footprint {size} at ({x0}, {y0}): {len(t)} yarn texels, {time.perf_counter() - t0:.1f} s")
    return [{"pattern": pattern, "alpha": alpha, "size": s, "metric": k, "interp": ip, "dr": dr,
             "K": K, "basis": basis_method if K else None, "footprints": len(v), "err": float(np.sqrt(np.mean(v))),
             "err_max": float(np.sqrt(np.max(v)))}
            for (s, k, ip, dr, K), v in sorted(sums.items())]


# ---------------------------------------------------------------------------- alternatives
def tangent_clusters(tangent, gap, J, iters=25, seed=0):
    """k-means of the yarn texels' tangents up to sign (features t t^T, so that the squared
    distance is 2 - 2 (a . b)^2). Returns (cluster id (H*W,) int, -1 in gaps; axis (J, 3):
    each cluster's principal direction)."""
    t = tangent.reshape(-1, 3)
    g = gap.reshape(-1)
    iu = [(0, 0), (1, 1), (2, 2), (0, 1), (0, 2), (1, 2)]
    scale = np.array([1, 1, 1, math.sqrt(2), math.sqrt(2), math.sqrt(2)])
    f = np.stack([t[:, i] * t[:, j] for i, j in iu], axis=1) * scale
    yarn = np.flatnonzero(g > 0)
    rng = np.random.default_rng(seed)
    fy = f[yarn]
    cent = fy[rng.choice(len(fy), J, replace=False)]
    for _ in range(iters):
        d = (fy * fy).sum(1)[:, None] - 2 * fy @ cent.T + (cent * cent).sum(1)[None]
        lab = np.argmin(d, axis=1)
        for j in range(J):
            sel = lab == j
            cent[j] = fy[sel].mean(0) if sel.any() else fy[rng.integers(len(fy))]
    ids = np.full(len(g), -1)
    ids[yarn] = lab
    axis = np.empty((J, 3))
    for j in range(J):
        c = cent[j] / scale
        m = np.array([[c[0], c[3], c[4]], [c[3], c[1], c[5]], [c[4], c[5], c[2]]])
        axis[j] = np.linalg.eigh(m)[1][:, -1]
    return ids, axis


class GaussianNDFTable:
    """G(mu, sigma) = E[D(c)], c ~ Normal(mu, sigma^2): D of roughness alpha blurred by a
    Gaussian, tabulated on mu in [-1, 1] (step alpha/40) x log-spaced sigma, read bilinearly
    (the 2-D table a renderer would hold; exact D at sigma = 0)."""

    def __init__(self, alpha, n_sigma=96, sigma_min=None, sigma_max=1.0):
        self.alpha = alpha
        step = alpha / 40
        self.sigma_min = sigma_min or alpha / 50
        self.log_s = np.linspace(math.log(self.sigma_min), math.log(sigma_max), n_sigma)
        self.mu = np.arange(-1.0, 1.0 + step / 2, step)
        half = 5.0  # c grid reaching 4 sigma_max beyond |mu| <= 1
        n = int(round(2 * half / step))
        n = 1 << int(math.ceil(math.log2(n)))
        c = (np.arange(n) - n // 2) * step
        d = fibre_ndf(c, alpha)
        fd = np.fft.rfft(np.fft.ifftshift(d))
        freq = np.fft.rfftfreq(n, d=step)
        rows = []
        for ls in self.log_s:
            s = math.exp(ls)
            g = np.fft.irfft(fd * np.exp(-2 * (math.pi * freq * s) ** 2), n)
            g = np.fft.fftshift(g)
            rows.append(np.interp(self.mu, c, g))
        self.table = np.array(rows)  # (n_sigma, n_mu)
        self.step = step

    def __call__(self, mu, sigma):
        mu = np.clip(mu, -1.0, 1.0)
        x = (mu + 1.0) / self.step
        i = np.clip(np.floor(x).astype(np.int64), 0, len(self.mu) - 2)
        fx = x - i
        small = sigma <= self.sigma_min
        ls = np.log(np.maximum(sigma, self.sigma_min))
        y = (ls - self.log_s[0]) / (self.log_s[1] - self.log_s[0])
        j = np.clip(np.floor(y).astype(np.int64), 0, len(self.log_s) - 2)
        fy = np.clip(y - j, 0.0, 1.0)
        tb = self.table
        v = ((1 - fy) * ((1 - fx) * tb[j, i] + fx * tb[j, i + 1])
             + fy * ((1 - fx) * tb[j + 1, i] + fx * tb[j + 1, i + 1]))
        # Below sigma_min: D + D'' sigma^2 / 2 is exact enough; use D itself.
        return np.where(small, fibre_ndf(mu, self.alpha), v)


def fibre_ndf(c, alpha):
    a2 = alpha * alpha
    return (alpha ** 3 / math.pi) / np.square(np.square(c) * (1 - a2) + a2)


def cluster_moments(t, w, ids, axis, J):
    """Per cluster of one footprint's texels: weight (J,), sum of sign-aligned t (J, 3),
    sum of t t^T (J, 3, 3) -- 10 SAT channels per cluster."""
    s = np.sign(np.einsum("ij,ij->i", t, axis[ids]))
    s[s == 0] = 1
    ta = t * s[:, None]
    wsum = np.bincount(ids, weights=w, minlength=J)
    tsum = np.stack([np.bincount(ids, weights=w * ta[:, k], minlength=J) for k in range(3)], 1)
    q = np.stack([np.bincount(ids, weights=w * t[:, a] * t[:, b], minlength=J)
                  for a in range(3) for b in range(3)], 1).reshape(J, 3, 3)
    return wsum, tsum, q


def moments_values(h, moments, count, gtable, second=True):
    """m(h) ~ (1/count) sum_j w_j E[D(c)], c = h . t over cluster j's texels with its exact
    mean h . tbar_j and variance h^T Cov_j h (second=True; else sigma = 0)."""
    wsum, tsum, q = moments
    out = np.zeros(len(h))
    for j in np.flatnonzero(wsum > 0):
        tb = tsum[j] / wsum[j]
        mu = h @ tb
        if second:
            var = np.einsum("ni,ij,nj->n", h, q[j] / wsum[j], h) - mu * mu
            sigma = np.sqrt(np.maximum(var, 0.0))
        else:
            mu = h @ (tb / np.linalg.norm(tb))
            sigma = np.zeros_like(mu)
        out += wsum[j] * gtable(mu, sigma)
    return out / count


def measure_alternatives(pattern, alpha, cluster_counts=(8, 16, 24), cv=(), sizes=(16, 64, 512),
                         positions=6, n_h=2048, resolution=512, seed=0, cv_texels=1024, log=print):
    """Error records of the cluster-moment representation (method 'moments2': per tangent
    cluster weight, mean and second moment, 10 J channels; 'moments1': weight and mean
    only, 4 J channels), and for each (dr, K) in ``cv`` the per-sample noise of the unbiased
    residual estimator  table(h) + D(h, t_p) I_p - recon_p(h)  (p uniform in the footprint)
    next to the noise of a plain texel sample D(h, t_p) I_p (records 'cv_noise', 'plain_noise':
    sqrt(sum_h Var_p / sum_h m^2))."""
    tangent, gap = make_maps(pattern, resolution)
    H, W = gap.shape
    rng = np.random.default_rng(seed)
    sampler = CosineSampler(alpha)
    gtable = GaussianNDFTable(alpha)
    clus = {}
    for J in cluster_counts:
        t0 = time.perf_counter()
        clus[J] = tangent_clusters(tangent, gap, J)
        log(f"  {J} tangent clusters: {time.perf_counter() - t0:.1f} s")
    bases = {}  # K = 0: the full table (control variate: each texel's own binned D)
    for dr in sorted({dr for dr, _ in cv}):
        kmax = max(K for d, K in cv if d == dr)
        basis = pca_basis(tangent, gap, alpha, dr, kmax)[0] if kmax else None
        for d, K in cv:
            if d == dr:
                bases[(dr, K)] = basis[:, :K] if K else None
    sums = {}
    flat_ids = {J: c[0].reshape(H, W) for J, c in clus.items()}
    for size, x0, y0, t, w, count, hsets, exact, t0 in _footprint_cases(
            tangent, gap, H, W, sizes, positions, rng, n_h, sampler, alpha):
        rows = (y0 + np.arange(min(size, H))) % H
        cols = (x0 + np.arange(min(size, W))) % W
        for J, (ids, axis) in clus.items():
            fid = flat_ids[J][np.ix_(rows, cols)].reshape(-1)
            fid = fid[gap[np.ix_(rows, cols)].reshape(-1) > 0]
            mom = cluster_moments(t, w, fid, axis, J)
            for second in (True, False):
                name = "moments2" if second else "moments1"
                for k, h in hsets.items():
                    e = rel_err(moments_values(h, mom, count, gtable, second), exact[k])
                    sums.setdefault((size, k, name, J, 10 * J if second else 4 * J), []).append(e * e)
        for (dr, K), basis in bases.items():
            # texels of the footprint, gaps included (weight 0), subsampled for the variance
            pick = np.arange(count) if count <= cv_texels else rng.choice(count, cv_texels, replace=False)
            tp = tangent[np.ix_(rows, cols)].reshape(-1, 3)[pick]
            wp = gap[np.ix_(rows, cols)].reshape(-1)[pick]
            dbins = _bin_matrix(bin_centres(dr), tp, wp, alpha)      # (B, n)
            recon = dbins if basis is None else basis @ (basis.T @ dbins)  # (B, n)
            for k, h in hsets.items():
                idx, wts = lookup_weights(h, dr)
                rp = np.einsum("hq,hqn->hn", wts, recon[idx])           # (n_h, n)
                dp = _bin_matrix(h, tp, wp, alpha)                      # (n_h, n)
                den = np.sum(exact[k] ** 2)
                sums.setdefault((size, k, "cv_noise", dr, K), []).append(
                    float(np.sum(np.var(dp - rp, axis=1)) / den))
                if (dr, K) == next(iter(bases)):
                    sums.setdefault((size, k, "plain_noise", 0, 0), []).append(
                        float(np.sum(np.var(dp, axis=1)) / den))
        log(f"  footprint {size} at ({x0}, {y0}): {time.perf_counter() - t0:.1f} s")
    return [{"pattern": pattern, "alpha": alpha, "size": s, "metric": k, "interp": "bilinear",
             "method": name, "dr": a if name in ("cv_noise", "plain_noise") else 0,
             "J": a if name.startswith("moments") else 0, "channels": b if name.startswith("moments") else 0,
             "K": b if name == "cv_noise" else 0, "footprints": len(v),
             "err": float(np.sqrt(np.mean(v))), "err_max": float(np.sqrt(np.max(v)))}
            for (s, k, name, a, b), v in sorted(sums.items())]


def _bin_matrix(dirs, t, w, alpha):
    """D(dirs_i . t_n) w_n: (len(dirs), len(t)) float64."""
    return fibre_ndf(dirs @ t.T, alpha) * w[None, :]


# ---------------------------------------------------------------------------- cost
def table_mib(resolution, dr, K=0):
    """Directional SAT memory (MiB) of a resolution^2 tile: full (K = 0) or rank K + basis."""
    per_channel = (resolution + 1) ** 2 * 4
    if K == 0:
        return dr * dr * per_channel / 2**20
    return (K * per_channel + dr * dr * K * 4) / 2**20


def time_rank_build(pattern, alpha, dr, K, resolution=512, basis_method="auto", workers=None,
                    float32=False):
    """Seconds of the rank-K directional SAT's steps at ``resolution``^2, done as
    ``tables.build_tables`` does them (basis, coefficient slabs on worker threads, SAT).
    ``float32``: the coefficients in float32 blocks instead (a possible speed-up)."""
    from mscloth.precompute._util import map_ordered
    from mscloth.precompute.summed_area import build_sat
    from mscloth.precompute.tables import _d_times_gap

    tangent, gap = make_maps(pattern, resolution)
    H, W = gap.shape
    N = H * W
    out = {}
    c0 = time.process_time()
    basis, out["basis_s"], out["basis_method"] = pca_basis(tangent, gap, alpha, dr, K,
                                                          method=basis_method)
    out["basis_cpu_s"] = time.process_time() - c0
    t = tangent.reshape(N, 3)
    tt = np.ascontiguousarray(t.T)
    g = gap.reshape(N)
    bins = bin_centres(dr)
    B = len(bins)
    t0, c0 = time.perf_counter(), time.process_time()
    coef = np.empty((K, N), dtype=np.float32 if float32 else np.float64)
    slab = max(1, (8 << 20) // (8 * B))
    slabs = [(a, min(N, a + slab)) for a in range(0, N, slab)]
    if float32:
        b32 = (bins * math.sqrt(1 - alpha * alpha)).astype(np.float32)
        u32 = np.ascontiguousarray(basis.T.astype(np.float32) * np.float32(alpha ** 3 / math.pi))
        a2 = np.float32(alpha * alpha)

        def coefficients(r):
            a, b = r
            c = b32 @ tt[:, a:b].astype(np.float32)
            np.square(c, out=c)
            c += a2
            np.square(c, out=c)
            np.reciprocal(c, out=c)
            c *= g[a:b].astype(np.float32)
            coef[:, a:b] = u32 @ c
    else:
        def coefficients(r):
            a, b = r
            d = _d_times_gap(bins, tt[:, a:b], g[a:b], alpha)
            coef[:, a:b] = basis.T @ d
    map_ordered(coefficients, slabs, workers)
    out["coef_s"] = time.perf_counter() - t0
    out["coef_cpu_s"] = time.process_time() - c0
    t0 = time.perf_counter()
    build_sat(coef.reshape(K, H, W).astype(np.float64))
    out["sat_s"] = time.perf_counter() - t0
    out["total_s"] = out["basis_s"] + out["coef_s"] + out["sat_s"]
    out.update(pattern=pattern, alpha=alpha, dr=dr, K=K, resolution=resolution, float32=float32,
               mib=table_mib(resolution, dr, K))
    return out


def time_build_tables(pattern, alpha, dr, K, resolution=256):
    """tables.build_tables(..., d_rank=K) at ``resolution``^2: (total seconds, timings, MiB)."""
    from mscloth.precompute.tables import build_tables

    pat, kw = PATTERNS[pattern]
    maps = generate_maps(named_pattern(pat), resolution, **kw)
    tab = build_tables(maps, alpha, dr=dr, d_rank=K, progress=False)
    mib = sum(tab.memory_report().values()) / 2**20
    return {"pattern": pattern, "alpha": alpha, "dr": dr, "K": K, "resolution": resolution,
            "build_s": tab.params["build_seconds"], "timings": tab.params["timings"], "mib": mib,
            "d_sat_mib": tab.d_sat.nbytes / 2**20}


# ---------------------------------------------------------------------------- report
def markdown_tables(records) -> str:
    """Error records -> one markdown table per (pattern, metric, interp): rows (alpha, dr, K),
    columns footprint sizes, values in %."""
    out = []
    alts = [r for r in records if "method" in r]
    records = [r for r in records if "method" not in r]
    keyf = lambda r: (r["pattern"], r["metric"], r["interp"])
    for key in sorted({keyf(r) for r in records}):
        rs = [r for r in records if keyf(r) == key]
        sizes = sorted({r["size"] for r in rs})
        out.append(f"\n{key[0]}, h ~ {key[1]}, {key[2]}: relative RMS error in % (RMS over footprints)\n")
        out.append("| alpha | dr | K | " + " | ".join(f"{s}x{s}" for s in sizes) + " |")
        out.append("|---|---|---|" + "---|" * len(sizes))
        rows = sorted({(r["alpha"], r["dr"], r["K"]) for r in rs})
        for a, dr, K in rows:
            cells = []
            for s in sizes:
                v = [r["err"] for r in rs if (r["alpha"], r["dr"], r["K"], r["size"]) == (a, dr, K, s)]
                cells.append(f"{100 * v[0]:.2f}" if v else "")
            out.append(f"| {a:g} | {dr} | {K or 'full'} | " + " | ".join(cells) + " |")
    if alts:
        out.append(alternatives_table(alts))
    return "\n".join(out)


def alternatives_table(records) -> str:
    """Records of :func:`measure_alternatives` -> markdown (values in %)."""
    out = []
    keyf = lambda r: (r["pattern"], r["metric"])
    for key in sorted({keyf(r) for r in records}):
        rs = [r for r in records if keyf(r) == key]
        sizes = sorted({r["size"] for r in rs})
        out.append(f"\n{key[0]}, h ~ {key[1]}: alternatives, % (moments: relative RMS error; "
                   "noise: per-sample relative std)\n")
        out.append("| alpha | method | J / dr | channels / K | " + " | ".join(f"{s}x{s}" for s in sizes) + " |")
        out.append("|---|---|---|---|" + "---|" * len(sizes))
        rows = sorted({(r["alpha"], r["method"], r["J"] or r["dr"], r["channels"] or r["K"]) for r in rs})
        for a, m, x, y in rows:
            cells = []
            for s in sizes:
                v = [r["err"] for r in rs if (r["alpha"], r["method"], r["J"] or r["dr"],
                                              r["channels"] or r["K"], r["size"]) == (a, m, x, y, s)]
                cells.append(f"{100 * v[0]:.2f}" if v else "")
            out.append(f"| {a:g} | {m} | {x} | {y} | " + " | ".join(cells) + " |")
    return "\n".join(out)


def summary_tables(records) -> str:
    """Compact markdown: one table per interpolation (full bins and rank K), rows (alpha, dr,
    K), columns pattern x footprint size, cells "M / U" errors in %."""
    recs = [r for r in records if "err" in r and "method" not in r]
    pats = sorted({r["pattern"] for r in recs}, key=lambda p: p != "satin")
    sizes = sorted({r["size"] for r in recs})
    cell = {(r["pattern"], r["alpha"], r["dr"], r["K"], r["interp"], r["size"], r["metric"]): r["err"]
            for r in recs}
    out = []
    for interp in ("bilinear", "bicubic", "bilinear-vs-full"):
        rows = sorted({(r["alpha"], r["K"] > 0, r["dr"], r["K"]) for r in recs if r["interp"] == interp})
        if not rows:
            continue
        out.append(f"\n{interp} interpolation: relative RMS error in %, h ~ m / h uniform\n")
        out.append("| alpha | dr | K | " + " | ".join(f"{p} {s}x{s}" if s < 512 else f"{p} tile"
                                                    for p in pats for s in sizes) + " |")
        out.append("|---|---|---|" + "---|" * (len(pats) * len(sizes)))
        for a, _, dr, K in rows:
            cells = []
            for p in pats:
                for s in sizes:
                    m = cell.get((p, a, dr, K, interp, s, "M"))
                    u = cell.get((p, a, dr, K, interp, s, "U"))
                    cells.append("" if m is None else f"{100 * m:.2f} / {100 * u:.2f}")
            out.append(f"| {a:g} | {dr} | {K or 'full'} | " + " | ".join(cells) + " |")
    return "\n".join(out)


def _append(path, recs):
    path = Path(path)
    old = json.loads(path.read_text()) if path.exists() else []
    path.write_text(json.dumps(old + recs, indent=0))


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--pattern", choices=sorted(PATTERNS), default="satin")
    ap.add_argument("--alpha", type=float, nargs="+", default=[0.1])
    ap.add_argument("--dr", type=int, nargs="*", default=[16, 32, 48, 64, 96, 128])
    ap.add_argument("--ranks", type=int, nargs="*", default=[], help="rank-K reconstructions")
    ap.add_argument("--rank-dr", type=int, nargs="*", default=[], help="dr values of the rank-K runs")
    ap.add_argument("--basis-method", default="auto", choices=["auto", "eigh", "rsvd"],
                    help="PCA basis: eigh as tables._d_basis (auto: up to 4096 bins), rsvd")
    ap.add_argument("--interp", nargs="+", default=["bilinear"], choices=["bilinear", "bicubic"])
    ap.add_argument("--sizes", type=int, nargs="+", default=[16, 64, 512])
    ap.add_argument("--positions", type=int, default=6, help="random footprints per size")
    ap.add_argument("--nh", type=int, default=2048, help="h samples per footprint and metric")
    ap.add_argument("--resolution", type=int, default=512)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--out", default="bench/direction_binning.json")
    ap.add_argument("--time-build", nargs=2, type=int, metavar=("DR", "K"), action="append",
                    help="time the rank-K directional SAT's steps at --resolution (repeatable)")
    ap.add_argument("--workers", type=int, default=None, help="--time-build: worker threads")
    ap.add_argument("--float32", action="store_true", help="--time-build: float32 coefficients")
    ap.add_argument("--build-tables", nargs=2, type=int, metavar=("DR", "K"),
                    help="time tables.build_tables at --resolution with d_rank K")
    ap.add_argument("--moments", type=int, nargs="*", default=None, metavar="J",
                    help="alternatives: cluster-moment representation with J tangent clusters")
    ap.add_argument("--cv", nargs=2, type=int, metavar=("DR", "K"), action="append", default=[],
                    help="alternatives: noise of the unbiased residual estimator (repeatable)")
    ap.add_argument("--table", action="store_true", help="print the markdown tables of --out")
    ap.add_argument("--summary", action="store_true", help="print the compact tables of --out")
    args = ap.parse_args(argv)

    if args.summary:
        print(summary_tables(json.loads(Path(args.out).read_text())))
        return
    if args.table:
        recs = [r for r in json.loads(Path(args.out).read_text()) if "err" in r]
        print(markdown_tables(recs))
        return
    if args.time_build:
        for dr, K in args.time_build:
            for a in args.alpha:
                r = time_rank_build(args.pattern, a, dr, K, args.resolution, float32=args.float32,
                                    basis_method=args.basis_method, workers=args.workers)
                r["openblas_threads"] = os.environ.get("OPENBLAS_NUM_THREADS")
                r["workers"] = args.workers
                print(json.dumps(r))
                _append(args.out, [dict(r, kind="build")])
        return
    if args.build_tables:
        dr, K = args.build_tables
        r = time_build_tables(args.pattern, args.alpha[0], dr, K, args.resolution)
        print(json.dumps(r))
        _append(args.out, [dict(r, kind="build_tables")])
        return
    if args.moments is not None or args.cv:
        for a in args.alpha:
            recs = measure_alternatives(args.pattern, a, args.moments or (), [tuple(c) for c in args.cv],
                                        args.sizes, args.positions, args.nh, args.resolution,
                                        args.seed, log=lambda s: print(s, file=sys.stderr))
            _append(args.out, recs)
            print(alternatives_table(recs))
        return
    for a in args.alpha:
        t0 = time.perf_counter()
        print(f"{args.pattern} alpha {a}", file=sys.stderr)
        recs = measure(args.pattern, a, args.dr, args.ranks, args.rank_dr, args.interp, args.sizes,
                       args.positions, args.nh, args.resolution, args.seed,
                       log=lambda s: print(s, file=sys.stderr), basis_method=args.basis_method)
        _append(args.out, recs)
        print(markdown_tables(recs))
        print(f"({time.perf_counter() - t0:.0f} s)", file=sys.stderr)


if __name__ == "__main__":
    main()
