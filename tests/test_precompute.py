"""Multi-scale precomputation: direction bins, residual SATs, visibility, clusters, parallax,
the per-tile tables and their cache (docs/design.md §4)."""
from __future__ import annotations

import json
import math
import warnings

import mitsuba as mi
import numpy as np
import pytest

from mscloth.errors import ParameterError
from mscloth.maps.woven import woven_maps
from mscloth.patterns.weaves import plain, twill
from mscloth.precompute import tables as tables_mod
from mscloth.precompute import visibility as vis_mod
from mscloth.precompute._march import escape_mask
from mscloth.precompute._util import texel_pitch
from mscloth.precompute.direction_bins import (bilinear_bins, bin_centres, direction_to_bin,
                                               fold_upper, hemisphere_to_square,
                                               square_to_hemisphere, triangle_bins)
from mscloth.precompute.parallax import parallax_table
from mscloth.precompute.summed_area import ResidualSAT, build_sat, rect_mean, rect_sum
from mscloth.precompute.tables import (MultiscaleTables, TableKey, build_tables, default_cache_dir,
                                       load_or_build, sggx_fibre_ndf, table_key)
from mscloth.precompute.visibility import cluster_visibility, visibility_table

EPS32 = 2.0 ** -24


# ============================================================== helpers (independent)
def coverage_1d(a0: float, a1: float):
    """Integer cells i (unwrapped) and their overlap with [a0, a1]."""
    cells = np.arange(math.floor(a0), math.ceil(a1))
    w = np.clip(np.minimum(cells + 1, a1) - np.maximum(cells, a0), 0.0, None)
    return cells, w


def brute_rect(img: np.ndarray, x0, y0, x1, y1) -> np.ndarray:
    """Integral of a periodic piecewise-constant image (C, H, W) over [x0,x1]x[y0,y1], float64."""
    C, H, W = img.shape
    cx, wx = coverage_1d(x0, x1)
    cy, wy = coverage_1d(y0, y1)
    sub = img[:, (cy % H)[:, None], (cx % W)[None, :]].astype(np.float64)
    return np.einsum("cyx,y,x->c", sub, wy, wx)


def d_image(maps, alpha, n_bins_side):
    """D(h_b, t(p)) * gap(p), (B, H, W) float64, straight from the definition."""
    t = np.asarray(maps.tangent, dtype=np.float64)
    t = t / np.linalg.norm(t, axis=-1, keepdims=True)
    h = bin_centres(n_bins_side)
    mt = np.einsum("bk,yxk->byx", h, t)
    d = alpha ** 3 / (np.pi * (mt ** 2 + alpha ** 2 * (1 - mt ** 2)) ** 2)
    return d * np.asarray(maps.gap, dtype=np.float64)[None]


def bilinear_periodic(h, x, y):
    """Bilinear height at real texel coordinates (centres at integers), periodic."""
    H, W = h.shape
    x0, y0 = np.floor(x), np.floor(y)
    fx, fy = x - x0, y - y0
    i0, j0 = x0.astype(int) % W, y0.astype(int) % H
    i1, j1 = (i0 + 1) % W, (j0 + 1) % H
    return ((1 - fy) * ((1 - fx) * h[j0, i0] + fx * h[j0, i1])
            + fy * ((1 - fx) * h[j1, i0] + fx * h[j1, i1]))


def reference_margin(height, w, pitch, step=0.05, dtan=0.0):
    """Per-texel float64 march with a fine step, straight from the definition: the largest
    height (texels) of the surface above the ray; the ray escapes where it is <= 0.
    ``dtan`` tilts the ray: its rise per horizontal texel becomes tan(elevation) + dtan."""
    px, py = pitch
    h = height / px
    dx, dy, dz = w[0] / px, w[1] / py, w[2] / px
    horiz = math.hypot(dx, dy)
    H, W = h.shape
    margin = np.full((H, W), -np.inf)
    if horiz < 1e-12:
        return margin
    L = step / horiz
    dz = dz + dtan * horiz
    ys, xs = np.mgrid[0:H, 0:W].astype(np.float64)
    n = int(math.ceil((h.max() - h.min()) / (dz * L))) + 1
    for k in range(1, n + 1):
        s = k * L
        margin = np.maximum(margin, bilinear_periodic(h, xs + s * dx, ys + s * dy) - (h + s * dz))
    return margin


def smooth_field(H, W, seed=0, amp=0.1):
    """A smooth periodic random height field in tile-width units."""
    rng = np.random.default_rng(seed)
    y, x = np.mgrid[0:H, 0:W]
    f = np.zeros((H, W))
    for _ in range(6):
        kx, ky = rng.integers(-3, 4, 2)
        ph = rng.uniform(0, 2 * np.pi)
        f += rng.uniform(0.3, 1.0) * np.cos(2 * np.pi * (kx * x / W + ky * y / H) + ph)
    return amp * f / np.abs(f).max()


@pytest.fixture(scope="module")
def maps_sq():
    return woven_maps(plain(), 32)


@pytest.fixture(scope="module")
def maps_rect():
    # Non-square texel grid (24 x 36 texels on a square tile): catches H/W and pitch mix-ups.
    return woven_maps(twill(2, 1), (24, 36))


@pytest.fixture(scope="module")
def tables_sq(maps_sq):
    return build_tables(maps_sq, 0.3, dr=8, dv=4, clusters=4, per_cluster_sat=True,
                        parallax=True, progress=False)


@pytest.fixture(scope="module")
def tables_rect(maps_rect):
    return build_tables(maps_rect, 0.45, dr=6, dv=3, clusters=3, progress=False)


# ============================================================== direction bins
def test_square_to_hemisphere_matches_mitsuba():
    rng = np.random.default_rng(0)
    p = np.concatenate([rng.random((4000, 2)),
                        [[0.5, 0.5], [0, 0], [1, 1], [0, 1], [1, 0], [0.5, 0], [0.5, 1],
                         [0, 0.5], [0.25, 0.75], [0.75, 0.75], [0.9, 0.5]]])
    ours = square_to_hemisphere(p)
    theirs = np.array(mi.warp.square_to_uniform_hemisphere(mi.Point2f(p[:, 0], p[:, 1]))).T
    assert ours.shape == (len(p), 3)
    np.testing.assert_allclose(ours, theirs, atol=1e-5)
    np.testing.assert_allclose(np.linalg.norm(ours, axis=-1), 1.0, atol=1e-12)
    assert np.all(ours[:, 2] >= 0)


def test_hemisphere_to_square_matches_mitsuba_and_inverts():
    rng = np.random.default_rng(1)
    w = rng.normal(size=(4000, 3))
    w /= np.linalg.norm(w, axis=-1, keepdims=True)
    w = fold_upper(w)
    w = np.concatenate([w, [[0, 0, 1], [1, 0, 0], [0, 1, 0], [-1, 0, 0], [0, -1, 0],
                            [math.sqrt(0.5), math.sqrt(0.5), 0]]])
    ours = hemisphere_to_square(w)
    theirs = np.array(mi.warp.uniform_hemisphere_to_square(
        mi.Vector3f(w[:, 0], w[:, 1], w[:, 2]))).T
    np.testing.assert_allclose(ours, theirs, atol=1e-5)
    np.testing.assert_allclose(square_to_hemisphere(ours), w, atol=1e-9)


def test_fold_upper_and_direction_to_bin():
    w = np.array([[0.3, -0.2, -0.9], [0.1, 0.2, 0.5], [0.0, 0.0, -1.0]])
    f = fold_upper(w)
    np.testing.assert_array_equal(f, [[-0.3, 0.2, 0.9], [0.1, 0.2, 0.5], [0, 0, 1.0]])
    n = 6
    c = bin_centres(n)
    np.testing.assert_array_equal(direction_to_bin(c, n), np.arange(n * n))
    np.testing.assert_array_equal(direction_to_bin(-c, n), np.arange(n * n))


def test_bin_centres_layout():
    n = 5
    c = bin_centres(n)
    assert c.shape == (n * n, 3)
    for a, b in [(0, 0), (3, 1), (4, 2), (1, 4)]:
        np.testing.assert_allclose(c[b * n + a],
                                   square_to_hemisphere([(a + 0.5) / n, (b + 0.5) / n]))
    np.testing.assert_allclose(c[2 * n + 2], [0, 0, 1], atol=1e-12)  # odd n: zenith bin


def _check_centre_and_linear(bins_of, n, rng, count):
    """An interpolation over direction bins (``bins_of(p, n)`` -> indices, weights): all the
    weight on the bin at its centre, and functions linear in the bin coordinates exact in
    the interior. Returns the interior points with their bins and weights."""
    idx, w = bins_of([(n - 2 + 0.5) / n, (1 + 0.5) / n], n)
    assert np.isclose(w[np.argmax(w)], 1.0) and idx[np.argmax(w)] == 1 * n + n - 2
    p = rng.uniform(0.5 / n, 1 - 0.5 / n, size=(count, 2))
    idx, w = bins_of(p, n)
    a, b = idx % n, idx // n
    f = lambda a, b: 3.0 * a - 2.0 * b + 1.0   # noqa: E731
    np.testing.assert_allclose(np.sum(w * f(a, b), axis=-1),
                               f(p[:, 0] * n - 0.5, p[:, 1] * n - 0.5), atol=1e-12)
    return p, idx, w


def test_bilinear_bins():
    n = 4
    rng = np.random.default_rng(2)
    _check_centre_and_linear(bilinear_bins, n, rng, 500)
    # Edges clamp; weights always sum to 1 and are >= 0.
    p = rng.uniform(0, 1, size=(500, 2))
    p[:10] = [[0, 0], [1, 1], [0, 1], [1, 0], [0.01, 0.5], [0.99, 0.5], [0.5, 0], [0.5, 1],
              [0.1, 0.99], [0.999, 0.001]]
    idx, w = bilinear_bins(p, n)
    np.testing.assert_allclose(w.sum(-1), 1.0)
    assert np.all(w >= 0) and np.all((idx >= 0) & (idx < n * n))
    idx, w = bilinear_bins([0.0, 0.0], n)
    assert set(idx[w > 0].tolist()) == {0}
    idx, w = bilinear_bins([1.0, 0.3], n)
    assert set((idx[w > 0] % n).tolist()) == {n - 1}


def test_triangle_bins():
    """Three of the four bilinear bins and barycentric weights: a bin centre is that bin,
    functions linear in the bin coordinates come out exactly, the result is continuous
    across the cell's diagonal and its edges, and edges clamp."""
    n = 5
    rng = np.random.default_rng(4)
    p, idx, w = _check_centre_and_linear(triangle_bins, n, rng, 2000)
    four, _ = bilinear_bins(p, n)
    assert np.all(np.isin(idx, four).all(axis=-1))  # a subset of the cell's four
    # Continuity: a random table interpolated on both sides of the diagonal and of a
    # cell edge agrees (the bilinear four would too; a nearest-bin lookup would not).
    table = rng.random(n * n)

    def lookup(q):
        i, wt = triangle_bins(q, n)
        return np.sum(table[i] * wt, axis=-1)
    s = rng.uniform(0.1, 0.9, 50)
    eps = 1e-9
    # On a cell's diagonal (fa = fb), crossed along (1, -1); on a vertical and a
    # horizontal cell edge (bin centres' lines), crossed along x and along y.
    for on, step in ((np.stack([(1.5 + s) / n, (2.5 + s) / n], -1), [eps, -eps]),
                     (np.stack([np.full(50, 2.5 / n), (1.5 + 2 * s) / n], -1), [eps, 0.0]),
                     (np.stack([(0.5 + 3 * s) / n, np.full(50, 3.5 / n)], -1), [0.0, eps])):
        np.testing.assert_allclose(lookup(on + step), lookup(on - np.array(step)), atol=1e-7)
    p = rng.uniform(0, 1, size=(500, 2))
    p[:6] = [[0, 0], [1, 1], [0, 1], [1, 0], [0.999, 0.001], [0.001, 0.999]]
    idx, w = triangle_bins(p, n)
    np.testing.assert_allclose(w.sum(-1), 1.0)
    assert np.all(w >= 0) and np.all((idx >= 0) & (idx < n * n))


# ============================================================== summed-area tables
def test_build_sat_layout():
    rng = np.random.default_rng(3)
    v = rng.random((2, 5, 7))
    sat, mean = build_sat(v)
    assert sat.shape == (2, 6, 8) and sat.dtype == np.float32 and mean.dtype == np.float64
    np.testing.assert_allclose(mean, v.mean(axis=(1, 2)), rtol=1e-14)
    assert np.all(sat[:, 0, :] == 0) and np.all(sat[:, :, 0] == 0)
    ref = np.cumsum(np.cumsum(v - mean[:, None, None], axis=1), axis=2)
    np.testing.assert_allclose(sat[:, 1:, 1:], ref, atol=1e-6)
    assert np.all(np.abs(sat[:, -1, -1]) < 1e-6)


@pytest.mark.parametrize("shape", [(1, 13, 9), (3, 8, 8)])
def test_rect_sum_integer_and_fractional_any_size(shape):
    rng = np.random.default_rng(4)
    img = rng.random(shape) * 2 - 0.3
    C, H, W = shape
    sat, mean = build_sat(img)
    rects = [
        (0, 0, W, H), (2, 3, 3, 4), (5, 1, 5, 6), (-3, -2, 4, 5), (1, 1, 1 + 3.5 * W, 1 + 3.5 * H),
        (-2.25 * W, -1.75 * H, 1.5 * W + 0.3, 0.2 * H), (0.3, 0.7, 0.9, 0.8), (-0.5, 2.5, 0.5, 3.5),
        (W - 0.5, H - 0.5, W + 0.5, H + 0.5), (-7.3, -11.9, -6.1, -3.2),
    ]
    for _ in range(40):
        x0, y0 = rng.uniform(-3 * W, 3 * W), rng.uniform(-3 * H, 3 * H)
        rects.append((x0, y0, x0 + rng.uniform(0, 4 * W), y0 + rng.uniform(0, 4 * H)))
        xi, yi = rng.integers(-2 * W, 2 * W), rng.integers(-2 * H, 2 * H)
        rects.append((xi, yi, xi + rng.integers(0, 3 * W), yi + rng.integers(0, 3 * H)))
    r = np.array(rects, dtype=np.float64)
    got = rect_sum(sat, mean, r[:, 0], r[:, 1], r[:, 2], r[:, 3])
    assert got.shape == (len(r), C)
    ref = np.array([brute_rect(img, *q) for q in r])
    scale = np.abs(img).sum(axis=(1, 2)).max() * 20
    np.testing.assert_allclose(got, ref, atol=1e-5 * scale / 20 + 1e-9 * scale)
    # One channel per rectangle.
    ch = np.arange(len(r)) % C
    np.testing.assert_allclose(rect_sum(sat, mean, r[:, 0], r[:, 1], r[:, 2], r[:, 3], ch),
                               ref[np.arange(len(r)), ch], atol=1e-5)
    # Means.
    area = (r[:, 2] - r[:, 0]) * (r[:, 3] - r[:, 1])
    ok = area > 0
    np.testing.assert_allclose(rect_mean(sat, mean, *r[ok].T), ref[ok] / area[ok, None], atol=1e-5)


def test_residual_sat_class():
    rng = np.random.default_rng(14)
    img = rng.random((2, 6, 9))
    r = ResidualSAT.build(img)
    assert r.channels == 2 and r.resolution == (6, 9) and r.nbytes == 2 * 7 * 10 * 4 + 16
    np.testing.assert_allclose(r.rect_sum(-1.5, 2, 20, 5.5), brute_rect(img, -1.5, 2, 20, 5.5),
                               atol=1e-5)
    np.testing.assert_allclose(r.rect_mean(0, 0, 9, 6), img.mean(axis=(1, 2)), atol=1e-7)


def test_rect_sum_rejects_inverted_rectangles():
    sat, mean = build_sat(np.ones((1, 4, 4)))
    with pytest.raises(ValueError):
        rect_sum(sat, mean, 2, 0, 1, 1)


def test_residual_sat_precision_on_a_big_tile():
    """2048^2 random tile, 4x4 boxes anywhere: the residual SAT stays within 1e-4 of the
    float64 box sum; a plain float32 SAT of the same data is far worse."""
    rng = np.random.default_rng(5)
    n = 2048
    img = rng.random((1, n, n), dtype=np.float64)
    sat, mean = build_sat(img)
    plain_sat = np.zeros((1, n + 1, n + 1), dtype=np.float32)
    plain_sat[0, 1:, 1:] = np.cumsum(np.cumsum(img[0], axis=0), axis=1)
    x0 = rng.integers(0, n, 3000).astype(float)
    y0 = rng.integers(0, n, 3000).astype(float)
    x0[:4], y0[:4] = [n - 4, n - 2, 0, 1500], [n - 4, 7, n - 3, n - 1]   # far corner, wraps
    ref = np.array([brute_rect(img, a, b, a + 4, b + 4)[0] for a, b in zip(x0, y0)])
    got = rect_sum(sat, mean, x0, y0, x0 + 4, y0 + 4)[:, 0]
    naive = rect_sum(plain_sat, np.zeros(1), x0, y0, x0 + 4, y0 + 4)[:, 0]
    err = np.abs(got - ref) / ref
    err_naive = np.abs(naive - ref) / ref
    assert err.max() < 1e-4
    assert err_naive.max() > 1e-3 and err_naive.max() > 30 * err.max()


# ============================================================== visibility
def test_flat_field_is_all_visible():
    for n in (3, 4):
        v = visibility_table(np.full((16, 20), 0.05), n)
        assert v.shape == (16, 20, n * n) and v.dtype == np.uint8
        assert np.all(v == 255)
        assert np.all(visibility_table(np.zeros((16, 20)), n, back=True) == 255)


def test_visibility_is_the_same_on_any_number_of_threads():
    """Small fields march on one thread by default (THREADED_TEXELS); the directions come
    back in bin order whatever the threads, so the tables (and their cache entries) do not
    depend on the machine."""
    rng = np.random.default_rng(3)
    h = rng.random((24, 20)) * 0.2
    assert h.size < vis_mod.THREADED_TEXELS
    one = visibility_table(h, 4, fast=True, workers=1)
    for workers in (None, 3):
        np.testing.assert_array_equal(visibility_table(h, 4, fast=True, workers=workers), one)
    assert 0 < np.count_nonzero(one == 0) < one.size  # shadows and light, so order matters


def _tower_field(n=32, height_texels=8.0):
    h = np.zeros((n, n))
    h[14:18, 14:18] = height_texels / n            # tile-width units (pitch 1/n)
    return h


@pytest.mark.parametrize("fast", [False, True])
def test_tower_shadows_texels_behind_it_at_low_elevation(fast):
    n_tile, n = 32, 4
    h = _tower_field(n_tile)
    vis = visibility_table(h, n, fast=fast)
    dirs = bin_centres(n)
    centre = np.array([15.5, 15.5])               # (x, y) texel coordinates of the tower
    low = np.flatnonzero(dirs[:, 2] < 0.5)
    assert len(low) == 12
    checked = 0
    for b in low:
        u = dirs[b, :2] / np.linalg.norm(dirs[b, :2])
        for d in (4.0, 6.0, 8.0):
            # In front: walking along w from here runs into the tower while still low.
            x, y = np.round(centre - d * u).astype(int) % n_tile
            assert vis[y, x, b] == 0, (b, d)
            # Behind: walking along w leads away; the tower's next copy is too far to block.
            x, y = np.round(centre + d * u).astype(int) % n_tile
            assert vis[y, x, b] == 255, (b, d)
            checked += 1
    assert checked == 36
    # Top of the tower sees everything; far from it everything is visible.
    assert np.all(vis[15, 15] == 255)
    # Steep directions are blocked only next to the tower.
    high = np.flatnonzero(dirs[:, 2] > 0.9)
    far = np.ones((n_tile, n_tile), dtype=bool)
    far[10:22, 10:22] = False
    assert np.all(vis[far][:, high] == 255)


def test_zenith_is_never_blocked():
    h = _tower_field()
    vis = visibility_table(h, 3)                  # odd n: the middle bin is the zenith
    assert np.all(vis[:, :, 4] == 255)
    assert np.any(vis[:, :, 0] == 0)


@pytest.mark.parametrize("pitch", [None, (1 / 24, 1 / 40)])
def test_visibility_matches_an_independent_march(pitch):
    """A smooth random field: the table agrees with a fine float64 per-texel march wherever
    the verdict is robust (clear even with the ray's slope 0.1 lower; blocked by > 0.05 texel
    even with it 0.1 higher; closer calls depend on where the samples fall), and fast agrees
    with exact."""
    H, W = 20, 24
    h = smooth_field(H, W, seed=7, amp=0.12)
    n = 4
    p = (1 / W, 1 / H) if pitch is None else pitch
    fast = visibility_table(h, n, pitch=pitch, fast=True)
    exact = visibility_table(h, n, pitch=pitch)
    back = visibility_table(h, n, pitch=pitch, back=True)
    assert np.mean(fast != exact) < 0.01
    n_blocked = n_clear = 0
    for b, w in enumerate(bin_centres(n)):
        for table, field in ((exact, h), (back, -h)):
            blocked = reference_margin(field, w, p, dtan=0.1) > 0.05
            clear = reference_margin(field, w, p, dtan=-0.1) <= 1e-4
            assert np.all(table[:, :, b][blocked] == 0), b
            assert np.all(table[:, :, b][clear] == 255), b
            margin = reference_margin(field, w, p)
            assert np.mean((table[:, :, b] == 255) != (margin <= 1e-4)) < 0.05, b
            n_blocked += np.count_nonzero(blocked)
            n_clear += np.count_nonzero(clear)
    cases = 2 * H * W * n * n
    assert n_blocked > 0.1 * cases and n_blocked + n_clear > 0.8 * cases


def test_escape_mask_far_field_blocks_agree_with_exact():
    """Low elevation on a bigger tile: the far-field block shortcut is used and agrees."""
    h = smooth_field(64, 64, seed=3, amp=0.15) * 64   # texel units
    for d in [(0.93, 0.31, 0.12), (-0.2, 0.97, 0.08), (0.7, -0.7, 0.1), (-1.0, 0.0, 0.15)]:
        fast = escape_mask(h, d, fast=True)
        exact = escape_mask(h, d)
        assert np.mean(fast != exact) < 0.01
        assert 0.05 < np.mean(exact) < 0.95


def test_far_field_block_slope_is_close():
    from mscloth.precompute._march import block_plan
    for slope in np.linspace(-1, 1, 401):
        Q, P, err = block_plan(slope, 3, 10_000)
        assert 16 <= Q <= 48 and np.isclose(err, abs(slope - P / Q), rtol=0, atol=1e-12)
        assert err <= 0.5 / Q and err < 0.011
    assert block_plan(0.3, 3, 20) is None          # short rays: always the full march


def test_back_visibility_is_the_mirrored_field():
    h = smooth_field(16, 16, seed=11, amp=0.1)
    np.testing.assert_array_equal(visibility_table(h, 3, back=True), visibility_table(-h, 3))


# ============================================================== clusters
def test_kmeans_recovers_planted_clusters():
    rng = np.random.default_rng(8)
    H, W, D, k = 40, 30, 32, 4
    protos = rng.random((k, D)) < 0.5
    labels = rng.integers(0, k, (H, W))
    vis = protos[labels]
    flip = rng.random((H, W, D)) < 0.04
    vis = np.where(vis ^ flip, 255, 0).astype(np.uint8)
    gap = (rng.random((H, W)) > 0.1).astype(np.float32)
    ids, means = cluster_visibility(vis, gap, k=k, seed=0)
    assert ids.dtype == np.int8 and ids.shape == (H, W) and means.shape == (k, D)
    assert means.dtype == np.float32
    np.testing.assert_array_equal(ids == -1, gap == 0)
    yarn = gap == 1
    # Every found cluster is exactly one planted cluster (a bijection).
    pairs = set(zip(ids[yarn].tolist(), labels[yarn].tolist()))
    assert len(pairs) == k
    assert len({a for a, _ in pairs}) == k and len({b for _, b in pairs}) == k
    for c in range(k):
        np.testing.assert_allclose(means[c], vis[ids == c].mean(axis=0) / 255.0, atol=1e-6)
    # Numbered by increasing mean visibility; deterministic.
    assert np.all(np.diff(means.mean(axis=1)) >= 0)
    ids2, means2 = cluster_visibility(vis, gap, k=k, seed=0)
    np.testing.assert_array_equal(ids, ids2)
    np.testing.assert_array_equal(means, means2)


def test_kmeans_result_is_a_lloyd_fixed_point():
    """Every yarn texel is nearest to the mean of its own cluster (converged k-means)."""
    h = smooth_field(32, 32, seed=21, amp=0.15)
    vis = visibility_table(h, 4)
    gap = np.ones((32, 32))
    gap[::5, ::3] = 0
    ids, means = cluster_visibility(vis, gap, k=5, seed=3, iters=200)
    x = vis[gap == 1].astype(np.float64) / 255
    d = ((x[:, None, :] - means[None].astype(np.float64)) ** 2).sum(-1)
    own = d[np.arange(len(x)), ids[gap == 1]]
    assert np.all(own <= d.min(axis=1) + 1e-5)
    assert len(np.unique(ids[gap == 1])) == 5


def test_kmeans_with_fewer_distinct_vectors_than_clusters():
    vis = np.full((8, 8, 5), 255, dtype=np.uint8)
    ids, means = cluster_visibility(vis, np.ones((8, 8)), k=8)
    assert np.all(ids == 0)
    np.testing.assert_allclose(means, 1.0)


# ============================================================== parallax
def test_flat_field_has_zero_parallax():
    p = parallax_table(np.full((12, 16), 0.02), 4)
    assert p.shape == (12, 16, 16, 2) and p.dtype == np.float32
    assert np.all(p == 0)


def _ramp_hits(coord, u_along, g, slope, n_period):
    """Analytic horizontal distance to the hit on the rising flank of a triangle wave
    h = slope * min(x, n - x) (texel units) for a ray from (coord, top) descending g per
    texel with horizontal direction component u_along > 0; None where not on that flank."""
    top = slope * n_period / 2
    t = (top - slope * coord) / (g + slope * u_along)
    x_hit = coord + t * u_along
    return np.where((coord < n_period / 2) & (x_hit <= n_period / 2 - 1.0), t, np.nan)


@pytest.mark.parametrize("axis", [1, 0])
def test_parallax_on_a_ramp_is_analytic(axis):
    n_wave, n_other = 32, 16
    slope = 0.5                                    # texel heights per texel
    x = np.arange(n_wave)
    wave = slope * np.minimum(x, n_wave - x)       # texel units
    if axis == 1:                                  # varies along columns (u)
        shape, pitch = (n_other, n_wave), (1 / n_wave, 1 / n_wave)
        h = np.tile(wave, (n_other, 1)) * pitch[0]
    else:                                          # varies along rows (v)
        shape, pitch = (n_wave, n_other), (1 / n_other, 1 / n_other)
        h = np.tile(wave[:, None], (1, n_other)) * pitch[0]
    n = 6
    table = parallax_table(h, n, pitch=pitch)
    assert table.shape == shape + (n * n, 2)
    dirs = bin_centres(n)
    checked = 0
    for b, w in enumerate(dirs):
        d = np.array([-w[0] / pitch[0], -w[1] / pitch[1]])   # ray: away from the viewer
        horiz = np.linalg.norm(d)
        u = d / horiz
        g = (w[2] / pitch[0]) / horiz
        u_along = u[0] if axis == 1 else u[1]
        if u_along < 0.2:
            continue
        t = _ramp_hits(np.arange(n_wave, dtype=float), u_along, g, slope, n_wave)
        ok = np.isfinite(t)
        expect = t[ok, None] * u[None, :]              # (dx, dy) per wave coordinate
        got = table[0, ok, b] if axis == 1 else table[ok, 0, b]
        np.testing.assert_allclose(got, expect, atol=2e-3, rtol=1e-4)
        # Constant across the other axis.
        other = table[:, :, b] if axis == 1 else np.swapaxes(table[:, :, b], 0, 1)
        np.testing.assert_allclose(other, np.broadcast_to(other[:1], other.shape), atol=1e-5)
        checked += int(ok.sum())
    assert checked > 40
    # The peak column/row is at the top: zero offset in every direction.
    peak = table[:, n_wave // 2] if axis == 1 else table[n_wave // 2]
    assert np.all(peak == 0)


def reference_first_hit(height, w, pitch, step=0.02):
    """Per-texel float64 march from the top along -w with a fine step; (dx, dy) texels."""
    px, py = pitch
    h = height / px
    d = np.array([-w[0] / px, -w[1] / py])
    dz = w[2] / px
    horiz = np.linalg.norm(d)
    H, W = h.shape
    top = h.max()
    ys, xs = np.mgrid[0:H, 0:W].astype(np.float64)
    t_hit = np.where(h >= top, 0.0, np.nan)
    prev = h - top
    n = int(math.ceil((top - h.min()) / (dz / horiz * step))) + 2
    for k in range(1, n + 1):
        s = k * step
        e = bilinear_periodic(h, xs + s * d[0] / horiz, ys + s * d[1] / horiz) - (top - s * dz / horiz)
        new = np.isnan(t_hit) & (e >= 0)
        t_hit[new] = s - step + step * (-prev[new]) / (e[new] - prev[new])
        prev = e
    return t_hit[..., None] * (d / horiz)


def test_parallax_matches_an_independent_march(monkeypatch):
    from mscloth.precompute import _march
    H, W = 20, 24
    h = smooth_field(H, W, seed=5, amp=0.1)
    pitch = (1 / W, 1 / 30)
    n = 4
    table = parallax_table(h, n, pitch=pitch)
    # Whole-array steps only / gathers after the first check: identical results.
    monkeypatch.setattr(_march, "_COMPACT_FRACTION", 0.0)
    np.testing.assert_array_equal(parallax_table(h, n, pitch=pitch), table)
    monkeypatch.setattr(_march, "_COMPACT_FRACTION", 1.0)
    np.testing.assert_array_equal(parallax_table(h, n, pitch=pitch), table)
    far = 0
    for b, w in enumerate(bin_centres(n)):
        ref = reference_first_hit(h, w, pitch)
        close = np.all(np.abs(table[:, :, b] - ref) < 0.05, axis=-1)
        assert np.mean(close) > 0.95, b
        far += np.count_nonzero(np.linalg.norm(ref, axis=-1) > 3)
    assert far > 100                               # long rays are part of the test


def test_visibility_compaction_modes_agree(monkeypatch):
    from mscloth.precompute import _march
    h = smooth_field(24, 20, seed=13, amp=0.15)
    ref = visibility_table(h, 4)
    for frac in (0.0, 1.0):
        monkeypatch.setattr(_march, "_COMPACT_FRACTION", frac)
        np.testing.assert_array_equal(visibility_table(h, 4), ref)


def test_texel_pitch_follows_the_tile_aspect(tables_rect):
    assert texel_pitch((24, 36), {"tile_size_mm": [1.5, 1.5]}) == (1 / 36, 1 / 24)
    assert texel_pitch((20, 10), {"tile_size_mm": [1.0, 3.0]}) == (1 / 10, 3.0 / 20)
    assert texel_pitch((20, 10), {}) == (1 / 10, 1 / 20)
    assert tables_rect.params["pitch"] == [1 / 36, 1 / 24]


# ============================================================== tables
FOOTPRINTS = [1, 2, 4, 8, 16]                      # sides: 1, 4, 16, 64, 256 texels


def test_d_sat_footprints_equal_brute_force(tables_sq, maps_sq, tables_rect, maps_rect):
    for tables, maps, alpha in ((tables_sq, maps_sq, 0.3), (tables_rect, maps_rect, 0.45)):
        H, W = maps.resolution
        img = d_image(maps, alpha, tables.dr)
        rng = np.random.default_rng(9)
        rects = []
        for side in FOOTPRINTS:
            for _ in range(6):
                x0, y0 = rng.integers(-W, 2 * W), rng.integers(-H, 2 * H)
                rects.append((x0, y0, x0 + side, y0 + side))
        rects.append((W - 1, H - 2, W + 1, H + 0))   # straddles the tile corner
        x0, y0 = -0.37 * W, 0.61 * H               # spans 3.5 tiles, fractional
        rects.append((x0, y0, x0 + 3.5 * W, y0 + 3.5 * H))
        rects.append((0.25, 0.5, 0.25 + 3.5 * W, 1.5))
        r = np.array(rects, dtype=float)
        got = tables.footprint_mean("d", *r.T)
        area = ((r[:, 2] - r[:, 0]) * (r[:, 3] - r[:, 1]))[:, None]
        ref = np.array([brute_rect(img, *q) for q in r]) / area
        # Float32 storage: each corner value carries <= 2^-24 relative error; the periodic
        # query combines <= 4 * (|qx qy| + |qx| + |qy| + 1) of them.
        q = np.maximum(np.abs(np.floor(r[:, [0, 2]] / W)).max(1), np.abs(np.floor(r[:, [1, 3]] / H)).max(1))
        weight = 4 * (q * q + 2 * q + 1)[:, None]
        sat_scale = np.abs(tables.d_sat).max(axis=(1, 2))[None, :]
        tol = 2 * weight * EPS32 * sat_scale / area + 1e-12
        assert np.all(np.abs(got - ref) <= tol), np.max(np.abs(got - ref) / tol)
        assert np.max(tol) < 0.02 * img.max()     # the bound is tight enough to mean something
        # Single texels: the value at the texel.
        for (yy, xx) in [(0, 0), (H - 1, W - 1), (3, 5)]:
            np.testing.assert_allclose(tables.footprint_mean("d", xx, yy, xx + 1, yy + 1),
                                       img[:, yy, xx], atol=4 * 4 * EPS32 * sat_scale.max())


def test_d_footprint_mean_interpolates_bins(tables_sq):
    n = tables_sq.dr
    c = bin_centres(n)
    box = (2.0, 3.0, 10.0, 7.0)
    vals = tables_sq.footprint_mean("d", *box)
    for b in (0, 9, 27, n * n - 1):
        np.testing.assert_allclose(tables_sq.d_footprint_mean(c[b], *box), vals[b], rtol=1e-9)
        np.testing.assert_allclose(tables_sq.d_footprint_mean(-c[b], *box), vals[b], rtol=1e-9)
    # Half-way between bins (a, b) and (a+1, b) in square coordinates: the average.
    p = np.array([(3 + 1.0) / n, (2 + 0.5) / n])
    h = square_to_hemisphere(p)
    np.testing.assert_allclose(tables_sq.d_footprint_mean(h, *box),
                               0.5 * (vals[2 * n + 3] + vals[2 * n + 4]), rtol=1e-9)


@pytest.fixture(scope="module")
def maps_twill():
    return woven_maps(twill(2, 1), 96)


@pytest.mark.parametrize("rank", [24, 48])
def test_rank_k_directional_sat(maps_twill, rank):
    """The rank-K table: an orthonormal basis over the bins, K coefficient channels, and
    footprint means of D (any rectangle, any half vector) close to the full table's; the
    error shrinks with K. The per-cluster tables split the rank-K table exactly."""
    full = build_tables(maps_twill, 0.3, dr=12, dv=2, clusters=3, progress=False)
    low = build_tables(maps_twill, 0.3, dr=12, dv=2, clusters=3, per_cluster_sat=True, d_rank=rank,
                       progress=False)
    B = 12 * 12
    assert low.d_basis.shape == (B, rank) and low.d_sat.shape == (rank, 97, 97)
    np.testing.assert_allclose(low.d_basis.T.astype(np.float64) @ low.d_basis, np.eye(rank), atol=1e-5)
    assert low.memory_report()["d_sat"] * B == full.memory_report()["d_sat"] * rank
    rng = np.random.default_rng(3)
    x0, y0 = rng.uniform(-50, 150, 200), rng.uniform(-50, 150, 200)
    x1, y1 = x0 + rng.uniform(1, 60, 200), y0 + rng.uniform(1, 60, 200)
    h = rng.normal(size=(200, 3))
    ref = full.d_footprint_mean(h, x0, y0, x1, y1)
    got = low.d_footprint_mean(h, x0, y0, x1, y1)
    scale = np.max(full.d_mean)  # errors relative to the tile's brightest bin mean
    err = np.max(np.abs(got - ref)) / scale
    # Mixed over three bins: single bins' errors reach 0.096 / 0.017 (24 / 48); bilinear
    # weights over four averaged them down to 0.040 / 0.008, the three to 0.051 / 0.008.
    assert err < {24: 0.06, 48: 0.01}[rank], err
    total = low.d_sat_cluster.sum(axis=0)
    np.testing.assert_allclose(total, low.d_sat, atol=2e-3 * np.abs(low.d_sat).max())


def test_rank_k_coefficients_do_not_depend_on_the_slabs(maps_twill, monkeypatch):
    """The rank-K coefficients are computed a slab of texels at a time on worker threads:
    slabs of 100 texels (the last one short) give the tables of one slab to rounding, so
    no texel is skipped, counted twice or written to another's columns, and the clusters'
    sums of D (d_cluster_tile) gather every slab."""
    kw = dict(dr=6, dv=2, clusters=3, d_rank=8, progress=False)
    one = build_tables(maps_twill, 0.3, **kw)
    monkeypatch.setattr(tables_mod, "_D_CHUNK_BYTES", 8 * 36 * 100)
    many = build_tables(maps_twill, 0.3, workers=2, **kw)
    for name in ("d_sat", "d_mean", "d_cluster_tile"):
        a, b = (np.asarray(getattr(t, name), np.float64) for t in (one, many))
        np.testing.assert_allclose(b, a, rtol=0, atol=1e-6 * np.abs(a).max(), err_msg=name)


def test_rank_must_fit_the_bins(maps_sq):
    with pytest.raises(ParameterError, match="d_rank"):
        build_tables(maps_sq, 0.3, dr=4, d_rank=17, progress=False)


def test_small_sats_equal_brute_force(tables_sq, maps_sq, tables_rect, maps_rect):
    for tables, maps in ((tables_sq, maps_sq), (tables_rect, maps_rect)):
        H, W = maps.resolution
        gap = np.asarray(maps.gap, dtype=np.float64)
        t = np.asarray(maps.tangent, dtype=np.float64)
        t /= np.linalg.norm(t, axis=-1, keepdims=True)
        comps = [(0, 0), (0, 1), (0, 2), (1, 1), (1, 2), (2, 2)]
        ids = tables.cluster_id
        k = tables.params["clusters"]
        images = {
            "gap": gap[None],
            "albedo": np.moveaxis(np.asarray(maps.albedo, np.float64) * gap[..., None], -1, 0),
            "moment": np.stack([t[..., i] * t[..., j] * gap for i, j in comps]),
            "cluster": np.stack([(ids == c) * gap for c in range(k)]).astype(float),
        }
        for box in [(1, 2, 5, 3), (-3.5, 0.25, 2.0 * W + 0.5, 1.5 * H), (0, 0, W, H)]:
            for name, img in images.items():
                got = tables.footprint_sum(name, *box)
                np.testing.assert_allclose(got, brute_rect(img, *box), atol=2e-4 * W * H / 100)
        # Whole tile, by the means: fractions.
        np.testing.assert_allclose(tables.gap_mean[0], gap.mean(), rtol=1e-12)
        np.testing.assert_allclose(tables.cluster_mean.sum(), gap.mean(), rtol=1e-12)


def test_clusters_and_visibility_tables_are_consistent(tables_sq, maps_sq):
    tb = tables_sq
    H, W = maps_sq.resolution
    D = tb.dv ** 2
    assert tb.visibility.shape == (H, W, D) and tb.visibility.dtype == np.uint8
    pitch = texel_pitch((H, W), maps_sq.meta)
    np.testing.assert_array_equal(tb.visibility, visibility_table(maps_sq.height, tb.dv, pitch=pitch))
    np.testing.assert_array_equal(tb.visibility_back,
                                  visibility_table(maps_sq.height, tb.dv, pitch=pitch, back=True))
    np.testing.assert_array_equal(tb.parallax, parallax_table(maps_sq.height, tb.dv, pitch=pitch))
    np.testing.assert_array_equal(tb.cluster_id == -1, maps_sq.gap == 0)
    for c in range(tb.params["clusters"]):
        sel = tb.cluster_id == c
        if sel.any():
            np.testing.assert_allclose(tb.cluster_vis[c], tb.visibility[sel].mean(0) / 255, atol=1e-6)
            np.testing.assert_allclose(tb.cluster_vis_back[c], tb.visibility_back[sel].mean(0) / 255,
                                       atol=1e-6)
    assert tb.cluster_vis.dtype == np.float32 and tb.cluster_vis.shape == (4, D)
    # The woven tile is not flat: some texels are shadowed, and clusters differ.
    assert 0 < np.mean(tb.visibility == 0) < 0.9
    assert np.ptp(tb.cluster_vis.mean(axis=1)) > 0.05


def test_per_cluster_d_sat_splits_d_sat(tables_sq, maps_sq):
    tb = tables_sq
    assert tb.d_sat_cluster.shape == (4, tb.dr ** 2) + tb.d_sat.shape[1:]
    img = d_image(maps_sq, 0.3, tb.dr)
    box = (-5.5, 3.25, 20.0, 41.0)
    per = np.stack([rect_sum(tb.d_sat_cluster[c], tb.d_cluster_mean[c], *box) for c in range(4)])
    np.testing.assert_allclose(per.sum(0), tb.footprint_sum("d", *box), rtol=1e-5, atol=1e-3)
    for c in range(4):
        np.testing.assert_allclose(per[c], brute_rect(img * (tb.cluster_id == c), *box),
                                   rtol=1e-5, atol=1e-3)


def test_memory_report_and_summary(tables_sq, tables_rect):
    rep = tables_sq.memory_report()
    assert rep["d_sat"] == tables_sq.d_sat.nbytes
    assert rep["d_sat_cluster"] == tables_sq.d_sat_cluster.nbytes
    assert "d_sat_cluster" not in tables_rect.memory_report()
    assert set(rep) == set(tables_sq.arrays())
    text = tables_sq.summary()
    assert "MiB" in text and "total" in text and "d_sat" in text
    assert f"{sum(rep.values()) / 2**20:.2f}" in text
    assert tables_rect.d_sat.shape == (36, 25, 37)
    # The parallax table only when asked for (the cache key knows the difference).
    assert tables_rect.parallax is None and "parallax" not in tables_rect.memory_report()
    assert tables_sq.parallax.shape == (32, 32, 16, 2) and "parallax" in rep


def test_build_reports_progress_on_stderr(maps_sq, capsys):
    build_tables(maps_sq, 0.3, dr=4, dv=2, clusters=2, parallax=True)
    err = capsys.readouterr().err
    assert "building directional SAT" in err and "bins" in err
    assert "visibility" in err and "parallax" in err and "MiB" in err


@pytest.mark.parametrize("kw", [dict(roughness=0.0), dict(roughness=-1), dict(roughness=float("nan")),
                                dict(roughness="x"), dict(roughness=0.3, dr=0),
                                dict(roughness=0.3, clusters=200), dict(roughness=0.3, dv=True)])
def test_bad_parameters_raise(maps_sq, kw):
    with pytest.raises(ParameterError):
        build_tables(maps_sq, progress=False, **kw)


def test_sggx_ndf_matches_the_plugin_formula():
    from mscloth.scattering import sggx
    rng = np.random.default_rng(12)
    m = rng.normal(size=(50, 3))
    m /= np.linalg.norm(m, axis=1, keepdims=True)
    t = rng.normal(size=(50, 3))
    t /= np.linalg.norm(t, axis=1, keepdims=True)
    ours = sggx_fibre_ndf(m, t, 0.27)
    theirs = np.array(sggx.ndf(mi.Vector3f(m.T), mi.Vector3f(t.T), 0.27))
    np.testing.assert_allclose(ours, theirs, rtol=2e-5)
    # The in-place form the directional SAT's build uses is the same function of m.t.
    from mscloth.precompute.tables import fibre_ndf_of_cosine
    mt = np.sum(m * t, axis=1)
    np.testing.assert_allclose(fibre_ndf_of_cosine(mt.copy(), 0.27), ours, rtol=1e-12)


# ============================================================== cache
CACHE_KW = dict(dr=4, dv=2, clusters=2, progress=False)


def _assert_same(a: MultiscaleTables, b: MultiscaleTables):
    assert a.key == b.key
    assert set(a.arrays()) == set(b.arrays())
    for name, arr in a.arrays().items():
        np.testing.assert_array_equal(arr, b.arrays()[name], err_msg=name)
        assert arr.dtype == b.arrays()[name].dtype


def test_cache_round_trip(maps_sq, tmp_path, monkeypatch):
    t1 = load_or_build(maps_sq, 0.3, cache_dir=tmp_path, **CACHE_KW)
    files = sorted(p.name for p in tmp_path.iterdir())
    assert files == [f"tables-{t1.key}.json", f"tables-{t1.key}.npz"]
    side = json.loads((tmp_path / f"tables-{t1.key}.json").read_text())
    assert side["key"] == t1.key and len(side["arrays"]["d_sat"]["sha256"]) == 64

    def no_build(*a, **k):
        raise AssertionError("should have loaded from the cache")
    monkeypatch.setattr(tables_mod, "build_tables", no_build)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        t2 = load_or_build(maps_sq, 0.3, cache_dir=tmp_path, **CACHE_KW)
    _assert_same(t1, t2)
    assert t2.params["roughness"] == 0.3 and t2.params["dr"] == 4


def test_build_warning_only_when_building(maps_sq, tmp_path):
    """The rank-compression note is given by the build, not by every load of its tables."""
    with pytest.warns(RuntimeWarning, match="using rank 4"):
        t1 = load_or_build(maps_sq, 0.3, cache_dir=tmp_path, build_warning="using rank 4", **CACHE_KW)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        t2 = load_or_build(maps_sq, 0.3, cache_dir=tmp_path, build_warning="using rank 4", **CACHE_KW)
    _assert_same(t1, t2)


def test_cache_key_changes_with_every_parameter(maps_sq, maps_rect, tmp_path):
    t1 = load_or_build(maps_sq, 0.3, cache_dir=tmp_path, **CACHE_KW)
    t2 = load_or_build(maps_sq, 0.31, cache_dir=tmp_path, **CACHE_KW)
    assert t1.key != t2.key
    assert (tmp_path / f"tables-{t2.key}.npz").is_file() and (tmp_path / f"tables-{t1.key}.npz").is_file()
    assert not np.array_equal(t1.d_sat, t2.d_sat)
    base = TableKey(0.3, dr=4, dv=2, clusters=2).as_params()
    keys = {table_key(maps_sq, base), table_key(maps_rect, base)}
    for change in [dict(dr=5), dict(dv=3), dict(clusters=3), dict(per_cluster_sat=True),
                   dict(seed=1), dict(iters=7), dict(max_step=0.25), dict(vis_eps=1e-3),
                   dict(fast_visibility=False), dict(d_rank=4), dict(parallax=True)]:
        keys.add(table_key(maps_sq, TableKey(0.3, **{**dict(dr=4, dv=2, clusters=2), **change}).as_params()))
    assert len(keys) == 13


def test_table_key_is_the_cache_key_of_its_fields(maps_sq, tmp_path):
    """A TableKey holds every build input, validated and normalised once; its cache key is the
    one the build inputs had before it existed (caches stay valid), and load_or_build takes
    it in place of the roughness and keywords."""
    import dataclasses
    import json

    from mscloth.errors import ParameterError
    from mscloth.precompute.tables import TableKey

    key = TableKey(0.3, dr=4, dv=2, clusters=2)
    as_before = {"roughness": 0.3, "dr": 4, "d_rank": 0, "dv": 2, "clusters": 2, "per_cluster_sat": False,
                 "seed": 0, "iters": 30, "max_step": 0.5, "vis_eps": 1e-4, "fast_visibility": True,
                 "parallax": False}
    assert json.dumps(key.as_params(), sort_keys=True) == json.dumps(as_before, sort_keys=True)
    assert table_key(maps_sq, key.as_params()) == table_key(maps_sq, as_before)
    with pytest.raises(dataclasses.FrozenInstanceError):
        key.roughness = 0.4
    assert TableKey(0.3, dr=4, d_rank=16).d_rank == 0  # a rank of all bins is the full table
    for bad in (dict(roughness=0.0), dict(roughness=0.3, dr=0), dict(roughness=0.3, d_rank=17, dr=4)):
        with pytest.raises(ParameterError):
            TableKey(**bad)
    tables = load_or_build(maps_sq, key, cache_dir=tmp_path, progress=False)
    assert tables.key == load_or_build(maps_sq, 0.3, cache_dir=tmp_path, **CACHE_KW).key
    assert tables.key == build_tables(maps_sq, key, progress=False).key
    with pytest.raises(TypeError):
        load_or_build(maps_sq, key, cache_dir=tmp_path, dr=8)


def _corrupt_middle(path):
    data = bytearray(path.read_bytes())
    mid = len(data) // 2
    for i in range(mid, mid + 64):
        data[i] ^= 0x5A
    path.write_bytes(bytes(data))


@pytest.mark.parametrize("damage", ["flip", "truncate", "checksum", "shape", "no_sidecar",
                                    "garbage_sidecar"])
def test_bad_cache_is_rebuilt_with_a_warning(maps_sq, tmp_path, damage):
    t1 = load_or_build(maps_sq, 0.3, cache_dir=tmp_path, **CACHE_KW)
    npz = tmp_path / f"tables-{t1.key}.npz"
    side = tmp_path / f"tables-{t1.key}.json"
    if damage == "flip":
        _corrupt_middle(npz)
    elif damage == "truncate":
        npz.write_bytes(npz.read_bytes()[: npz.stat().st_size // 3])
    elif damage in ("checksum", "shape"):
        js = json.loads(side.read_text())
        if damage == "checksum":
            js["arrays"]["visibility"]["sha256"] = "0" * 64
        else:
            js["arrays"]["cluster_vis"]["shape"] = [1, 2, 3]
        side.write_text(json.dumps(js))
    elif damage == "no_sidecar":
        side.unlink()
    else:
        side.write_text("{not json")
    bad = side if damage in ("shape", "no_sidecar", "garbage_sidecar") else npz
    with pytest.warns(RuntimeWarning, match=bad.name):
        t2 = load_or_build(maps_sq, 0.3, cache_dir=tmp_path, **CACHE_KW)
    _assert_same(t1, t2)
    # The rebuilt cache is good again.
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        _assert_same(t1, load_or_build(maps_sq, 0.3, cache_dir=tmp_path, **CACHE_KW))


def test_concurrent_loads_build_one_table_at_a_time_and_the_same_tables_once(maps_sq, tmp_path, monkeypatch):
    """Mitsuba's parallel loader constructs cloths on several threads: their table builds run
    one after another (each already spreads over every core), and a thread that waited for
    tables another thread built meanwhile loads them instead of building them again."""
    import threading
    import time

    real_build = tables_mod.build_tables
    running, spans = [], []
    guard = threading.Lock()

    def build(*args, **kwargs):
        with guard:
            running.append(1)
            overlapping = len(running) > 1
        start = time.perf_counter()
        time.sleep(0.05)  # long enough for the other threads to arrive
        try:
            return real_build(*args, **kwargs)
        finally:
            with guard:
                running.pop()
                spans.append((start, time.perf_counter(), overlapping))

    monkeypatch.setattr(tables_mod, "build_tables", build)
    results = {}

    def load(name, roughness):
        results[name] = load_or_build(maps_sq, roughness, cache_dir=tmp_path, **CACHE_KW)

    threads = [threading.Thread(target=load, args=(name, r))
               for name, r in (("a", 0.3), ("b", 0.3), ("c", 0.45), ("d", 0.3))]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    assert len(spans) == 2, spans  # 0.3 once, 0.45 once
    assert not any(overlapping for _, _, overlapping in spans)
    for name in "bd":
        _assert_same(results["a"], results[name])
    assert results["c"].key != results["a"].key


def test_default_cache_dir(monkeypatch, tmp_path, maps_sq):
    monkeypatch.setenv("MSCLOTH_CACHE", str(tmp_path / "c"))
    assert default_cache_dir() == tmp_path / "c"
    t = load_or_build(maps_sq, 0.5, **CACHE_KW)
    assert (tmp_path / "c" / f"tables-{t.key}.npz").is_file()
    monkeypatch.delenv("MSCLOTH_CACHE")
    assert default_cache_dir() == __import__("pathlib").Path.home() / ".cache" / "mscloth"


def test_unwritable_cache_still_returns_tables(maps_sq, tmp_path):
    blocker = tmp_path / "file"
    blocker.write_text("not a directory")
    with pytest.warns(RuntimeWarning, match="cannot write"):
        t = load_or_build(maps_sq, 0.3, cache_dir=blocker / "sub", **CACHE_KW)
    assert t.d_sat.shape == (16, 33, 33)


# ====================================================== Dr.Jit queries of the residual SATs
def test_lookup_tables_are_64_byte_aligned_so_packet_reads_stay_packets():
    """Dr.Jit maps NumPy memory without copying, and a table not 64-byte aligned gets no
    packet reads: each ``gather_block`` packet silently became four scalar gathers. Tables
    (float and word) and per-lane inputs come out aligned from any NumPy source, also one
    whose data starts at an odd offset, with their values intact."""
    from mscloth.jit_arrays import flat_array, flat_word_array, gather_block, lane_values

    raw = np.arange(1001, dtype=np.float32)
    for source in (raw[1:], raw[5:].reshape(-1, 2, 2)[:, :, 0], raw[2:].astype(np.uint32)):
        for make in (flat_array, lane_values, flat_word_array):
            arr = make(source)
            view = np.from_dlpack(arr)
            assert view.ctypes.data % 64 == 0, make.__name__
            np.testing.assert_array_equal(view, np.ravel(source).astype(view.dtype))
    table = flat_array(raw[1:])
    got = gather_block(table, mi.UInt32(np.array([0, 8, 96], dtype=np.uint32)), 8)
    np.testing.assert_array_equal(np.stack([np.array(g) for g in got], axis=1),
                                  raw[1:][np.array([0, 8, 96])[:, None] + np.arange(8)])


@pytest.mark.parametrize("layout", ["channel minor", "channel major", "packet planes"])
def test_jit_sat_queries_match_brute_force_on_wrapping_rectangles(layout):
    """The BSDF's O(1) queries (bsdf/sat_queries.py) against float64 summation over the same
    texels: exact fractional corners (bilinear reads) and corners rounded to whole texels
    (packets of four channels), for rectangles inside one tile and rectangles wrapping up to
    3.5 tiles, anywhere (negative coordinates too), mixed in one packet of lanes, so the
    reads of the last row and column that only wrapping corners need are skipped in none
    of the lanes that need them. Every layout: channels innermost (the scalar tables, read
    in packets), one channel's plane whole (the full directional table) and one packet of
    four channels' plane whole (the sky albedo table), two packets each."""
    from mscloth.bsdf.sat_queries import ResidualSATs

    rng = np.random.default_rng(17)
    C, H, W = 8, 24, 40
    img = rng.random((C, H, W)) ** 3 * 5.0
    sats = ResidualSATs(*build_sat(img), channel_major=layout == "channel major",
                        packet_planes=layout == "packet planes")
    n = 400
    x0 = rng.uniform(-3.0 * W, 3.0 * W, n)
    y0 = rng.uniform(-3.0 * H, 3.0 * H, n)
    # Every other lane stays inside one tile; the others span up to 3.5 tiles.
    inside = np.arange(n) % 2 == 0
    x0 = np.where(inside, np.floor(x0 / W) * W + rng.uniform(0.0, 0.4 * W, n), x0)
    y0 = np.where(inside, np.floor(y0 / H) * H + rng.uniform(0.0, 0.4 * H, n), y0)
    wx = np.where(inside, rng.uniform(0.5, 0.5 * W, n), rng.uniform(0.5, 3.5 * W, n))
    wy = np.where(inside, rng.uniform(0.5, 0.5 * H, n), rng.uniform(0.5, 3.5 * H, n))
    x1, y1 = x0 + wx, y0 + wy
    ref = np.array([brute_rect(img, *r) for r in zip(x0, y0, x1, y1)])  # (n, C)
    # float32 SATs of mean-free residuals: error grows with the covered tiles' count.
    tol = 1e-4 * (1.0 + wx * wy / (W * H))[:, None] * np.abs(img).max()

    q = sats.query(*(mi.Float(v.astype(np.float32)) for v in (x0, y0, x1, y1)))
    exact = np.stack([np.array(sats.integral(q, c)) for c in range(C)], axis=1)
    # The float32 corners themselves move by up to ~1e-6 relative: allow for that area.
    slack = (np.abs(x0) + np.abs(x1) + np.abs(y0) + np.abs(y1))[:, None] * 2e-7 * (wx + wy)[:, None] * img.max()
    assert np.all(np.abs(exact - ref) <= tol + slack), np.abs(exact - ref).max()

    # Rounded corners with xi = 0 are floor(): compare with the floored rectangle.
    fx0, fy0, fx1, fy1 = (np.floor(v) for v in (x0, y0, x1, y1))
    ref_floor = np.array([brute_rect(img, *r) for r in zip(fx0, fy0, fx1, fy1)])
    zero = mi.Float(np.zeros(n, np.float32))
    qr = sats.query_rounded(*(mi.Float(v.astype(np.float32)) for v in (x0, y0, x1, y1)), zero, zero)
    packets = np.stack([np.array(v) for v in sats.integrals(qr, 0, C)], axis=1)
    singles = np.stack([np.array(sats.integral(qr, c)) for c in range(C)], axis=1)
    assert np.all(np.abs(packets - ref_floor) <= tol), np.abs(packets - ref_floor).max()
    np.testing.assert_allclose(packets, singles, rtol=1e-6, atol=1e-4)
    # Both kinds of lanes occurred, and the wrapping ones needed the edge reads.
    assert inside.any() and (~inside).any() and (wx > W).any()


class _RecordedWrites:
    """A stream that keeps every ``write`` call apart, to see how lines were written."""

    def __init__(self):
        self.writes = []

    def write(self, text):
        self.writes.append(text)
        return len(text)

    def flush(self):
        pass


def test_parallel_builds_write_whole_progress_lines_with_their_label(maps_sq, maps_rect, monkeypatch):
    """Two cloths' tables built at once (as Mitsuba constructs a scene's plugins): every write
    is one whole progress line carrying its build's label (``print`` wrote the text and its
    newline apart, and lines carried no label)."""
    import re
    import sys
    from concurrent.futures import ThreadPoolExecutor

    stream = _RecordedWrites()
    monkeypatch.setattr(sys, "stderr", stream)
    builds = {"floor.bsdf, plain": maps_sq, "ball.bsdf, twill-2-1": maps_rect}
    with ThreadPoolExecutor(2) as pool:
        list(pool.map(lambda item: build_tables(item[1], 0.3, dr=4, dv=2, clusters=2, workers=2,
                                                label=item[0]), builds.items()))
    line = re.compile(r"mscloth precompute \[([^\]\n]+)\]: [^\n]+\n")
    seen = {label: [] for label in builds}
    for text in stream.writes:
        match = line.fullmatch(text)
        assert match and match.group(1) in builds, repr(text)
        seen[match.group(1)].append(text)
    for label, lines in seen.items():
        assert any("visibility (front)" in t for t in lines) and any("tables built" in t for t in lines), lines
