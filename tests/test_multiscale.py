"""Multi-scale (footprint) shading of the ``cloth`` BSDF against brute force: the Monte Carlo
average of fibre-level evaluations over the same footprint."""
import drjit as dr
import mitsuba as mi
import numpy as np
import pytest

import mscloth
from mscloth import validation
from mscloth.bsdf.footprint_estimator import FootprintEstimator
from mscloth.bsdf.lobes import enabled_lobes

from cloth_fixtures import N_TEXELS, hold_probe, make_si, non_delta_context

mscloth.register()

BASE = {"type": "cloth", "pattern": "plain", "roughness": 0.4, "thickness": 1.5,
        "specular_albedo": 0.5, "specular_transmittance": 0.3, "diffuse_albedo": 0.3,
        "diffuse_transmittance": 0.1, "sheen_thickness": 0.3}

DIRECTIONS = [  # (wi, wo): reflection near the specular cone, off-specular, transmission,
    # and the same seen from the back side (viewer below: the mirrored frame)
    ([0.3, 0.1, 0.95], [-0.4, 0.0, 0.92]),
    ([0.6, -0.2, 0.77], [-0.1, 0.7, 0.7]),
    ([0.2, 0.4, 0.89], [-0.3, -0.2, -0.93]),
    ([0.6, -0.2, -0.77], [-0.1, 0.7, -0.7]),
    ([0.2, 0.4, -0.89], [-0.3, -0.2, 0.93]),
]


def unit(v):
    v = np.asarray(v, dtype=float)
    return (v / np.linalg.norm(v)).tolist()


def footprint_si(n, uv, half_texels, wi):
    return validation.footprint_interaction(n, uv, half_texels, N_TEXELS, wi)


def multiscale_expectation(bsdf, uv, half, wi, wo):
    return validation.footprint_expectation(bsdf, uv, half, N_TEXELS, wi, wo)


def brute_force(params, uv, half, wi, wo):
    return validation.brute_force(params, uv, half, N_TEXELS, wi, wo)


# Half-widths (texels) of square footprints of 1, 4, 16, 64, 256 texels, and one 3.5 tiles wide.
HALVES = [0.5, 1.0, 2.0, 4.0, 8.0, 1.75 * N_TEXELS]

# The stated approximations of the footprint form (docs/architecture.md): D is tabulated on
# 16 x 16 half-vector bins (bilinear), G uses the footprint's mean SGGX matrix, and albedo
# is factored out of the integral. Together they stay within this relative error here.
APPROXIMATION = 0.05


@pytest.mark.parametrize("visibility", [False, True])
@pytest.mark.parametrize("half", HALVES)
@pytest.mark.parametrize("dirs", range(len(DIRECTIONS)))
def test_footprint_matches_brute_force(visibility, half, dirs):
    params = dict(BASE, visibility=visibility)
    bsdf = mi.load_dict(params)
    wi, wo = DIRECTIONS[dirs]
    uv = [0.3, 0.55]
    ms, ms_err, _ = multiscale_expectation(bsdf, uv, half, wi, wo)
    bf, bf_err = brute_force(params, uv, half, wi, wo)
    tolerance = 5.0 * np.hypot(ms_err, bf_err) + APPROXIMATION * abs(bf)
    assert abs(ms - bf) <= tolerance, (ms, bf, tolerance)


def test_sub_texel_footprint_is_the_fibre_level_bsdf():
    """Footprints under POINT_TEXELS texels: the fibre-level BSDF at a point drawn uniformly
    in the footprint's parallelogram."""
    bsdf = mi.load_dict(BASE)
    point = mi.load_dict(dict(BASE, multiscale=False))
    rng = np.random.default_rng(3)
    n = 10000
    wi = rng.normal(size=(n, 3)); wi /= np.linalg.norm(wi, axis=1, keepdims=True)
    wo = rng.normal(size=(n, 3)); wo /= np.linalg.norm(wo, axis=1, keepdims=True)
    uv = rng.random((n, 2))
    si = make_si(mi.Vector3f(*wi.T), mi.Point2f(*uv.T), n)
    si.duv_dx = mi.Vector2f(0.3 / N_TEXELS, 0.0)
    si.duv_dy = mi.Vector2f(0.0, 0.2 / N_TEXELS)
    ctx = mi.BSDFContext()
    a = np.array(bsdf.eval(ctx, si, mi.Vector3f(*wo.T)))
    # The fibre-level BSDF at the point the footprint BSDF drew in the footprint.
    xi = np.array(bsdf.estimator.shading_hash(si)[0])
    uv_drawn = uv + (xi.T - 0.5) * np.array([0.3, 0.2]) / N_TEXELS
    b = np.array(point.eval(ctx, make_si(mi.Vector3f(*wi.T), mi.Point2f(*uv_drawn.T), n), mi.Vector3f(*wo.T)))
    np.testing.assert_allclose(a, b, rtol=1e-5, atol=1e-7)
    # A zero footprint is the fibre-level BSDF at si.uv itself, bit for bit.
    si.duv_dx = mi.Vector2f(0.0, 0.0)
    si.duv_dy = mi.Vector2f(0.0, 0.0)
    a = np.array(bsdf.eval(ctx, si, mi.Vector3f(*wo.T)))
    b = np.array(point.eval(ctx, make_si(mi.Vector3f(*wi.T), mi.Point2f(*uv.T), n), mi.Vector3f(*wo.T)))
    np.testing.assert_array_equal(a, b)


# ---------------------------------------------------------------- sampling the footprint BSDF
from cloth_fixtures import direction, footprint_chi2_adapter  # noqa: E402

CHI2_CASES = [(direction(30, 40), 2.0), (direction(70, 200), 8.0), (direction(50, 120, back=True), 40.0),
              (direction(20, 300), 1.75 * N_TEXELS)]


@pytest.mark.parametrize("wi,half", CHI2_CASES)
def test_chi2_footprint_sampling(wi, half):
    sample_func, pdf_func = footprint_chi2_adapter(BASE, wi, [0.3, 0.55], non_delta_context(), half)
    test = mi.chi2.ChiSquareTest(domain=mi.chi2.SphericalDomain(), sample_func=sample_func, pdf_func=pdf_func,
                                 sample_dim=3, seed=11, sample_count=1_000_000, res=100, ires=16)
    assert test.run(significance_level=0.01, test_count=len(CHI2_CASES)), test.messages


@pytest.mark.parametrize("roughness", [0.4, 0.1])
def test_footprint_furnace_and_weights(roughness):
    """Footprint sampling: mean weight (albedo, delta included) <= 1, and the sample's
    density is eval_pdf's; on shiny fibres too, whose small probes are shaded texel by texel
    and whose sampled direction is weighed at a texel."""
    bsdf = mi.load_dict(dict(BASE, roughness=roughness, specular_albedo=0.6, diffuse_albedo=0.3,
                             diffuse_transmittance=0.1))
    rng = np.random.default_rng(5)
    n = 200_000
    for half in (2.0, 30.0):
        for theta in (0.0, 45.0, 80.0):
            si = footprint_si(n, [0.41, 0.17], half, direction(theta, 33.0))
            # The shading hash's source: each lane its own probe, residual texels and rounding.
            validation.scatter_shading_points(si, rng)
            ctx = mi.BSDFContext()
            bs, w = bsdf.sample(ctx, si, validation.lanes(mi.Float, rng.random(n)),
                                validation.lanes(mi.Point2f, rng.random(n), rng.random(n)))
            w = np.array(w)
            # Weights are finite; single ones may be negative (the control-variate residual
            # is an unbiased, signed estimate), their mean is the albedo.
            assert np.all(np.isfinite(w))
            mean, err = w.mean(axis=1), w.std(axis=1) / np.sqrt(n)
            assert np.all(mean <= 1.0 + 5 * err), (half, theta, mean)
            delta = np.array(mi.has_flag(bs.sampled_type, mi.BSDFFlags.Delta))
            ok = (np.array(bs.pdf) > 0) & ~delta
            value, pdf = bsdf.eval_pdf(ctx, si, bs.wo)
            np.testing.assert_allclose(np.array(bs.pdf)[ok], np.array(pdf)[ok], rtol=1e-4)


@pytest.mark.parametrize("roughness", [0.05, 0.4])
def test_no_nan_on_random_and_degenerate_footprints(roughness):
    bsdf = mi.load_dict(dict(BASE, roughness=roughness))
    rng = np.random.default_rng(6)
    n = 300_000
    wi = rng.normal(size=(n, 3)); wi /= np.linalg.norm(wi, axis=1, keepdims=True)
    wo = rng.normal(size=(n, 3)); wo /= np.linalg.norm(wo, axis=1, keepdims=True)
    si = make_si(validation.lanes(mi.Vector3f, *wi.T), validation.lanes(mi.Point2f, *(rng.random((n, 2)) * 40 - 20).T), n)
    scale = 10.0 ** rng.uniform(-8, 4, size=(n, 4))       # zero-ish to huge
    scale[: n // 10] = 0.0                                 # zero footprints
    scale[n // 10: n // 5, 1:3] = 0.0                      # skewed: a line
    scale[n // 5: n // 4] = np.inf                         # degenerate input
    scale[n // 4: n // 3, 2:] = scale[n // 4: n // 3, :2] * rng.uniform(0.9, 1.1, (n // 3 - n // 4, 1))  # sheared flat
    si.duv_dx = validation.lanes(mi.Vector2f, *scale[:, :2].T)
    si.duv_dy = validation.lanes(mi.Vector2f, *scale[:, 2:].T)
    ctx = mi.BSDFContext()
    value, pdf = bsdf.eval_pdf(ctx, si, validation.lanes(mi.Vector3f, *wo.T))
    bs, w = bsdf.sample(ctx, si, validation.lanes(mi.Float, rng.random(n)),
                        validation.lanes(mi.Point2f, rng.random(n), rng.random(n)))
    for arr in (np.array(value), np.array(pdf), np.array(w), np.array(bs.pdf), np.array(bs.wo)):
        assert np.all(np.isfinite(arr))
    # Footprint evaluations are unbiased control-variate estimates: finite, rarely negative.
    assert np.mean(np.array(value) < 0) < 0.05


def test_footprints_inside_gaps_far_from_the_origin_have_finite_densities():
    """Small footprints hundreds of tiles from the origin, many of them wholly in the
    gaps of a knit: the SAT means' cancellation (~1e-9 below zero) must not reach the
    lobe probabilities (a negative one made the defensive share's root, and so the pdf,
    NaN in 0.15% of these lanes)."""
    bsdf = mi.load_dict({"type": "cloth", "fabric": "cotton-jersey", "uv_scale": 1.0, "uv_scale_v": 1.0})
    h, w_ = bsdf.maps.resolution
    rng = np.random.default_rng(6)
    n = 300_000
    wi = rng.normal(size=(n, 3)); wi[:, 2] = np.abs(wi[:, 2]); wi /= np.linalg.norm(wi, axis=1, keepdims=True)
    wo = rng.normal(size=(n, 3)); wo /= np.linalg.norm(wo, axis=1, keepdims=True)
    si = make_si(mi.Vector3f(*wi.T), mi.Point2f(*(150.0 + rng.random((n, 2)) * 50.0).T), n)
    side = rng.uniform(1.0, 6.0, n)  # texels
    si.duv_dx = mi.Vector2f(side / w_, 0.0)
    si.duv_dy = mi.Vector2f(0.0, side / h)
    ctx = mi.BSDFContext()
    value, pdf = bsdf.eval_pdf(ctx, si, mi.Vector3f(*wo.T))
    bs, weight = bsdf.sample(ctx, si, mi.Float(rng.random(n)), mi.Point2f(rng.random(n), rng.random(n)))
    for arr in (np.array(value), np.array(pdf), np.array(weight), np.array(bs.pdf)):
        assert np.all(np.isfinite(arr))
    assert np.all(np.array(pdf) >= 0.0)


def test_parallax_shifts_the_lookup_to_the_table_offset():
    """With parallax, the fibre-level BSDF at uv equals the BSDF without parallax at the
    texel the precomputed view ray reaches (the table's offset for that view direction)."""
    from mscloth.maps.builtin import resolve_pattern
    from mscloth.precompute.direction_bins import bin_centres
    from mscloth.precompute.tables import load_or_build

    params = dict(BASE, multiscale=False, visibility=False)
    shifted = mi.load_dict(dict(params, parallax=True))
    plain_bsdf = mi.load_dict(params)
    tables = load_or_build(resolve_pattern("plain"), BASE["roughness"], dr=16, dv=8, clusters=8,
                           per_cluster_sat=False, parallax=True)
    wi = bin_centres(8)[10]  # a bin centre: the bilinear lookup returns that bin exactly
    assert wi[2] < 0.9       # oblique enough for a real offset
    r, c = 40, 70
    dx, dy = (float(v) for v in tables.parallax[r, c, 10])
    assert abs(dx) + abs(dy) > 0.5
    ctx = non_delta_context()
    wo = mi.Vector3f(unit([-0.2, 0.3, 0.9]))
    at = make_si(mi.Vector3f(*[float(v) for v in wi]), mi.Point2f((c + 0.5) / N_TEXELS, (r + 0.5) / N_TEXELS), 1)
    moved = make_si(mi.Vector3f(*[float(v) for v in wi]),
                    mi.Point2f((c + 0.5 + dx) / N_TEXELS, (r + 0.5 + dy) / N_TEXELS), 1)
    np.testing.assert_allclose(np.array(shifted.eval(ctx, at, wo)), np.array(plain_bsdf.eval(ctx, moved, wo)),
                               rtol=1e-5)
    assert not np.allclose(np.array(shifted.eval(ctx, at, wo)), np.array(plain_bsdf.eval(ctx, at, wo)))


@pytest.mark.parametrize("half", [2.0, 16.0])
def test_rank_compressed_directional_sat_matches_brute_force(half):
    """direction_rank = 64: the compressed table's footprint eval against brute force, with
    the same tolerance as the full table's."""
    params = dict(BASE, direction_rank=64)
    bsdf = mi.load_dict(params)
    assert bsdf.footprint_data.d_rank == 64
    wi, wo = DIRECTIONS[1]
    ms, ms_err, _ = multiscale_expectation(bsdf, [0.3, 0.55], half, wi, wo)
    bf, bf_err = brute_force(params, [0.3, 0.55], half, wi, wo)
    assert abs(ms - bf) <= 5.0 * np.hypot(ms_err, bf_err) + APPROXIMATION * abs(bf), (ms, bf)


def test_choose_direction_rank_keeps_tables_within_the_budget():
    from mscloth.precompute.tables import AUTO_RANK, choose_direction_rank

    # 512^2 at 32^2 bins: 1028 MiB full -> rank 64 (64 MiB); 256^2 at 16^2: 64 MiB, full.
    rank, why = choose_direction_rank(512, 512, 32, 0, 256)
    assert rank == AUTO_RANK and "1028 MiB" in why and "rank 64" in why
    assert choose_direction_rank(256, 256, 16, 0, 256) == (0, "")
    # An explicit rank is kept; a budget below rank 64 gets the largest multiple of 4 that fits.
    assert choose_direction_rank(512, 512, 32, 24, 16) == (24, "")
    assert choose_direction_rank(512, 512, 32, 0, 16)[0] == 12


def test_a_full_table_over_max_table_mib_is_compressed(monkeypatch, tmp_path):
    """A 64^2 tile at 32^2 bins (16.5 MiB full) with a 16 MiB budget is built at rank 64, with
    a warning that names the budget and what to set (an empty cache: it warns when built)."""
    monkeypatch.setenv("MSCLOTH_CACHE", str(tmp_path / "cache"))
    with pytest.warns(RuntimeWarning, match=r"max_table_mib 16: using rank 64.*set direction_rank or max_table_mib"):
        bsdf = mi.load_dict(dict(BASE, resolution=64, direction_bins=32, max_table_mib=16))
    assert bsdf.maps.resolution == (64, 64)
    assert bsdf.direction_rank == 64 and bsdf.footprint_data.d_rank == 64
    roomy = mi.load_dict(dict(BASE, resolution=64, direction_bins=32, max_table_mib=17))
    assert roomy.direction_rank == 0 and roomy.footprint_data.d_rank == 0


def test_default_ccv_base_is_unbiased_over_whole_tiles(monkeypatch):
    """The default base weights each cluster's visibility by its share of the footprint's
    D (footprint share x the cluster's tile mean of D): over a footprint of one whole tile
    it is the per-cluster (unbiased) base, where Alg. 4's mean over the residual texels is
    off by -Cov(D, v) (-1.3% here). Expectations over 20k evaluations of 2x2 residual
    texels each (the grid moves the noise, not the expectation)."""
    from mscloth.bsdf.footprint_estimator import FootprintEstimator
    from mscloth.validation import footprint_expectation

    monkeypatch.setattr(FootprintEstimator, "RESIDUAL_GRID", 2)

    wi, wo, uv = unit([0.75, 0.1, 0.4]), unit([-0.7, 0.0, 0.45]), [0.3, 0.55]
    default = mi.load_dict(BASE)
    unbiased = mi.load_dict(dict(BASE, unbiased_ccv=True))
    alg4 = mi.load_dict(BASE)
    alg4.footprint_data.d_cluster_tile = None  # the fallback: Alg. 4's base
    tile = default.maps.resolution[1]
    half = tile / 2.0
    (d, d_err, _), (u, u_err, _), (a, a_err, _) = (
        footprint_expectation(b, uv, half, tile, wi, wo) for b in (default, unbiased, alg4))
    assert abs(d - u) <= 5.0 * np.hypot(d_err, u_err) + 1e-3 * u, (d, u)
    assert abs(a - u) > 5.0 * np.hypot(a_err, u_err) + 5e-3 * u, (a, u)  # what the weights fix


def test_cluster_tile_means_add_up_to_the_tile_mean():
    """sum_c (cluster share of the tile) x (cluster's mean D gap) = the tile's mean D gap,
    per bin, for the full and the rank-compressed tables alike."""
    from mscloth.maps.woven import woven_maps
    from mscloth.patterns.weaves import twill
    from mscloth.precompute.tables import build_tables

    maps = woven_maps(twill(2, 1), 96)
    full = build_tables(maps, 0.3, dr=8, progress=False)
    total = full.cluster_mean @ full.d_cluster_tile.T.astype(np.float64)
    np.testing.assert_allclose(total, full.d_mean, rtol=1e-5)
    ranked = build_tables(maps, 0.3, dr=8, d_rank=12, progress=False)
    np.testing.assert_array_equal(ranked.d_cluster_tile, full.d_cluster_tile)


def test_direction_rank_must_fit_the_bins():
    with pytest.raises(Exception, match="direction_rank"):
        mi.load_dict(dict(BASE, direction_bins=4, direction_rank=17))


def test_sat_queries_far_from_the_origin_keep_their_precision():
    """A finely tiled surface puts footprints hundreds of tiles from the texel origin (the
    `plane` scene: uv_scale 500). A 1-texel box there must read what it reads in the first
    tile: the periodic decomposition used to multiply the tile counts into float32 edge
    sums and lost up to 27% of small values (0.07 absolute) at 300-800 tiles."""
    from mscloth.bsdf.sat_queries import ResidualSATs
    from mscloth.precompute.summed_area import build_sat

    rng = np.random.default_rng(3)
    H, W = 96, 128
    img = rng.random((4, H, W)) ** 4 * 10.0  # peaky, like D
    sats = ResidualSATs(*build_sat(img))
    n = 2000
    x0 = rng.integers(0, W, n).astype(np.float64)
    y0 = rng.integers(0, H, n).astype(np.float64)
    far_x = x0 + rng.integers(300, 800, n) * W
    far_y = y0 + rng.integers(300, 800, n) * H
    ref = img[1, y0.astype(int), x0.astype(int)]
    zero = mi.Float(0.0)
    for X, Y in ((x0, y0), (far_x, far_y)):
        q = sats.query_rounded(mi.Float(X), mi.Float(Y), mi.Float(X + 1), mi.Float(Y + 1), zero, zero)
        got = np.array(sats.integral(q, 1))
        # float32 residual SATs of this tile: ~1e-4 absolute (test_precompute's bound).
        assert np.abs(got - ref).max() < 2e-4
        # Packet reads of four channels (rank-K tables) agree with one-channel reads.
        q3 = sats.query_rounded(mi.Float(X), mi.Float(Y), mi.Float(X + 3), mi.Float(Y + 2), zero, zero)
        for c, packet in enumerate(sats.integrals(q3, 0, 4)):
            np.testing.assert_allclose(np.array(packet), np.array(sats.integral(q3, c)), rtol=1e-6, atol=1e-6)


@pytest.mark.parametrize("packet_planes", [False, True])
def test_exact_sat_queries_integrate_fractional_boxes_in_packets_and_alone(packet_planes):
    """Boxes at exact (fractional) corners, inside a tile and across its edges (periodic):
    packet reads of four channels (from a fixed channel and from one per lane, as the sky
    albedo table reads its nodes), one-channel reads and the float64 integral of the
    piecewise-constant image agree (the exact corners of shiny cloth's probes), with
    channels innermost and by planes of four."""
    from mscloth.bsdf.sat_queries import ResidualSATs
    from mscloth.precompute.summed_area import ResidualSAT, build_sat

    rng = np.random.default_rng(11)
    H, W = 24, 40
    img = rng.random((8, H, W)) ** 3 * 5.0
    sats = ResidualSATs(*build_sat(img), packet_planes=packet_planes)
    reference = ResidualSAT.build(img.astype(np.float64))
    n = 64
    x0 = rng.uniform(-10.0, 70.0, n)
    y0 = rng.uniform(-10.0, 50.0, n)
    x1 = x0 + rng.uniform(0.3, 30.0, n)
    y1 = y0 + rng.uniform(0.3, 30.0, n)
    q = sats.query(*(mi.Float(v) for v in (x0, y0, x1, y1)))
    assert not q.on_grid
    want = np.array([reference.rect_sum(*box) for box in zip(x0, y0, x1, y1)])  # (n, channels)
    packets = [np.array(v) for v in sats.integrals(q, 4, 4)]
    for j, packet in enumerate(packets):
        single = np.array(sats.integral(q, 4 + j))
        np.testing.assert_allclose(packet, single, rtol=1e-5, atol=1e-4)
        np.testing.assert_allclose(packet, want[:, 4 + j], rtol=1e-4, atol=2e-3)
    first = np.where(np.arange(n) % 3 == 0, 0, 4).astype(np.uint32)
    per_lane = [np.array(v) for v in sats.integrals(q, mi.UInt32(first), 4, aligned=True)]
    for j, packet in enumerate(per_lane):
        np.testing.assert_allclose(packet, want[np.arange(n), first + j], rtol=1e-4, atol=2e-3)


# ---------------------------------------------------------------- sheared footprints (probes)
def sheared_si(n, uv, a_texels, shear, wi, curvature=0.0):
    """A pixel footprint with edges a = (a, 0) and b = (shear * a, a) texels: the parallelogram
    a perspective camera gives towards the image's sides (on a surface whose normal turns by
    ``curvature`` radians per UV unit)."""
    return validation.sheared_interaction(n, uv, a_texels, shear, N_TEXELS, wi, curvature=curvature)


#: A curvature in radians per UV unit (a 40-texel pixel of the 128-texel tile: 0.6 rad).
CURVED = 2.0


def probe_boxes(bsdf, si, u_probe):
    fp = bsdf.estimator.footprint(si, bsdf.fibre.frame(si, True), mi.Float(0.0), mi.Float(u_probe))
    return np.array([np.asarray(v) for v in fp.box]).T  # (n, 4)


@pytest.mark.parametrize("a,shear", [(12.0, 0.9), (40.0, 3.0), (12.0, 0.0), (30.0, -0.2), (3.0, 1.0)])
def test_footprint_probes_tile_the_pixel_parallelogram(a, shear):
    """The probes of a pixel's parallelogram (edges (a, 0) and (shear a, a) texels): slices
    of it, each shaded as the box of its own area and centre. Together they have the
    parallelogram's area and cover almost all of it (their boxes cut the slices' slanted ends,
    as far as they reach beyond them), exactly the rectangle where it is not sheared; the
    probes' centres are symmetric about the pixel's centre (CELLS x CELLS or more cells)."""
    bsdf = mi.load_dict(BASE)
    uv = [0.3, 0.55]
    m = 64
    u = (np.arange(m) + 0.5) / m
    boxes = np.unique(probe_boxes(bsdf, sheared_si(m, uv, a, shear, [0.2, 0.1, 0.97]), u), axis=0)
    n = len(boxes)
    assert 1 <= n <= bsdf.estimator.MAX_PROBES * bsdf.estimator.CELLS
    rng = np.random.default_rng(8)
    s, t = rng.random(20000) - 0.5, rng.random(20000) - 0.5
    c = np.array(uv) * N_TEXELS
    pts = c + np.outer(s, [a, 0.0]) + np.outer(t, [shear * a, a])
    eps = 1e-3
    inside = ((pts[:, None, 0] >= boxes[None, :, 0] - eps) & (pts[:, None, 0] <= boxes[None, :, 2] + eps)
              & (pts[:, None, 1] >= boxes[None, :, 1] - eps) & (pts[:, None, 1] <= boxes[None, :, 3] + eps))
    covered = inside.any(axis=1).mean()
    assert covered >= 0.85, covered
    probe_area = ((boxes[:, 2] - boxes[:, 0]) * (boxes[:, 3] - boxes[:, 1])).sum()
    if np.all(boxes[:, 2:] - boxes[:, :2] > 1.0 + 1e-4):
        np.testing.assert_allclose(probe_area, a * a, rtol=1e-4)
    else:  # a probe is at least a texel wide
        assert probe_area >= a * a * (1 - 1e-4)
    if shear == 0.0:  # axis-aligned: pieces of the rectangle itself
        assert covered == 1.0
    # The cells' centres: a grid symmetric about the pixel's centre, inside the parallelogram.
    centres = 0.5 * (boxes[:, :2] + boxes[:, 2:]) - c
    np.testing.assert_allclose(centres.mean(axis=0), 0.0, atol=1e-3 * a)
    inv = np.linalg.inv(np.array([[a, shear * a], [0.0, a]]))
    st = centres @ inv.T
    assert np.all(np.abs(st) < 0.5), st


@pytest.mark.parametrize("curvature", [CURVED, 0.0])
@pytest.mark.parametrize("pixel_filter", ["box", "tent"])
def test_pixel_filter_places_probes_and_points(pixel_filter, curvature):
    """Camera samples at known places in their pixel, on a stratified 64 x 64 grid: on
    curved cloth with the box the probes are the 2 x 2 cells of a square footprint (offsets
    +-1/4 pixel: variance 1/16), on flat cloth the whole footprint (variance 0); the
    fibre-level points are the samples' own (variance 1/12). With clothpath's ``uv_filter``
    tent each probe also moves by a tent offset (variance + 1/6) and each point sits at the
    quadratic B-spline's quantile (box x tent: 1/12 + 1/6). Means stay at the pixel centre."""
    bsdf = mi.load_dict(BASE)
    m = 64
    g = (np.arange(m) + 0.5) / m - 0.5
    ox, oy = (v.ravel() for v in np.meshgrid(g, g))
    a = 40.0
    si = sheared_si(ox.size, [0.3, 0.55], a, 0.0, [0.2, 0.1, 0.97], curvature)
    fr = bsdf.fibre.frame(si, True, mi.Point2f(ox, oy), pixel_filter)
    fp = bsdf.estimator.footprint(si, fr, mi.Float(0.0))
    x0, y0, x1, y1 = (np.asarray(v) for v in fp.box)
    centre = np.array([0.3, 0.55]) * N_TEXELS
    probe = np.stack([0.5 * (x0 + x1), 0.5 * (y0 + y1)], axis=1) - centre  # texels
    point = np.stack([np.asarray(fp.point_xi.x), np.asarray(fp.point_xi.y)], axis=1) - 0.5  # pixels
    assert np.all(np.asarray(fp.use)) and np.all(np.asarray(fp.point_known))
    tent = 1.0 / 6.0 if pixel_filter == "tent" else 0.0
    np.testing.assert_allclose(probe.mean(axis=0) / a, 0.0, atol=2e-3)
    np.testing.assert_allclose(point.mean(axis=0), 0.0, atol=2e-3)
    cells = 1.0 / 16.0 if curvature else 0.0
    np.testing.assert_allclose((probe / a).var(axis=0), cells + tent, rtol=0.02, atol=1e-9)
    np.testing.assert_allclose(point.var(axis=0), 1.0 / 12.0 + tent, rtol=0.02)


def test_long_footprints_get_cells_across_on_curved_rough_cloth_only():
    """A footprint cut into MAX_PROBES slices keeps one cell across on shiny fibres (a
    second multiplied satin-plane's noise) and gets CELLS across on rough ones where the
    surface is curved (the sample's cell keeps its texels with their normal): twice the
    distinct probes there. On flat cloth, and on a surface that turns by less than
    CELLS_TILT across the pixel, one cell (less variance between probes)."""
    a, shear = 40.0, 3.0
    # The pixel's longer edge, (shear a, a) texels, in UV units: where the normal turns most.
    edge = a * np.hypot(shear, 1.0) / N_TEXELS
    tilt = FootprintEstimator.CELLS_TILT
    surfaces = {"curved": CURVED, "just curved": 2.0 * tilt / edge, "slightly curved": 0.5 * tilt / edge, "flat": 0.0}
    counts = {}
    for roughness in (0.1, 0.3):
        bsdf = mi.load_dict(dict(BASE, roughness=roughness))
        for name, curvature in surfaces.items():
            m = 512
            si = sheared_si(m, [0.3, 0.55], a, shear, [0.2, 0.1, 0.97], curvature)
            boxes = probe_boxes(bsdf, si, (np.arange(m) + 0.5) / m)
            counts[roughness, name] = len(np.unique(boxes, axis=0))
    n = FootprintEstimator.MAX_PROBES
    expected = {(r, name): n * (FootprintEstimator.CELLS if r == 0.3 and name in ("curved", "just curved") else 1)
                for r in (0.1, 0.3) for name in surfaces}
    assert counts == expected, counts


@pytest.mark.parametrize("a,shear", [(10.0, 0.8), (6.0, 2.5)])
def test_sheared_footprint_matches_brute_force_over_the_parallelogram(a, shear):
    """The footprint BSDF with its probe drawn uniformly is the mean of the fibre-level BSDF
    over the pixel's parallelogram (not its bounding box), within the same tolerance as
    square footprints, with visibility."""
    params = dict(BASE)
    bsdf = mi.load_dict(params)
    ctx = non_delta_context()
    uv = [0.3, 0.55]
    for wi, wo in DIRECTIONS[:3]:
        n = 20000
        si = sheared_si(n, uv, a, shear, unit(wi))
        fr = bsdf.fibre.frame(si, True)
        enabled = enabled_lobes(ctx)
        rng = np.random.default_rng(12)
        numbers = (validation.lanes(mi.Point2f, rng.random(n), rng.random(n)),
                   validation.lanes(mi.Point2f, rng.random(n), rng.random(n)), validation.lanes(mi.Float, rng.random(n)))
        st = bsdf.estimator.state(si, fr, enabled, *numbers)
        ms = np.array(bsdf.estimator.eval(fr, st, fr.mirror(validation.direction(wo, n)), enabled))[0]
        bf_mean, bf_err = validation.parallelogram_brute_force(params, uv, a, shear, N_TEXELS, wi, wo)
        ms_mean, ms_err = ms.mean(), ms.std() / np.sqrt(n)
        tolerance = 5.0 * np.hypot(ms_err, bf_err) + APPROXIMATION * abs(bf_mean)
        assert abs(ms_mean - bf_mean) <= tolerance, (wi, wo, ms_mean, bf_mean, tolerance)


@pytest.mark.parametrize("roughness, blend", [(None, (16.0, 32.0)), (0.1, (1.0, 2.0))], ids=["rough", "shiny"])
def test_small_footprints_blend_into_fibre_level_shading(roughness, blend):
    """The share of lanes shaded as a footprint rises linearly from 0 at POINT_TEXELS
    texels to 1 at FOOTPRINT_TEXELS, by the footprint's area (square, sheared, a line);
    shiny cloth (exact SAT corners) blends at 1 to 2 texels (BLEND_TEXELS_BY_ROUGHNESS)."""
    bsdf = mi.load_dict(BASE if roughness is None else dict(BASE, roughness=roughness))
    n = 20000
    lo, hi = bsdf.estimator.blend_texels()
    assert (lo, hi) == blend
    for texels in (1.0, lo, 0.5 * (lo + hi), 0.75 * lo + 0.25 * hi, hi, 4 * hi):
        for shear in (0.0, 1.5):
            side = float(np.sqrt(texels))
            si = sheared_si(n, [0.3, 0.55], side, shear, [0.2, 0.1, 0.97])
            si.uv = mi.Point2f(*np.random.default_rng(1).random((2, n)))
            si.p = mi.Point3f(*np.random.default_rng(2).random((3, n)))
            # A skew this large makes the longer edge the sheared one; its width shrinks.
            length = side * max(1.0, np.hypot(shear, 1.0))
            covered = max(length, 1.0) * max(side * side / length, 1.0)
            expected = np.clip((covered - lo) / (hi - lo), 0.0, 1.0)
            use = np.array(bsdf.estimator.footprint(si, bsdf.fibre.frame(si, True), bsdf.estimator.shading_hash(si)[2]).use)
            assert abs(use.mean() - expected) <= 5.0 * np.sqrt(expected * (1 - expected) / n) + 1e-9, \
                (texels, shear, use.mean(), expected)


@pytest.mark.parametrize("dv", [4, 8, 12])
def test_packed_visibility_reads_the_table(dv):
    """Visibility is stored as one bit per texel and direction bin (the table holds 0 or
    255): a lookup is the bilinear mix over its four bins of table / 255, front and back,
    for bins in any 32-bit word of a texel's block: one packet of four words up to 8x8
    bins (4: one word per side, 8: two), a word per bin above (12: five per side)."""
    from mscloth.bsdf.footprint_data import FootprintData
    from mscloth.bsdf.sat_queries import hemisphere_bins
    from mscloth.maps.builtin import resolve_pattern
    from mscloth.precompute.tables import load_or_build

    tables = load_or_build(resolve_pattern("plain"), BASE["roughness"], dr=16, dv=dv, clusters=8)
    fd = FootprintData(tables, with_sats=False, with_parallax=False)
    assert fd.packed_visibility == (dv <= 8)
    rng = np.random.default_rng(21)
    n = 5000
    H, W = tables.visibility.shape[:2]
    ix, iy = rng.integers(0, W, n), rng.integers(0, H, n)
    w = rng.normal(size=(n, 3))
    w[:, 2] = np.abs(w[:, 2])
    w /= np.linalg.norm(w, axis=1, keepdims=True)
    back = rng.random(n) < 0.5
    wv = mi.Vector3f(*w.T)
    got = np.array(fd.visibility_at(mi.UInt32(ix), mi.UInt32(iy), wv, mi.Bool(back)))
    bins, weights = hemisphere_bins(wv, dv)
    table = np.where(back[:, None], tables.visibility_back[iy, ix], tables.visibility[iy, ix]) / 255.0
    expected = sum(np.array(wt) * table[np.arange(n), np.array(b)] for b, wt in zip(bins, weights))
    assert np.ptp(expected) > 0.5  # shadowed and lit texels both occur
    np.testing.assert_allclose(got, expected, atol=1e-6)


def test_triangle_bins_match_the_tables():
    """The BSDF's three direction bins and weights around h (Dr.Jit) are the tables'
    (:func:`mscloth.precompute.direction_bins.triangle_bins`, NumPy), edges and the zenith
    included: the residual's control variate and the base then interpolate alike."""
    from mscloth.bsdf.sat_queries import hemisphere_triangle_bins
    from mscloth.precompute.direction_bins import fold_upper, hemisphere_to_square, triangle_bins

    rng = np.random.default_rng(31)
    w = rng.normal(size=(4000, 3))
    w[:, 2] = np.abs(w[:, 2])
    w[:8] = [[0, 0, 1], [1, 0, 1e-7], [0, 1, 1e-7], [-1, 0, 1e-7], [0, -1, 1e-7], [1, 1, 1], [1, -1, 0.1],
             [-0.3, 0.2, 0.9]]
    w /= np.linalg.norm(w, axis=1, keepdims=True)
    for n in (8, 16, 32):
        bins, weights = hemisphere_triangle_bins(mi.Vector3f(*w.T), n)
        got = np.zeros((len(w), n * n))
        for b, wt in zip(bins, weights):
            np.add.at(got, (np.arange(len(w)), np.array(b)), np.array(wt))
        idx, wts = triangle_bins(hemisphere_to_square(fold_upper(w)), n)
        expected = np.zeros_like(got)
        np.add.at(expected, (np.arange(len(w))[:, None], idx), wts)
        np.testing.assert_allclose(got, expected, atol=2e-5)


def test_the_square_map_is_mitsubas_with_constant_components():
    """sat_queries.hemisphere_to_square, which every direction bin read goes through, gives
    Mitsuba's uniform_hemisphere_to_square to the bit on computed directions, and the
    scalar variant's values where x or y is a literal 0 beside a computed z, also inside a
    symbolic if. Mitsuba's own map returns y = -0.080 instead of 0.5 at (-0.4, 0, 0.9) then
    (LLVM folds the sign of select(|x| > 0, x, 0))."""
    from mscloth.bsdf.sat_queries import hemisphere_to_square

    rng = np.random.default_rng(41)
    w = rng.normal(size=(4096, 3))
    w[:, 2] = np.abs(w[:, 2])
    w[:6] = [[0, 0, 1], [0.5, 0, 0.5], [0, -0.5, 0.5], [-1e-7, 1e-7, 1], [-0.0, -0.0, 1], [0.5, -0.0, 0.5]]
    w /= np.linalg.norm(w, axis=1, keepdims=True)
    wv = validation.lanes(mi.Vector3f, *w.T)
    np.testing.assert_array_equal(np.array(hemisphere_to_square(wv)), np.array(mi.warp.uniform_hemisphere_to_square(wv)))

    n = 16
    inside = validation.constants(mi.Float, n, 1.0) > 0.5

    @dr.syntax
    def in_branch(square, inside, x, y, z):  # (dr.syntax functions see no closure)
        p = mi.Point2f(0.0)
        if inside:
            p = square(mi.Vector3f(x, y, z))
        return p

    for x, y in ((-0.4, 0.0), (0.0, -0.4), (0.4, 0.0), (0.0, 0.4), (0.0, 0.0), (-0.3, -0.3)):
        s = 1.0 / float(np.sqrt(x * x + y * y + 0.81))
        expected = mi.scalar_rgb.warp.uniform_hemisphere_to_square(mi.scalar_rgb.Vector3f(x * s, y * s, 0.9 * s))
        z = validation.constants(mi.Float, n, 0.9 * s)
        for got in (hemisphere_to_square(mi.Vector3f(x * s, y * s, z)), in_branch(hemisphere_to_square, inside, x * s, y * s, z)):
            np.testing.assert_allclose(np.array(got), np.tile(np.array(expected)[:, None], n), atol=1e-6)


def test_footprint_means_are_means_and_lobe_choices_a_distribution(monkeypatch):
    """Footprints of 1-5 texels anywhere, sheared or not: the SAT means of the rounded box
    are averages (yarn coverage and cluster shares in [0, 1], the shares summing to the
    coverage) and the sampling mixture's lobe probabilities are >= 0 and sum to 1. Means
    normalised by the exact area instead read 0.54-1.62 for a gap-free footprint of 2.3
    texels, and the gap lobe's probability reached -39. (Boxes this small are the cells of
    larger footprints; the blend is set to start at 1 texel so that they are shaded whole.)"""
    from mscloth.bsdf.footprint_estimator import FootprintEstimator
    monkeypatch.setattr(FootprintEstimator, "POINT_TEXELS", 1.0)
    monkeypatch.setattr(FootprintEstimator, "FOOTPRINT_TEXELS", 2.0)
    bsdf = mi.load_dict(BASE)
    rng = np.random.default_rng(12)
    n = 20000
    w = rng.normal(size=(n, 3)); w[:, 2] = np.abs(w[:, 2]) + 0.05
    w /= np.linalg.norm(w, axis=1, keepdims=True)
    si = make_si(mi.Vector3f(*w.T), mi.Point2f(*rng.random((2, n))), n)
    si.p = mi.Point3f(*rng.random((3, n)))
    size = rng.uniform(1.0, 5.0, (4, n)) * rng.choice([-1.0, 1.0], (4, n)) / N_TEXELS
    size[1] *= rng.random(n) < 0.5  # half of them axis-aligned
    size[2] *= rng.random(n) < 0.5
    si.duv_dx = mi.Vector2f(size[0], size[1])
    si.duv_dy = mi.Vector2f(size[2], size[3])
    fr = bsdf.fibre.frame(si, True)
    st = bsdf.estimator.state(si, fr, [True] * 6)
    use = np.array(bsdf.estimator.footprint(si, fr, bsdf.estimator.shading_hash(si)[2]).use)
    assert use.mean() > 0.3
    yarn = np.array(st.yarn_mean)[use]
    shares = np.array([np.array(f) for f in st.fractions])[:, use]
    assert yarn.min() >= -1e-5 and yarn.max() <= 1.0 + 1e-5
    assert shares.min() >= -1e-5
    np.testing.assert_allclose(shares.sum(axis=0), yarn, atol=2e-5)
    probs = np.array([np.array(p) for p in st.probs])[:, use]
    assert probs.min() >= 0.0
    np.testing.assert_allclose(probs.sum(axis=0), 1.0, atol=1e-5)


def test_lanes_marked_exact_shade_small_footprints_whole():
    """Where a shading point's emitter directions are shaded texel by texel (``exact``),
    footprints blend into fibre-level shading between EXACT_BLEND_TEXELS (1 and 2 texels:
    the texel-by-texel probe has no noise at the sun, which a point sample keeps); other
    lanes between POINT_TEXELS and FOOTPRINT_TEXELS (16 and 32)."""
    bsdf = mi.load_dict(dict(BASE, roughness=0.33))
    estimator = bsdf.estimator
    point_exact, whole_exact = estimator.EXACT_BLEND_TEXELS
    point, whole = estimator.blend_texels()
    assert whole_exact < point
    n = 4096
    u = mi.Float((np.arange(n) + 0.5) / n)
    marked = mi.Bool(np.arange(n) % 2 == 0)
    wi = unit([0.2, 0.1, 0.97])
    for side in (0.5, 1.2, 3.0, 20.0, 40.0):  # texels across a square pixel
        si = sheared_si(n, [0.3, 0.55], side, 0.0, wi)
        fr = bsdf.fibre.frame(si, True)
        use = np.asarray(estimator.footprint(si, fr, u, exact_emitters=marked).use)
        texels = max(side, 1.0) ** 2
        share = lambda lo, hi: np.clip((texels - lo) / (hi - lo), 0.0, 1.0)  # noqa: E731
        # u is uniform over each half of the lanes: the share that takes the footprint.
        assert abs(use[0::2].mean() - share(point_exact, whole_exact)) <= 2.0 / n, side
        assert abs(use[1::2].mean() - share(point, whole)) <= 2.0 / n, side
    # Without marks, every lane blends as the unmarked ones.
    si = sheared_si(n, [0.3, 0.55], 3.0, 0.0, wi)
    assert not np.any(np.asarray(estimator.footprint(si, bsdf.fibre.frame(si, True), u).use))


def test_shade_hands_the_exact_mark_to_the_blend(monkeypatch):
    """Through ``shade``: a flat 3 x 3 texel pixel is shaded whole where its emitter
    directions are marked exact (one probe, texel by texel: one value) and at the sample's
    own fibre-level point elsewhere (a value per point)."""
    bsdf = mi.load_dict(dict(BASE, roughness=0.33))
    n = 4096
    wi, wo = (unit(d) for d in DIRECTIONS[1])
    si = sheared_si(n, [0.3, 0.55], 3.0, 0.0, wi)
    rng = np.random.default_rng(12)
    validation.scatter_shading_points(si, rng)
    hold_probe(monkeypatch, n)
    enabled = enabled_lobes(non_delta_context())
    samples = (mi.Float(rng.random(n)), mi.Point2f(rng.random(n), rng.random(n)))
    marked = mi.Bool(np.arange(n) % 2 == 0)
    values, _, _ = bsdf.shading.shade(enabled, si, [mi.Vector3f(wo)], samples, True, exact_wos=marked)
    v = np.array(values[0])[0]
    exact, point = v[0::2], v[1::2]
    assert np.std(exact) < 1e-5 * np.mean(exact), np.std(exact)
    assert np.std(point) > 0.05 * np.mean(point), np.std(point)


def test_emitter_directions_marked_exact_shade_rough_probes_texel_by_texel(monkeypatch):
    """Where clothpath marks a first hit's emitter directions exact (``exact_wos``: a sun over
    a dim sky), rough cloth's probes of few texels are shaded texel by texel there: one
    probe, one value, the mean the SAT means and residual texels estimate. Their sampled
    direction is weighed at the texel that lent its tangent (``EMITTER_COVERED_AT_TEXEL``):
    the same expectation of weight x g(wo) as the footprint's f / p (g: 1, the transmitted
    side, a lobe around the mirror direction), different values, and the density reported
    for MIS the mixture's. Lanes not marked keep the SAT estimate and its sample."""
    bsdf = mi.load_dict(dict(BASE, roughness=0.33))
    estimator = bsdf.estimator
    limit = estimator.emitter_covered_texels()
    assert limit > 0 and estimator.covered_texels() == 0
    n = 65536
    wi, wo = (unit(d) for d in DIRECTIONS[1])
    # A 6 x 6 texel pixel on curved cloth: 2 x 2 cells, probes of 9 texels.
    si = sheared_si(n, [0.3, 0.55], 6.0, 0.0, wi, CURVED)
    rng = np.random.default_rng(9)
    validation.scatter_shading_points(si, rng)
    # Every lane's probe the same (the hash's probe number held); its residual texels and
    # rounding its own.
    hold_probe(monkeypatch, n)
    fr = bsdf.fibre.frame(si, True)
    counts = np.array(estimator.footprint(si, fr, mi.Float(0.0)).covered_count())
    assert np.all((counts >= 4) & (counts <= limit)), counts
    enabled = enabled_lobes(non_delta_context())
    samples = (mi.Float(rng.random(n)), mi.Point2f(rng.random(n), rng.random(n)))
    marked = mi.Bool(np.arange(n) % 2 == 0)
    values, _, (bs, weight) = bsdf.shading.shade(enabled, si, [mi.Vector3f(wo)], samples, True, exact_wos=marked)
    plain, _, (bs0, weight0) = bsdf.shading.shade(enabled, si, [mi.Vector3f(wo)], samples, True)
    v, v0 = np.array(values[0])[0], np.array(plain[0])[0]
    exact, rest = v[0::2], v[1::2]
    assert np.std(exact) < 1e-5 * np.mean(exact), np.std(exact)  # one probe, one value
    assert np.std(v0) > 1e-3 * np.mean(v0), np.std(v0)  # the SAT estimate varies
    np.testing.assert_array_equal(rest, v0[1::2])
    # Both estimate the same mean over the probe.
    assert abs(np.mean(exact) - np.mean(v0)) <= 5.0 * np.std(v0) / np.sqrt(n) + 1e-6, (np.mean(exact), np.mean(v0))
    wo_s, wo_s0 = np.array(bs.wo), np.array(bs0.wo)
    w, w0 = np.array(weight)[0], np.array(weight0)[0]
    np.testing.assert_allclose(wo_s[:, 1::2], wo_s0[:, 1::2], rtol=1e-6, atol=1e-7)
    np.testing.assert_allclose(w[1::2], w0[1::2], rtol=1e-5, atol=1e-7)
    assert np.mean(np.abs(w[0::2] - w0[0::2]) > 1e-3 * np.mean(w0)) > 0.2  # weighed at a texel
    # The density reported for MIS stays the mixture's, the one eval_pdf gives there.
    smooth = np.array(mi.has_flag(bs.sampled_type, mi.BSDFFlags.Smooth)) & (np.array(bs.pdf) > 0)
    _, at_wo, _ = bsdf.shading.shade(enabled, si, [bs.wo], None, True, exact_wos=marked)
    on = smooth & (np.arange(n) % 2 == 0)
    assert on.mean() > 0.3
    np.testing.assert_allclose(np.array(bs.pdf)[on], np.array(at_wo[0])[on], rtol=1e-4)
    mirror = np.array([-wi[0], -wi[1], wi[2]])
    for g in (lambda d: np.ones(d.shape[1]), lambda d: (d[2] < 0.0).astype(float),
              lambda d: np.maximum(0.0, mirror @ d) ** 8):
        a, b = w[0::2] * g(wo_s[:, 0::2]), w0[0::2] * g(wo_s0[:, 0::2])
        tolerance = 5.0 * np.hypot(a.std(), b.std()) / np.sqrt(a.size) + 1e-4 * abs(b.mean())
        assert abs(a.mean() - b.mean()) <= tolerance, (a.mean(), b.mean(), tolerance)


@pytest.mark.parametrize("visibility", [False, True])
def test_a_constant_direction_shades_as_a_computed_one(visibility):
    """bsdf.eval at a direction given as a constant (a script's mi.Vector3f(x, y, z)) beside
    shading points whose viewer is computed: the same values as at the same direction
    computed per lane. Through Mitsuba's uniform_hemisphere_to_square the visibility bins
    were wrong: 0.037 where the value is 0.082."""
    bsdf = mi.load_dict(dict(BASE, visibility=visibility))
    n = 20000
    wi, wo = DIRECTIONS[0]
    si = validation.sheared_interaction(n, [0.3, 0.55], 10.0, 0.0, N_TEXELS, unit(wi))
    validation.scatter_shading_points(si, np.random.default_rng(3))
    ctx = non_delta_context()
    constant = np.array(bsdf.eval(ctx, si, mi.Vector3f(unit(wo))))
    computed = np.array(bsdf.eval(ctx, si, validation.direction(wo, n)))
    np.testing.assert_allclose(constant, computed, rtol=1e-5, atol=1e-7)
