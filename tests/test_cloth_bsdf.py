"""The ``cloth`` BSDF: sample/eval/pdf agreement, reciprocity, energy, robustness."""
import drjit as dr
import mitsuba as mi
import numpy as np
import pytest

import mscloth
from mscloth import validation
from mscloth.bsdf.footprint_estimator import FootprintEstimator
from mscloth.bsdf.lobes import GAP, SHEEN

from cloth_fixtures import gap_texel, make_si, non_delta_context, uv_of, yarn_texels

mscloth.register()

CLOTH = {"type": "cloth", "pattern": "plain", "roughness": 0.35, "thickness": 1.8,
         "specular_albedo": {"type": "rgb", "value": [0.5, 0.4, 0.3]},
         "specular_transmittance": 0.3,
         "diffuse_albedo": {"type": "rgb", "value": [0.3, 0.4, 0.5]},
         "diffuse_transmittance": 0.15,
         "sheen_color": 0.7, "sheen_roughness": 0.45, "sheen_thickness": 0.5}


def random_directions(rng, n, lower_fraction=0.5):
    w = rng.normal(size=(n, 3))
    w /= np.linalg.norm(w, axis=1, keepdims=True)
    return w


def random_uv(rng, n):
    return rng.random((n, 2))


def vec(a):
    return validation.lanes(mi.Vector3f, a[:, 0], a[:, 1], a[:, 2])


def pt2(a):
    return validation.lanes(mi.Point2f, a[:, 0], a[:, 1])


def np3(v):
    """(n, 3) NumPy array of a Dr.Jit 3-vector/colour."""
    return np.stack([np.array(v[i]) for i in range(3)], axis=1)


@pytest.fixture(scope="module")
def bsdf():
    return mi.load_dict(CLOTH)


def test_flags_and_components(bsdf):
    assert bsdf.component_count() == 6
    assert mi.has_flag(bsdf.flags(), mi.BSDFFlags.DeltaTransmission)
    assert mi.has_flag(bsdf.flags(), mi.BSDFFlags.GlossyTransmission)
    assert mi.has_flag(bsdf.flags(), mi.BSDFFlags.BackSide)
    assert mi.has_flag(bsdf.flags(bsdf.component_count() - 1), mi.BSDFFlags.DeltaTransmission)


def test_sample_weight_is_eval_over_pdf(bsdf):
    rng = np.random.default_rng(1)
    n = 200_000
    si = make_si(vec(random_directions(rng, n)), pt2(random_uv(rng, n)), n)
    ctx = mi.BSDFContext()
    bs, weight = bsdf.sample(ctx, si, mi.Float(rng.random(n)), pt2(rng.random((n, 2))))
    value, pdf = bsdf.eval_pdf(ctx, si, bs.wo)
    delta = np.array(mi.has_flag(bs.sampled_type, mi.BSDFFlags.Delta))
    valid = (np.array(bs.pdf) > 0) & ~delta
    assert valid.sum() > 0.5 * n
    w, v, p = np3(weight)[valid], np3(value)[valid], np.array(pdf)[valid]
    np.testing.assert_allclose(np.array(bs.pdf)[valid], p, rtol=1e-4)
    np.testing.assert_allclose(w, v / p[:, None], rtol=2e-3, atol=1e-6)
    # eval_pdf agrees with eval and pdf called alone.
    np.testing.assert_allclose(np3(bsdf.eval(ctx, si, bs.wo))[valid], v, rtol=1e-5, atol=1e-8)
    np.testing.assert_allclose(np.array(bsdf.pdf(ctx, si, bs.wo))[valid], p, rtol=1e-5, atol=1e-8)


def test_delta_samples_go_straight_through_gaps(bsdf):
    n = 10_000
    rng = np.random.default_rng(2)
    wi = random_directions(rng, n)
    si = make_si(vec(wi), mi.Point2f(gap_texel()), n)
    ctx = mi.BSDFContext()
    bs, weight = bsdf.sample(ctx, si, mi.Float(rng.random(n)), pt2(rng.random((n, 2))))
    comp = np.array(bs.sampled_component)
    ok = np.array(bs.pdf) > 0
    assert np.all((comp[ok] == GAP) | (comp[ok] == SHEEN))  # in a gap only sheen and the gap remain
    assert np.count_nonzero(comp[ok] == GAP) > 0.2 * n
    wo = np3(bs.wo)[ok & (comp == GAP)]
    np.testing.assert_allclose(wo, -wi[ok & (comp == GAP)], atol=1e-6)
    # Non-delta eval at o = -i ignores the delta lobe.
    assert np.all(np3(bsdf.eval(ctx, si, vec(-wi))) == 0.0)


def test_reciprocity(bsdf):
    """f(i, o) = f(o, i); eval carries |cos o|, so compare eval/|cos o| with eval/|cos i|."""
    rng = np.random.default_rng(3)
    n = 100_000
    wi, wo = random_directions(rng, n), random_directions(rng, n)
    uv = pt2(random_uv(rng, n))
    ctx = mi.BSDFContext()
    f_io = np3(bsdf.eval(ctx, make_si(vec(wi), uv, n), vec(wo))) / np.abs(wo[:, 2:3])
    f_oi = np3(bsdf.eval(ctx, make_si(vec(wo), uv, n), vec(wi))) / np.abs(wi[:, 2:3])
    keep = (np.abs(wi[:, 2]) > 1e-3) & (np.abs(wo[:, 2]) > 1e-3)
    assert np.count_nonzero(f_io[keep] > 0) > 0.5 * keep.sum()
    np.testing.assert_allclose(f_io[keep], f_oi[keep], rtol=2e-3, atol=1e-6)


@pytest.mark.parametrize("half_texels", [3.0, 40.0])
def test_footprint_reciprocity(bsdf, half_texels):
    """The footprint BSDF is reciprocal too: the same footprint (and so the same residual
    texels and SAT rounding, which depend on uv and p only) with i and o swapped."""
    check_footprint_reciprocity(bsdf, half_texels)


@pytest.mark.parametrize("half_texels", [3.0, 12.0, 40.0])
def test_shiny_footprint_reciprocity(half_texels):
    """... and on shiny fibres, whose probes of few texels are shaded texel by texel
    (3 and 12 texels: probes of ~36 and ~150 texels) and larger ones by exact SAT corners
    and the finer residual grid."""
    check_footprint_reciprocity(mi.load_dict(dict(CLOTH, roughness=0.1)), half_texels)


def check_footprint_reciprocity(bsdf, half_texels):
    rng = np.random.default_rng(4)
    n = 50_000
    wi, wo = random_directions(rng, n), random_directions(rng, n)
    uv = pt2(random_uv(rng, n))
    d = 2.0 * half_texels / bsdf.fibre.tile.tile_w

    def footprint_si(w):
        si = make_si(vec(w), uv, n)
        si.duv_dx = validation.constants(mi.Vector2f, n, d, 0.0)
        si.duv_dy = validation.constants(mi.Vector2f, n, 0.0, d)
        return si

    ctx = mi.BSDFContext()
    f_io = np3(bsdf.eval(ctx, footprint_si(wi), vec(wo))) / np.abs(wo[:, 2:3])
    f_oi = np3(bsdf.eval(ctx, footprint_si(wo), vec(wi))) / np.abs(wi[:, 2:3])
    keep = (np.abs(wi[:, 2]) > 1e-2) & (np.abs(wo[:, 2]) > 1e-2)
    assert np.count_nonzero(f_io[keep] != 0) > 0.5 * keep.sum()
    scale = np.abs(f_io[keep]).max()
    np.testing.assert_allclose(f_io[keep], f_oi[keep], rtol=2e-3, atol=1e-6 * scale)


def test_directions_evaluated_in_one_loop_equal_each_evaluated_alone(bsdf):
    """eval_pdf_sample_n evaluates its directions and the sampled one in one symbolic loop
    (a kernel half the size, compiled 4x faster): the same values, densities and sample,
    to the bit, as eval_pdf and sample of one direction each (traced without the loop),
    over lanes at fibre level (no footprint), in the blend (5 texels across: 25 texels,
    between POINT_TEXELS and FOOTPRINT_TEXELS) and over footprints (80 texels across)."""
    rng = np.random.default_rng(8)
    n = 24_000
    wi = random_directions(rng, n)
    wos = [vec(random_directions(rng, n)) for _ in range(2)]
    si = make_si(vec(wi), pt2(random_uv(rng, n)), n)
    d = np.repeat([0.0, 5.0, 80.0], n // 3) / bsdf.fibre.tile.tile_w
    si.duv_dx = mi.Vector2f(mi.Float(d), 0.0)
    si.duv_dy = mi.Vector2f(0.0, mi.Float(d))
    s1, s2 = mi.Float(rng.random(n)), mi.Point2f(rng.random(n), rng.random(n))
    ctx = mi.BSDFContext()
    values, pdfs, bs, weight = bsdf.eval_pdf_sample_n(ctx, si, wos, s1, s2)
    for wo, value, pdf in zip(wos, values, pdfs):
        alone = bsdf.eval_pdf(ctx, si, wo)
        np.testing.assert_array_equal(np3(value), np3(alone[0]))
        np.testing.assert_array_equal(np.array(pdf), np.array(alone[1]))
        for third in range(3):
            assert np.count_nonzero(np.array(pdf)[third * (n // 3):(third + 1) * (n // 3)]) > n // 6
    bs_alone, weight_alone = bsdf.sample(ctx, si, s1, s2)
    for a, b in ((bs.wo, bs_alone.wo), (bs.pdf, bs_alone.pdf), (weight, weight_alone)):
        np.testing.assert_array_equal(np.array(a), np.array(b))
    np.testing.assert_array_equal(np.array(bs.sampled_component), np.array(bs_alone.sampled_component))


SHINY_SATIN = {"type": "cloth", "pattern": "satin-5-2", "roughness": 0.12, "specular_albedo": 0.8,
               "specular_transmittance": 0.05, "diffuse_albedo": 0.1, "sheen_color": 0.2}


@pytest.mark.parametrize("params", [CLOTH, SHINY_SATIN], ids=["rough plain", "shiny satin"])
def test_residual_texels_summed_in_one_loop_equal_their_unrolled_sum(params, monkeypatch):
    """The footprint BSDF sums its residual texels' terms (2x2 on rough cloth, 4x4 on
    shiny) in one symbolic loop, each texel's fields picked by its index: the same values
    and densities, to the bit, as one traced copy per texel, for viewers above and below,
    over footprints inside a tile and over whole tiles (where the control variate's
    visibility switches), and where the footprint blends into fibre level."""
    bsdf = mi.load_dict(params)
    tile_w = bsdf.fibre.tile.tile_w
    rng = np.random.default_rng(9)
    n = 20_000
    wi, wo = random_directions(rng, n), vec(random_directions(rng, n))
    si = make_si(vec(wi), pt2(random_uv(rng, n)), n)
    d = np.repeat([5.0, 80.0, 2.5 * tile_w, 5.0 * tile_w], n // 4) / tile_w
    si.duv_dx = validation.lanes(mi.Vector2f, d, np.zeros_like(d))
    si.duv_dy = validation.lanes(mi.Vector2f, 0.3 * d, 0.8 * d)
    ctx = mi.BSDFContext()
    looped = bsdf.eval_pdf(ctx, si, wo)
    monkeypatch.setattr(FootprintEstimator, "LOOP_TEXELS", False)
    unrolled = bsdf.eval_pdf(ctx, si, wo)
    np.testing.assert_array_equal(np3(looped[0]), np3(unrolled[0]))
    np.testing.assert_array_equal(np.array(looped[1]), np.array(unrolled[1]))
    for quarter in range(4):
        lanes = slice(quarter * (n // 4), (quarter + 1) * (n // 4))
        assert np.count_nonzero(np3(looped[0])[lanes].sum(axis=1) > 0.0) > n // 16
        assert np.isfinite(np3(looped[0])[lanes]).all() and np.isfinite(np.array(looped[1])[lanes]).all()


def hemispherical_albedo(bsdf, wi, uv, n, seed):
    """Mean sample weight per incident direction = directional albedo (delta lobe included)."""
    m = len(wi)
    rng = np.random.default_rng(seed)
    wi_rep = np.repeat(wi, n, axis=0)
    si = make_si(vec(wi_rep), mi.Point2f(uv), m * n)
    bs, weight = bsdf.sample(mi.BSDFContext(), si, mi.Float(rng.random(m * n)), pt2(rng.random((m * n, 2))))
    w = np3(weight).reshape(m, n, 3)
    return w.mean(axis=1), w.std(axis=1) / np.sqrt(n)


def incident_grid(back=False):
    thetas = [0.0, 30.0, 60.0, 80.0, 89.0]
    phis = [0.0, 70.0, 160.0]
    out = []
    for th in thetas:
        for ph in phis:
            t, p = np.radians(th), np.radians(ph)
            out.append([np.sin(t) * np.cos(p), np.sin(t) * np.sin(p), (-1 if back else 1) * np.cos(t)])
    return np.array(out)


EXTREME = {"type": "cloth", "roughness": 0.05, "thickness": 30.0,
           "specular_albedo": 1.0, "specular_transmittance": 1.0,
           "diffuse_albedo": 0.0, "diffuse_transmittance": 0.0,
           "sheen_color": 1.0, "sheen_roughness": 1.0, "sheen_thickness": 5.0}


@pytest.mark.parametrize("params", [CLOTH, EXTREME, dict(EXTREME, diffuse_albedo=0.5, specular_albedo=0.5,
                                                           specular_transmittance=0.5, sheen_thickness=0.1)])
@pytest.mark.parametrize("back", [False, True])
def test_white_furnace_never_gains_energy(params, back):
    bsdf = mi.load_dict(params)
    wi = incident_grid(back)
    for uv in yarn_texels() + [gap_texel()]:
        mean, err = hemispherical_albedo(bsdf, wi, uv, 20_000, seed=4)
        assert np.all(mean <= 1.0 + 5 * err + 1e-6), (uv, mean.max())


def test_white_furnace_conserves_when_nothing_is_absorbed():
    """Diffuse lobes with k_rd + k_td = 1 and no fuzz: all light leaves (yarn texels);
    in a gap, the delta lobe carries all of it."""
    bsdf = mi.load_dict({"type": "cloth", "specular_albedo": 0.0, "specular_transmittance": 0.0,
                         "diffuse_albedo": 0.7, "diffuse_transmittance": 0.3, "sheen_thickness": 0.0,
                         "visibility": False})
    wi = incident_grid() [:-3]  # not at 89 degrees: there the cosine sampling is fine but keep it clean
    for uv in yarn_texels() + [gap_texel()]:
        mean, err = hemispherical_albedo(bsdf, wi, uv, 20_000, seed=5)
        np.testing.assert_allclose(mean, 1.0, atol=float(5 * err.max() + 1e-5))


def test_specular_albedo_matches_spongecake_single_scattering():
    """The specular lobes' albedo is the layer's single-scattered R + T (no fuzz, k = 1)."""
    from mscloth.maps.builtin import resolve_pattern
    from mscloth.scattering import spongecake

    bsdf = mi.load_dict({"type": "cloth", "roughness": 0.3, "thickness": 1.7, "specular_albedo": 1.0,
                         "specular_transmittance": 1.0, "diffuse_albedo": 0.0, "diffuse_transmittance": 0.0,
                         "sheen_thickness": 0.0, "visibility": False})
    maps = resolve_pattern("plain")
    r, c = 32, 32
    wi = np.array([[0.35, 0.2, 0.91]]) / np.linalg.norm([0.35, 0.2, 0.91])
    mean, err = hemispherical_albedo(bsdf, wi, uv_of(r, c), 400_000, seed=6)
    # Reference: integrate eval_specular over uniformly sampled directions.
    rng = np.random.default_rng(7)
    n = 2_000_000
    wo = random_directions(rng, n)
    t = mi.Vector3f(*[float(x) for x in maps.tangent[r, c]])
    value, _ = spongecake.eval_specular(mi.Vector3f(*[float(x) for x in wi[0]]), vec(wo), t, 0.3, 1.7)
    v = np.array(value) * 4 * np.pi
    ref, ref_err = v.mean(), v.std() / np.sqrt(n)
    assert abs(mean[0, 0] - ref) < 5 * np.hypot(err[0, 0], ref_err)


def test_no_nan_or_inf_anywhere():
    """10^6 random (i, o, uv) including grazing, o = +-i, with extreme parameters."""
    rng = np.random.default_rng(8)
    n = 1_000_000
    wi = random_directions(rng, n)
    wo = random_directions(rng, n)
    k = n // 10
    wi[:k, 2] = 0.0                       # exactly grazing incidence
    wi[:k] /= np.linalg.norm(wi[:k], axis=1, keepdims=True)
    wi[k:2 * k, 2] = rng.choice([-1, 1], k) * 1e-8   # almost grazing
    wi[k:2 * k] /= np.linalg.norm(wi[k:2 * k], axis=1, keepdims=True)
    wo[2 * k:3 * k] = wi[2 * k:3 * k]      # o = i
    wo[3 * k:4 * k] = -wi[3 * k:4 * k]     # o = -i
    wo[4 * k:5 * k] = wi[4 * k:5 * k] * [1, 1, -1]   # mirror direction
    wi[5 * k:6 * k] = [0, 0, 1]            # normal incidence
    uv = pt2(rng.random((n, 2)) * 20 - 10)
    for params in [CLOTH, EXTREME, dict(EXTREME, roughness=1.0, thickness=1e-3, sheen_thickness=0.0),
                   dict(EXTREME, roughness=1e-3, sheen_roughness=1e-3, sheen_thickness=1e3, thickness=1e3)]:
        bsdf = mi.load_dict(params)
        ctx = mi.BSDFContext()
        si = make_si(vec(wi), uv, n)
        value, pdf = bsdf.eval_pdf(ctx, si, vec(wo))
        bs, weight = bsdf.sample(ctx, si, mi.Float(rng.random(n)), pt2(rng.random((n, 2))))
        for name, arr in [("eval", np3(value)), ("pdf", np.array(pdf)), ("weight", np3(weight)),
                          ("sample pdf", np.array(bs.pdf)), ("wo", np3(bs.wo))]:
            assert np.all(np.isfinite(arr)), (name, params)
        assert np.all(np3(value) >= 0) and np.all(np.array(pdf) >= 0) and np.all(np3(weight) >= 0)


def test_back_side_mirrors_front_side():
    """Two-sided: mirroring both directions through the surface mirrors the tangent's z,
    which for an in-plane tangent texel leaves the value unchanged (without the height
    field's visibility, which differs between the two sides)."""
    bsdf = mi.load_dict(dict(CLOTH, visibility=False))
    rng = np.random.default_rng(9)
    n = 50_000
    wi, wo = random_directions(rng, n), random_directions(rng, n)
    uv = mi.Point2f(yarn_texels()[0])  # tangent with t.z ~ 0
    ctx = mi.BSDFContext()
    front = np3(bsdf.eval(ctx, make_si(vec(wi), uv, n), vec(wo)))
    back = np3(bsdf.eval(ctx, make_si(vec(wi * [1, 1, -1]), uv, n), vec(wo * [1, 1, -1])))
    np.testing.assert_allclose(front, back, rtol=2e-2, atol=1e-4)
    assert np.count_nonzero(front) > 0.5 * front.size


def test_zero_parameters_stay_scalars_after_shading_lanes():
    """A parameter set to 0 stays one value after the BSDF shaded lanes of one width, so
    lanes of another width shade too (Dr.Jit 1.5.0 folds `literal 0 * x` by resizing a
    literal held once in place: sheen_thickness 0 became 65536 wide in the calibration)."""
    bsdf = mi.load_dict({"type": "cloth", "sheen_thickness": 0.0, "visibility": False})
    for n in (1000, 777):
        wi = np.repeat([[0.3, 0.2, 0.93]], n, axis=0)
        si = make_si(vec(wi), mi.Point2f(0.3, 0.6), n)
        _, weight = bsdf.sample(mi.BSDFContext(), si, mi.Float(np.linspace(0, 1, n, endpoint=False)),
                                pt2(np.full((n, 2), 0.4)))
        assert np3(weight).shape == (n, 3) and np.all(np.isfinite(np3(weight)))
    for name in ("sheen_thickness", "sheen_roughness", "roughness", "thickness", "uv_scale"):
        assert dr.width(getattr(bsdf.params, name)) == 1, name


def test_two_cloth_bsdfs_that_differ_in_parameters_run_as_one_callable():
    """Parameters are evaluated values, not literals baked into the traced code, so two
    cloth BSDFs with the same maps and switches but other parameter values trace the same
    code and Dr.Jit runs one callable for a packet of lanes that hit both (two callables
    ran both bodies on every mixed packet)."""
    import contextlib
    import io
    import re

    a = mi.load_dict(dict(CLOTH, multiscale=False))
    b = mi.load_dict(dict(CLOTH, multiscale=False, roughness=0.2, thickness=3.0, sheen_thickness=0.1,
                          specular_albedo={"type": "rgb", "value": [0.2, 0.3, 0.1]}, diffuse_transmittance=0.05))
    for name in ("roughness", "thickness", "sheen_roughness", "sheen_thickness", "uv_scale"):
        assert getattr(b.params, name).state == dr.VarState.Evaluated, name
    n = 64
    rng = np.random.default_rng(8)
    si = make_si(vec(np.repeat([[0.3, 0.2, 0.93]], n, axis=0)), pt2(random_uv(rng, n)), n)
    ptrs = dr.gather(mi.BSDFPtr, mi.BSDFPtr([a, b]), mi.UInt32(np.arange(n) % 2))
    log = io.StringIO()
    with contextlib.redirect_stdout(log):
        dr.set_log_level(dr.LogLevel.Debug)
        try:
            value = ptrs.eval(mi.BSDFContext(), si, vec(np.repeat([[-0.2, 0.1, 0.97]], n, axis=0)))
            dr.eval(value)  # the call is assembled when its kernel runs
        finally:
            dr.set_log_level(dr.LogLevel.Warn)
    calls = [line for line in log.getvalue().splitlines() if "jit_var_call_assemble" in line]
    # "to 1/N functions": one distinct function for the N registered BSDF instances (every
    # cloth BSDF alive in the session is traced, and those here are all the same code).
    assert calls and all(re.search(r"to 1/\d+ functions", line) for line in calls), calls
    values = np3(value)
    assert np.all(np.isfinite(values)) and not np.allclose(values[0::2], values[1::2])


def test_cloth_bsdfs_with_the_same_fuzz_share_one_sheen_table():
    """The sheen sampler's table is read-only and depends on the fuzz alone: BSDFs with the
    same sheen_roughness and sheen_thickness read one table (its reads miss the cache
    often; two copies doubled what they compete for), other fuzz gets its own."""
    a = mi.load_dict(dict(CLOTH, multiscale=False))
    b = mi.load_dict(dict(CLOTH, multiscale=False, roughness=0.2, sheen_color=0.3))
    c = mi.load_dict(dict(CLOTH, multiscale=False, sheen_thickness=0.25))
    assert a.fibre.samplers.sheen is b.fibre.samplers.sheen
    assert c.fibre.samplers.sheen is not a.fibre.samplers.sheen
    assert not np.allclose(c.fibre.samplers.sheen.density, a.fibre.samplers.sheen.density)
    # The tables are held by the BSDFs alone: the last one gone, its table goes too.
    import gc
    import weakref
    table = weakref.ref(c.fibre.samplers.sheen)
    del c
    gc.collect()
    assert table() is None


def _exact_yarn(bsdf, x0, y0, x1, y1):
    """Yarn coverage I over the texel rectangle [x0, x1] x [y0, y1] (fractional corners:
    the exact integral, bilinear corner reads)."""
    sats = bsdf.footprint_data.scalar_sats
    q = sats.query(mi.Float(x0), mi.Float(y0), mi.Float(x1), mi.Float(y1))
    return np.array(sats.integral(q, bsdf.footprint_data.GAP)) / ((x1 - x0) * (y1 - y0))


def test_gap_transmission_of_a_footprint_is_its_gap_lobe(monkeypatch):
    """Shadow rays crossing multi-scale cloth see T_sheen^2 (1 - I), I the yarn coverage of
    the footprint over the box the footprint BSDF shades (its corners rounded to whole
    texels by the shading point's hash), or below 8 texels, where some lanes are shaded
    fibre level, of the point's texel: at every lane exactly the BSDF's own gap lobe, in
    [0, T_sheen^2], zero for a gap-free footprint (dividing the rounded box's yarn by the
    exact area, then clipping, gave a gap-free 2.3-texel footprint 0.09), and over the
    random roundings the exact footprint's fraction. The blend between fibre-level and
    footprint shading is set to 2-8 texels here (the default, 16-32, would shade the
    small boxes this test needs fibre level only)."""
    from mscloth.bsdf.footprint_estimator import FootprintEstimator
    monkeypatch.setattr(FootprintEstimator, "POINT_TEXELS", 2.0)
    monkeypatch.setattr(FootprintEstimator, "FOOTPRINT_TEXELS", 8.0)
    bsdf = mi.load_dict(dict(CLOTH, visibility=False))
    n = 256
    rng = np.random.default_rng(9)
    su, sv = (float(np.array(getattr(bsdf.params, k))[0]) for k in ("uv_scale", "uv_scale_v"))
    W, H = bsdf.fibre.tile.tile_w, bsdf.fibre.tile.tile_h
    # A gap-free spot: a texel whose 7 x 5 neighbourhood is all yarn (what a 2.3 x 1.6
    # texel box, rounded either way, can reach).
    ix, iy = np.meshgrid(np.arange(W), np.arange(H))
    texel = _exact_yarn(bsdf, ix.ravel(), iy.ravel(), ix.ravel() + 1.0, iy.ravel() + 1.0).reshape(H, W)
    full = np.ones_like(texel, dtype=bool)
    for dy in range(-2, 3):
        for dx in range(-3, 4):
            full &= np.roll(texel, (-dy, -dx), axis=(0, 1)) > 1.0 - 1e-5
    gy, gx = np.argwhere(full)[0]
    # Then boxes across a gap's edge (wrapping in y), across a gap, and over tiles' corners.
    cases = ((2.3, ((gx + 0.5) / (su * W), (gy + 0.5) / (sv * H)), True),
             (2.3, (58.3 / (su * W), 0.5 / (sv * H)), False), (9.6, (0.52, 0.05), False),
             (41.0, (0.5 / (su * W), 0.5 / (sv * H)), False))
    for width, (u, v), gap_free in cases:
        si = make_si(vec(np.repeat([[0.3, 0.1, 0.95]], n, axis=0) / np.linalg.norm([0.3, 0.1, 0.95])),
                     mi.Point2f(float(u), float(v)), n)
        si.p = mi.Point3f(*(mi.Float(rng.random(n)) for _ in range(3)))
        si.duv_dx = mi.Vector2f(width / (su * W), 0.0)
        si.duv_dy = mi.Vector2f(0.0, 0.7 * width / (sv * H))
        got = np.array(bsdf.gap_transmission(si))
        fr = bsdf.fibre.frame(si, True)
        t2 = float(np.array(fr.t_sheen_i)[0]) ** 2
        # Lanes shaded as a footprint (all of them from 8 texels on) see its yarn mean, the
        # others (a 2.3 x 1.6 texel footprint is mostly shaded fibre level) their point's texel.
        xi, _, u_choice = bsdf.estimator.shading_hash(si)
        fp = bsdf.estimator.footprint(si, fr, u_choice)
        use = np.broadcast_to(np.array(fp.use), (n,))
        assert use.all() if width > 4 else 0 < use.mean() < 1
        footprint = np.array(bsdf.estimator.state(si, fr, [True] * 6).yarn_mean)
        point = np.array(bsdf.fibre.texel(fr, *bsdf.estimator.point_in_footprint(fr, fp, xi)).yarn)
        lobe = np.where(use, footprint, point)
        np.testing.assert_allclose(got, t2 * (1.0 - lobe), rtol=1e-5, atol=1e-7)
        assert np.all((got >= 0.0) & (got <= t2 * (1.0 + 1e-6)))
        if gap_free:
            assert np.all(got == 0.0), got.max()
            continue
        x, y = u * su * W, v * sv * H
        rx, ry = 0.5 * width, 0.35 * width
        exact = t2 * (1.0 - _exact_yarn(bsdf, x - rx, y - ry, x + rx, y + ry)[0])
        # The rounded box moves each edge by under a texel: the lanes scatter by that much
        # around the exact fraction, and their mean meets it within 5 standard errors plus
        # a ratio bias (mean of a ratio of the box's yarn to its random area) of 1/area.
        spread = got.std(ddof=1) / np.sqrt(n)
        assert abs(got.mean() - exact) <= 5.0 * spread + t2 / (4.0 * rx * ry), (width, got.mean(), exact, spread)
        assert np.ptp(got) > 0.0  # the rounding varies with the shading point


def test_gap_transmission_skips_the_tables_only_for_lanes_without_a_footprint():
    """One call, lanes with and without footprints (shadow rays from the first hit and from
    vertices shaded at a point): each lane gets what it gets alone, the footprint's gap
    fraction or its texel's (the footprint reads sit in a symbolic if)."""
    bsdf = mi.load_dict(dict(CLOTH, visibility=False))
    n = 256
    rng = np.random.default_rng(4)
    wi = rng.normal(size=(n, 3))
    wi[:, 2] = np.abs(wi[:, 2]) + 0.2
    wi /= np.linalg.norm(wi, axis=1, keepdims=True)
    uv = rng.random((n, 2))
    width = np.where(np.arange(n) % 3 == 0, 0.0, rng.uniform(1.5, 30.0, n)) / bsdf.fibre.tile.tile_w

    def interaction(lanes):
        si = make_si(vec(wi[lanes]), mi.Point2f(*uv[lanes].T), len(lanes))
        si.duv_dx = mi.Vector2f(mi.Float(width[lanes]), 0.0)
        si.duv_dy = mi.Vector2f(0.0, mi.Float(0.8 * width[lanes] * bsdf.fibre.tile.tile_w / bsdf.fibre.tile.tile_h))
        return si

    def call(lanes):
        return np.array(bsdf.gap_transmission(interaction(lanes)))

    mixed = call(np.arange(n))
    point = np.flatnonzero(width == 0.0)
    footprint = np.flatnonzero(width > 0.0)
    np.testing.assert_allclose(mixed[point], call(point), rtol=1e-6, atol=1e-7)
    np.testing.assert_allclose(mixed[footprint], call(footprint), rtol=1e-5, atol=1e-6)
    # Points see one texel: no gap (0) or the gap (T_sheen^2); footprints, fractions between.
    t2 = np.array(bsdf.fibre.frame(interaction(point), True).t_sheen_i) ** 2
    assert np.all(np.isclose(mixed[point], 0.0, atol=1e-7) | np.isclose(mixed[point], t2, rtol=1e-5))
    assert np.any(mixed[point] > 0.0) and np.any(mixed[point] == 0.0)
    assert np.any((mixed[footprint] > 0.0) & (mixed[footprint] < 0.9 * np.max(t2)))


def _small_cloth(pattern):
    return {"type": "cloth", "pattern": pattern, "resolution": 32, "direction_bins": 4, "visibility_bins": 2,
            "clusters": 2}


def test_name_cloths_names_nested_cloths_after_their_shape_and_leaves_ids_alone():
    from mscloth.loading import name_cloths

    scene = {"type": "scene", "floor": {"type": "rectangle", "bsdf": _small_cloth("plain")},
             "ball": {"type": "sphere", "bsdf": dict(_small_cloth("plain"), id="mine")},
             "wrapped": {"type": "sphere", "bsdf": {"type": "twosided", "bsdf": _small_cloth("plain")}},
             "mat": _small_cloth("plain"), "other": {"type": "sphere", "bsdf": {"type": "diffuse"}}}
    named = name_cloths(scene)
    assert named["floor"]["bsdf"]["id"] == "floor.bsdf" and named["ball"]["bsdf"]["id"] == "mine"
    assert named["wrapped"]["bsdf"]["bsdf"]["id"] == "wrapped.bsdf.bsdf"
    assert "id" not in named["mat"] and "id" not in named["other"]["bsdf"]  # top level: its key is its id
    assert "id" not in scene["floor"]["bsdf"] and named["other"] is scene["other"]  # the input is not changed
    taken = {"type": "scene", "floor.bsdf": {"type": "diffuse"}, "floor": {"type": "rectangle", "bsdf": _small_cloth("plain")}}
    assert "id" not in name_cloths(taken)["floor"]["bsdf"]  # an id in use is not given twice


def test_name_xml_cloths_names_cloths_inside_shapes():
    import xml.etree.ElementTree as ET

    from mscloth.loading import name_xml_cloths

    root = ET.fromstring("<scene version='3.0.0'><shape type='sphere' id='ball'><bsdf type='cloth'/></shape>"
                         "<shape type='sphere' id='cup'><bsdf type='cloth' id='glaze'/></shape>"
                         "<shape type='sphere'><bsdf type='cloth'/></shape></scene>")
    assert name_xml_cloths(root)
    assert [b.get("id") for b in root.iter("bsdf")] == ["ball.bsdf", "glaze", None]
    assert not name_xml_cloths(root)  # nothing left to name


def test_loading_two_cloths_labels_each_progress_line_with_its_shape_and_pattern(capfd, tmp_path, monkeypatch):
    """Mitsuba builds both cloths' tables at once; each progress line is whole and says whose it is."""
    import re

    from mscloth.loading import load_dict

    monkeypatch.setenv("MSCLOTH_CACHE", str(tmp_path))  # built here, not loaded from the session's cache
    scene = load_dict({"type": "scene", "floor": {"type": "rectangle", "bsdf": _small_cloth("plain")},
                       "ball": {"type": "sphere", "bsdf": _small_cloth("twill-2-1")}})
    assert sorted(shape.bsdf().label for shape in scene.shapes()) == ["ball.bsdf, twill-2-1", "floor.bsdf, plain"]
    lines = [line for line in capfd.readouterr().err.splitlines() if "mscloth precompute" in line]
    line = re.compile(r"mscloth precompute \[(floor\.bsdf, plain|ball\.bsdf, twill-2-1)\]: "
                      r"(?:(?!mscloth precompute).)+")
    assert lines and all(line.fullmatch(text) for text in lines), lines
    assert {line.fullmatch(text).group(1) for text in lines if "tables built" in text} == \
        {"floor.bsdf, plain", "ball.bsdf, twill-2-1"}
