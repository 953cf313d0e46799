"""The sky albedo table (:mod:`mscloth.bsdf.sky_albedo`) and ``clothpath``'s control
variate for a uniform sky that reads it (``sky_share``, docs/performance-log.md L60).

The table must give what the footprint BSDF's sampled direction weighs on average (its
directional albedo over the probe, the gaps' delta transmission included): that is what keeps the control variate
unbiased. Checked against the mean weight of the BSDF's own samples, on rough and shiny
cloth, both sides, from the pole to grazing; then in a render, where the image must keep
its mean and lose most of its noise."""
from __future__ import annotations

import mitsuba as mi
import numpy as np
import pytest

import mscloth
from mscloth import validation
from mscloth.bsdf import sky_albedo
from mscloth.integrators import bsdf_contract as contract

from cloth_fixtures import N_TEXELS, direction

mscloth.register()

ROUGH = {"type": "cloth", "pattern": "plain", "roughness": 0.4}
#: Shiny satin, as the `satin` scene's (tests/test_footprint_shiny.py).
SATIN = {"type": "cloth", "pattern": "satin-8-3", "resolution": N_TEXELS, "thickness": 2.0, "roughness": 0.1,
         "specular_albedo": 0.8, "specular_transmittance": 0.3, "diffuse_albedo": 0.1,
         "diffuse_transmittance": 0.05, "sheen_thickness": 0.1}

#: What the table may differ by from the sampled weights' mean over a whole tile (its own
#: Monte Carlo error there is ~0.3%): reads between its nodes, bilinear and corrected by the
#: tile mean's cubic (0.2-0.5% at 70-80 degrees, under 0.2% beyond but for the last half
#: degree; bilinear alone: 1-1.3% at 86-88 degrees, 3.5% at 89.7; performance log L62).
APPROXIMATION = 0.006


def test_nodes_hold_every_bin_centre_and_interpolate_the_square_exactly():
    """The visibility tables' bin centres are nodes (V(wi) is bilinear between them, so A
    has its kinks there); between nodes the weights reproduce the square coordinate and
    sum to one; the outermost nodes reach the horizon."""
    import drjit as dr

    for n in (4, 8, 16):
        c = sky_albedo.node_coordinates(n)
        assert len(c) == sky_albedo.nodes_per_axis(n)
        assert np.all(np.diff(c) > 0)
        centres = (np.arange(n) + 0.5) / n
        assert np.all(np.min(np.abs(c[None] - centres[:, None]), axis=1) < 1e-12)
        assert c[0] < 0.01 / n * 3 and c[-1] > 1 - 0.01 / n * 3
        p = np.linspace(c[0], c[-1], 4001).astype(np.float32)
        k, f = sky_albedo.node_interval(mi.Float(p), n)
        k, f = np.array(k), np.array(f)
        np.testing.assert_allclose(c[k] * (1 - f) + c[k + 1] * f, p, atol=2e-6)
    w = mi.Vector3f(*np.array([direction(th, ph) for th in (0, 30, 60, 80, 89) for ph in (0, 37, 90, 200)]).T)
    nodes, weights = sky_albedo.node_weights(w, 8)
    np.testing.assert_allclose(sum(np.array(x) for x in weights), 1.0, atol=1e-6)
    m = sky_albedo.nodes_per_axis(8)
    assert all(np.array(b).max() < m * m for b in nodes)
    dr.eval()


@pytest.mark.parametrize("curve", ["steep towards the horizon", "kinked at the bin centres", "both"])
def test_shape_ratio_follows_the_curve_between_nodes(curve):
    """A tile mean curved between the nodes (as A rises towards the horizon, and bends at
    the bin centres, where V(wi) is bilinear): the bilinear read times the shape ratio
    follows it with a third of the bilinear read's RMS error or less, half its largest;
    1 at the nodes, where the bilinear read is exact."""
    n, steps = 8, sky_albedo.SHAPE_STEPS
    c, x = sky_albedo.node_coordinates(n), sky_albedo.shape_points(n, steps)
    steep = curve != "kinked at the bin centres"
    kinked = curve != "steep towards the horizon"

    def g(u):
        return 0.1 + steep * 0.15 * (2 * u - 1) ** 4 + kinked * 0.01 * np.abs(np.cos(np.pi * n * u))
    means = np.broadcast_to((g(c)[:, None] * g(c)[None, :])[None, :, :, None], (2, len(c), len(c), 3))
    ratio = sky_albedo.shape_ratio(np.array(means), n, steps)
    assert ratio.shape == (2, len(x), len(x), 3)
    linear_1d = np.interp(x, c, g(c))  # as node_interval reads it: clamped beyond the outermost
    linear = linear_1d[:, None] * linear_1d[None, :]
    truth = g(x)[:, None] * g(x)[None, :]
    bilinear_error = linear / truth - 1
    shaped_error = ratio[1, :, :, 2] * linear / truth - 1
    assert np.sqrt(np.mean(shaped_error ** 2)) <= np.sqrt(np.mean(bilinear_error ** 2)) / 3
    assert np.abs(shaped_error).max() <= np.abs(bilinear_error).max() / 2
    at_nodes = np.isin(np.round(x, 9), np.round(c, 9))
    np.testing.assert_allclose(ratio[:, at_nodes][:, :, at_nodes], 1.0, atol=1e-9)


def mean_sampled_weight(bsdf, si, n, seed=1):
    """The mean weight of the BSDF's samples at ``si`` (the gaps' delta ones included) and
    its standard error, per channel."""
    sampler = mi.load_dict({"type": "independent"})
    sampler.seed(seed, n)
    bs, weight = bsdf.sample(mi.BSDFContext(), si, sampler.next_1d(), sampler.next_2d())
    kept = np.asarray(bs.pdf > 0)
    w = np.where(kept, np.asarray(weight), 0.0)
    return w.mean(axis=1), w.std(axis=1) / np.sqrt(n)


@pytest.fixture(scope="module")
def tables():
    """The two cloths, their tables built."""
    out = {}
    for name, params in (("rough", ROUGH), ("shiny", SATIN)):
        bsdf = mi.load_dict(params)
        assert bsdf.prepare_sky_albedo()
        out[name] = bsdf
    return out


@pytest.mark.parametrize("cloth", ["rough", "shiny"])
@pytest.mark.parametrize("theta, phi, back", [(5, 20, False), (40, 37, False), (70, 37, False), (80, 120, False),
                                               (86, 37, False), (88, 37, False), (89.7, 37, False), (35, 60, True),
                                               (84, 10, True), (88, 200, True)])
def test_table_gives_the_mean_weight_of_the_footprint_samples(tables, cloth, theta, phi, back):
    """Over a footprint of one whole tile (the table's own Monte Carlo error is small there),
    the table's A is the mean weight of the footprint BSDF's samples, within the
    stated approximation of its bilinear reads. A table built with one random pairing of
    lobe and direction strata for every cell was 2-9% off; one without nodes beyond the bin
    centres, 9% at 85 degrees; read bilinearly alone, 1-1.3% at 86-88 degrees and 3.5% at
    89.7; one side read for the other, far more."""
    bsdf = tables[cloth]
    n = 200_000
    wi = direction(theta, phi, back)
    si = validation.footprint_interaction(n, [0.3, 0.55], N_TEXELS / 2, N_TEXELS, wi)
    si.p = mi.Point3f(*np.random.default_rng(3).random((3, n)))
    mean, err = mean_sampled_weight(bsdf, si, n)
    half = mi.Float(0.5)
    albedo, known = bsdf.eval_pdf_sample_n(mi.BSDFContext(), si, [], half, mi.Point2f(half, half),
                                           sky_albedo=True)[4:]
    assert np.all(np.asarray(known) == 1.0)
    table = np.asarray(albedo).mean(axis=1)
    tolerance = 5 * err + APPROXIMATION * mean
    assert np.all(np.abs(table - mean) <= tolerance), (table, mean, tolerance)


def test_fibre_level_and_textured_cloth_have_no_table():
    """Only multi-scale cloth with constant textures has a table: brute force shades at
    texels (its A would be each texel's), a spatially varying texture would make A vary
    beyond the tile."""
    assert not contract.prepare_sky_albedo(mi.load_dict(dict(ROUGH, multiscale=False)))
    image = np.random.default_rng(1).uniform(0.2, 0.4, (4, 4, 3)).astype(np.float32)
    textured = dict(ROUGH, diffuse_albedo={"type": "bitmap", "bitmap": mi.Bitmap(image)})
    assert not contract.prepare_sky_albedo(mi.load_dict(textured))
    assert not contract.prepare_sky_albedo(mi.load_dict({"type": "diffuse"}))


def test_a_changed_parameter_drops_the_table():
    bsdf = mi.load_dict(ROUGH)
    assert bsdf.prepare_sky_albedo()
    before = bsdf.shading.sky_table
    params = mi.traverse(bsdf)
    params["diffuse_albedo.value"] = 0.3
    params.update()
    assert bsdf.shading.sky_table is None
    assert bsdf.prepare_sky_albedo() and bsdf.shading.sky_table is not before


def cloth_under_sky(bsdf_params, uv_tiles: float, sky_share: float | None, roof: bool = False, crop=None,
                    sampler=None):
    """A cloth square filling a 16 x 16 view from above at 35 degrees, under a constant sky
    only, ``uv_tiles`` tiles across, rendered by ``clothpath`` with ``sky_share`` (None:
    auto); with ``roof``, a black square 4 units above it (above the camera too) hides all
    but the last 5 degrees above the horizon; ``crop``: the film's (x, y, width, height); ``sampler``: the sensor's sampler type (default: independent)."""
    integrator = {"type": "clothpath", "emitter_sampling": "all"}
    if sky_share is not None:
        integrator["sky_share"] = sky_share
    film = {"type": "hdrfilm", "width": 16, "height": 16}
    if crop is not None:
        film.update(crop_offset_x=crop[0], crop_offset_y=crop[1], crop_width=crop[2], crop_height=crop[3])
    scene = {
        "type": "scene",
        "integrator": integrator,
        "sensor": {"type": "perspective", "fov": 12,
                   "to_world": mi.ScalarTransform4f().look_at(origin=[0, -2.3, 3.3], target=[0, 0, 0], up=[0, 0, 1]),
                   "film": film, **({} if sampler is None else {"sampler": {"type": sampler}})},
        "square": {"type": "rectangle",
                   "bsdf": dict(bsdf_params, uv_scale=uv_tiles) if bsdf_params["type"] == "cloth" else bsdf_params},
        "sky": {"type": "constant", "radiance": {"type": "rgb", "value": [1.0, 2.0, 3.0]}}}
    if roof:
        scene["roof"] = {"type": "rectangle", "to_world": mi.ScalarTransform4f().translate([0, 0, 4]).scale(50),
                         "bsdf": {"type": "diffuse", "reflectance": {"type": "rgb", "value": [0.0, 0.0, 0.0]}}}
    return mi.load_dict(scene)


@pytest.mark.parametrize("share", [0.5, 1.0])
def test_sky_control_variate_keeps_the_mean_and_cuts_the_noise(share):
    """Open cloth under a sky: with the share c taken by the control variate the image
    keeps its mean (the whole frame, to the renders' standard error plus the table's
    approximation times c) and its noise per pixel falls (c = 1 on open cloth leaves only
    the floor's light to chance; the gaps' straight rays see the sky as the others do).
    Leaving the delta samples out of A, or reading the other side's A, moves the mean by
    more than that."""
    scene = cloth_under_sky(ROUGH, 40.0, 0.0)
    spp, renders = 4, 6
    plain = np.array([np.asarray(mi.render(scene, spp=spp, seed=s))[..., :3] for s in range(renders)])
    scene = cloth_under_sky(ROUGH, 40.0, share)
    taken = np.array([np.asarray(mi.render(scene, spp=spp, seed=100 + s))[..., :3] for s in range(renders)])
    assert np.all(np.isfinite(taken))
    # Each render's frame mean: independent estimates of one number per method.
    a, b = plain.mean(axis=(1, 2)), taken.mean(axis=(1, 2))
    err = np.hypot(a.std(axis=0, ddof=1), b.std(axis=0, ddof=1)) / np.sqrt(renders)
    tolerance = 5 * err + share * APPROXIMATION * a.mean(axis=0)
    assert np.all(np.abs(b.mean(axis=0) - a.mean(axis=0)) <= tolerance), (b.mean(axis=0), a.mean(axis=0), tolerance)
    # Noise per pixel: its variance across renders, averaged over the frame.
    noise_plain = plain.var(axis=0, ddof=1).mean()
    noise_taken = taken.var(axis=0, ddof=1).mean()
    assert noise_taken < (0.5 if share < 1 else 0.1) * noise_plain, (noise_taken, noise_plain)


def test_scenes_without_a_table_render_as_before():
    """A sky over a diffuse square: no BSDF gives A, nothing of the control variate is
    traced, the image is the same to the bit."""
    params = {"type": "diffuse"}
    before = np.asarray(mi.render(cloth_under_sky(params, 1.0, 0.0), spp=2, seed=3))
    after = np.asarray(mi.render(cloth_under_sky(params, 1.0, 1.0), spp=2, seed=3))
    np.testing.assert_array_equal(before, after)


@pytest.mark.parametrize("value", [-0.1, 1.5, "half", True])
def test_sky_share_outside_zero_to_one_is_refused_in_one_line(value):
    with pytest.raises(Exception) as info:
        mi.load_dict({"type": "clothpath", "sky_share": value})
    message = str(info.value)
    assert '"sky_share" must be a number in [0, 1]' in message and str(value) in message


# ----------------------------------------------------------------------------- sky_share auto


def pilot_data(n, coefficient, noise, seed=5):
    """Two renders' and a third's pixel estimates (F, T, M) of ``n`` pixels where F = 5 -
    ``coefficient`` T + independent noise of deviation ``noise``, T of unit deviation."""
    rng = np.random.default_rng(seed)
    T = rng.normal(0.0, 1.0, (3, n))
    F = 5.0 - coefficient * T + rng.normal(0.0, noise, (3, n))
    return F[:2], T[:2], F[2]


def test_pilot_statistics_find_the_coefficient_and_what_it_cuts():
    """c* = -Cov(F, T) / Var(T) from two renders' differences, the cut 1 - Var(F + c T) /
    Var(F) at c* clipped to [0, 1], and no share where the cut is below MIN_VARIANCE_CUT.
    Tolerances: 5 standard errors for n pixels (c*: noise / sqrt(2 n) with unit Var(T);
    the cut's relative error ~ sqrt(2 / n))."""
    from mscloth.integrators import sky_share_pilot as pilot

    n = 20_000
    p = pilot.choose_share(*pilot_data(n, 0.6, 0.5))
    assert abs(p.optimal - 0.6) < 5 * 0.5 / np.sqrt(2 * n)
    assert p.share == p.optimal
    assert abs(p.variance_cut - 0.36 / 0.61) < 5 * np.sqrt(2 / n)
    # Beyond 1: the share is clipped, the cut is the one at c = 1 (Var(F) = 2.25 + 0.25).
    p = pilot.choose_share(*pilot_data(n, 1.5, 0.5))
    assert p.share == 1.0 and abs(p.optimal - 1.5) < 0.02
    assert abs(p.variance_cut - (1 - (0.25 + 0.25) / 2.5)) < 5 * np.sqrt(2 / n)
    # A little correlation: c* ~ 0.1 cuts ~1%, less than the reads cost: no share.
    p = pilot.choose_share(*pilot_data(n, 0.1, 1.0))
    assert p.share == 0.0 and abs(p.optimal - 0.1) < 0.05 and p.variance_cut < pilot.MIN_VARIANCE_CUT
    # Anti-correlation: none either.
    assert pilot.choose_share(*pilot_data(n, -0.6, 0.5)).share == 0.0
    # Pixels that are not finite are left out; no variance: no share.
    F, T, M = pilot_data(n, 0.6, 0.5)
    F[0, :10] = np.nan
    p = pilot.choose_share(F, T, M)
    assert p.pixels == n - 10 and abs(p.optimal - 0.6) < 0.02
    assert pilot.choose_share(np.ones((2, 8)), np.ones((2, 8)), np.ones(8)) == pilot.SkySharePilot(0.0, 0.0, 0.0, 8)


def test_pilot_weighs_pixels_as_relmse_and_only_those_that_read_a_table():
    """Pixels whose samples read no table (T = 0 in both renders: a floor, the sky) are
    left out however noisy; the rest weigh by 1 / (M^2 + RELMSE_EPS), make bench's relMSE
    weight. Two groups of n pixels, T of unit deviation: dark ones (M = 0, weight 1 / eps =
    100) where F = -0.6 T + noise 0.5, and bright ones (M^2 = 99 eps, weight 1) with F
    uncorrelated, noise 1: c* = 100 * 0.6 / (100 + 1), cut = c* * 60 / (100 * 0.61 + 1).
    Tolerances: 5 standard errors as above."""
    from mscloth.evaluation.metrics import RELMSE_EPS
    from mscloth.integrators import sky_share_pilot as pilot

    assert pilot.RELMSE_EPS == RELMSE_EPS
    n = 20_000
    rng = np.random.default_rng(11)
    T = rng.normal(0.0, 1.0, (2, 2 * n))
    F = np.concatenate([-0.6 * T[:, :n] + rng.normal(0.0, 0.5, (2, n)), rng.normal(0.0, 1.0, (2, n))], axis=1)
    M = np.concatenate([np.zeros(n), np.full(n, np.sqrt(99 * RELMSE_EPS))])
    expected = 60.0 / 101.0
    p = pilot.choose_share(F, T, M)
    assert p.pixels == 2 * n
    assert abs(p.optimal - expected) < 5 * 0.6 / np.sqrt(2 * n)
    assert abs(p.variance_cut - expected * 60.0 / 62.0) < 5 * np.sqrt(2 / n)
    # A floor's pixels: loud, no table read; nothing changes but they are not counted.
    floor_f = rng.normal(0.0, 30.0, (2, n))
    q = pilot.choose_share(np.concatenate([F, floor_f], axis=1), np.concatenate([T, np.zeros((2, n))], axis=1),
                           np.concatenate([M, np.zeros(n)]))
    assert q == p


def test_pilot_takes_the_whole_sky_over_open_cloth_and_none_under_a_roof():
    """Open cloth sees the sky in every sampled direction: c* near 1 and most of the pixel
    variance gone. Under a black roof hiding all but the horizon, the sampled weight hardly
    ties in with what the path brings back: no share, no table read."""
    from mscloth.integrators import sky_share_pilot as pilot

    scene = cloth_under_sky(ROUGH, 40.0, None)
    open_sky = scene.integrator().pilot_sky_share(scene, 4)
    assert 0.8 <= open_sky.share <= 1.0 and open_sky.variance_cut > 0.5, open_sky
    scene = cloth_under_sky(ROUGH, 40.0, None, roof=True)
    roofed = scene.integrator().pilot_sky_share(scene, 4)
    assert roofed.share == 0.0 and roofed.variance_cut < pilot.MIN_VARIANCE_CUT, roofed


def test_auto_share_renders_as_the_pilots_share_given(monkeypatch):
    """``sky_share`` auto on a render of SKY_TABLE_LANES samples or more renders what the
    pilot's share, given explicitly, renders (to float rounding). Below that count, what
    share 0 renders."""
    from mscloth.integrators import clothpath, sky_share_pilot as pilot

    monkeypatch.setattr(clothpath, "SKY_TABLE_LANES", 16 * 16 * 4)
    scene = cloth_under_sky(ROUGH, 40.0, None)
    share = scene.integrator().pilot_sky_share(scene, 4).share
    assert share > 0.0
    auto = np.asarray(mi.render(scene, spp=4, seed=11))
    assert pilot.kept_share(pilot.scene_key(scene, 4)).share == share
    # (The same scene object, its integrator's share set: a scene loaded again may differ
    # in the last bits of its tables.)
    integrator = scene.integrator()
    integrator.sky_share = share
    # (To float rounding: a scene rendered twice may differ in the last bit.)
    np.testing.assert_allclose(auto, np.asarray(mi.render(scene, spp=4, seed=11)), rtol=1e-5, atol=1e-6)
    integrator.sky_share = None
    small = np.asarray(mi.render(scene, spp=2, seed=11))
    integrator.sky_share = 0.0
    np.testing.assert_allclose(small, np.asarray(mi.render(scene, spp=2, seed=11)), rtol=1e-5, atol=1e-6)
    # A share off by 1% would not pass.
    integrator.sky_share = share * 0.99
    assert not np.allclose(auto, np.asarray(mi.render(scene, spp=4, seed=11)), rtol=1e-5, atol=1e-6)


def test_a_crop_of_the_frame_gets_the_frames_share():
    """A crop renders part of the same frame: same key, so the same share, and the same
    decision whether to take one (make bench times its regions as crops); another sample
    count or another scene: another key."""
    from mscloth.integrators import sky_share_pilot as pilot

    full = cloth_under_sky(ROUGH, 40.0, None)
    crop = cloth_under_sky(ROUGH, 40.0, None, crop=(4, 2, 8, 5))
    assert pilot.scene_key(crop, 4) == pilot.scene_key(full, 4)
    # ... and decides as its frame does whether the render is large enough for a table.
    from mscloth.integrators import clothpath
    assert clothpath.frame_lanes(crop, 8 * 5 * 4) == clothpath.frame_lanes(full, 16 * 16 * 4) == 16 * 16 * 4
    assert pilot.scene_key(full, 16) != pilot.scene_key(full, 4)
    assert pilot.scene_key(cloth_under_sky(ROUGH, 40.0, None, roof=True), 4) != pilot.scene_key(full, 4)


def rough_cloth_sampler():
    """(bsdf, sample): the ROUGH cloth and the fibre-level sampling function its sky table
    is built from, (weights (3, n), kept) per lane."""
    import drjit as dr

    bsdf = mi.load_dict(ROUGH)
    ctx = mi.BSDFContext()

    def sample(uv, wi, sample1, sample2):
        si = dr.zeros(mi.SurfaceInteraction3f, dr.width(uv))
        si.uv, si.wi = uv, wi
        bs, weight = bsdf.sample(ctx, si, sample1, sample2)
        kept = bs.pdf > 0.0
        dr.eval(weight, kept)  # (one kernel, as cloth's build evaluates them)
        return np.asarray(weight).reshape(3, -1), np.asarray(kept)

    return bsdf, sample


def test_batched_directions_build_the_same_table(monkeypatch):
    """The build batches directions into launches of about BATCH_LANES lanes; one
    direction per launch (a batch of one) gives the same table to the bit, with a last
    batch that is only partly full."""
    bsdf, sample = rough_cloth_sampler()
    h, w = bsdf.maps.resolution
    dv = bsdf.footprint_data.dv
    n_dirs = len(sky_albedo.node_directions(dv))
    bx, by = sky_albedo.cell_blocks(h, w, dv, 0.5)
    lanes = (h // by) * (w // bx) * sky_albedo.SAMPLES
    tables = []
    for batch in (1, n_dirs // 3 + 1):  # (three launches per side, the last one short)
        monkeypatch.setattr(sky_albedo, "BATCH_LANES", batch * lanes)
        tables.append(sky_albedo.build_sky_albedo_table(sample, h, w, (1.0, 1.0), dv, max_mib=0.5))
    assert tables[0].block == tables[1].block == (bx, by)
    np.testing.assert_array_equal(np.asarray(tables[0].sats.data), np.asarray(tables[1].sats.data))


def test_table_builds_of_every_size_run_one_kernel(monkeypatch):
    """The build's kernel reads its lane count and traces every batch alike: tables of
    other cell counts, batch sizes and a short last batch launch one compiled kernel (each
    other one costs a compilation on a first picture: 6 of them, 0.9 s, on the sphere)."""
    import drjit as dr

    bsdf, sample = rough_cloth_sampler()
    h, w = bsdf.maps.resolution
    dv = bsdf.footprint_data.dv
    bx, by = sky_albedo.cell_blocks(h, w, dv, 0.5)
    # Three launches per side of the 0.5 MiB table, the last one short.
    lanes = (h // by) * (w // bx) * sky_albedo.SAMPLES
    monkeypatch.setattr(sky_albedo, "BATCH_LANES", (len(sky_albedo.node_directions(dv)) // 3 + 1) * lanes)
    dr.set_flag(dr.JitFlag.KernelHistory, True)
    try:
        dr.kernel_history_clear()
        for mib in (0.5, 0.1):
            sky_albedo.build_sky_albedo_table(sample, h, w, (1.0, 1.0), dv, max_mib=mib)
        history = dr.kernel_history()
    finally:
        dr.set_flag(dr.JitFlag.KernelHistory, False)
    big = [k for k in history if k.get("operation_count", 0) > 200]
    assert len({k["size"] for k in big}) >= 3
    assert len({k["hash"] for k in big}) == 1, {(k["hash"], k["size"], k["operation_count"]) for k in big}


def test_cells_keep_square_powers_of_two_and_divide_odd_tiles():
    """Cells are square powers of two while both sides halve (the full tables of the
    built-in tiles); a tile with an odd side still gets cells within the budget, each
    dividing its axis (a 51 x 64 knit: the pilot's 4 MiB table)."""
    dv = 16
    per_cell = 2 * sky_albedo.nodes_per_axis(dv) ** 2 * sky_albedo.CHANNELS_PER_BIN * 4
    for size in (64, 128, 160, 512, 1024):
        bx, by = sky_albedo.cell_blocks(size, size, dv, sky_albedo.MAX_MIB)
        assert bx == by and bx & (bx - 1) == 0 and size % bx == 0
        assert (size // bx + 1) ** 2 * per_cell <= sky_albedo.MAX_MIB * 2 ** 20
        if bx > 1:  # the finest that fits
            assert (size // (bx // 2) + 1) ** 2 * per_cell > sky_albedo.MAX_MIB * 2 ** 20
    for h, w in ((51, 64), (51, 51), (45, 100)):
        bx, by = sky_albedo.cell_blocks(h, w, dv, 4.0)
        assert w % bx == 0 and h % by == 0
        assert (h // by + 1) * (w // bx + 1) * per_cell <= 4.0 * 2 ** 20


def test_a_pilot_that_takes_no_share_builds_no_full_table(monkeypatch):
    """``sky_share`` auto decides on the pilot's small tables: under a roof (no share) no
    full table is built; under the open sky (a share) the full one is, and read."""
    from mscloth.integrators import clothpath
    from mscloth.integrators import sky_share_pilot as pilot

    monkeypatch.setattr(clothpath, "SKY_TABLE_LANES", 16 * 16 * 4)
    built = []
    real = sky_albedo.build_sky_albedo_table

    def recording(*args, max_mib=None, **kwargs):
        built.append(max_mib)
        return real(*args, max_mib=max_mib, **kwargs)

    monkeypatch.setattr(sky_albedo, "build_sky_albedo_table", recording)
    # (A uv scale of its own: tables kept from other tests would not be built again.)
    roofed = cloth_under_sky(ROUGH, 37.0, None, roof=True)
    image = np.asarray(mi.render(roofed, spp=4, seed=3))
    assert np.all(np.isfinite(image))
    assert pilot.kept_share(pilot.scene_key(roofed, 4)).share == 0.0
    assert built == [pilot.PILOT_MAX_MIB]
    open_sky = cloth_under_sky(ROUGH, 37.0, None)
    mi.render(open_sky, spp=4, seed=3)
    assert pilot.kept_share(pilot.scene_key(open_sky, 4)).share > 0.0
    # (The open scene's cloth is another BSDF with the same key: its pilot table is kept.)
    assert built == [pilot.PILOT_MAX_MIB, None]
    table = open_sky.shapes()[0].bsdf().shading.sky_table
    assert table.nbytes > pilot.PILOT_MAX_MIB * 2 ** 20


def test_shares_are_stored_on_disk_and_read_by_a_new_process(monkeypatch, tmp_path):
    """A share measured once is stored in the table cache: a process that has not measured
    it reads it (no pilot runs), and renders the same kernel as the process that ran the
    pilot (the pilot runs before the render traces). A damaged file is measured again."""
    import collections

    import drjit as dr

    from mscloth.integrators import clothpath
    from mscloth.integrators import sky_share_pilot as pilot

    monkeypatch.setenv("MSCLOTH_CACHE", str(tmp_path))
    monkeypatch.setattr(clothpath, "SKY_TABLE_LANES", 16 * 16 * 4)
    scene = cloth_under_sky(ROUGH, 40.0, None)
    key = pilot.scene_key(scene, 4)

    def render_kernels():
        dr.set_flag(dr.JitFlag.KernelHistory, True)
        dr.kernel_history()
        image = np.asarray(mi.render(scene, spp=4, seed=5))
        history = dr.kernel_history()
        dr.set_flag(dr.JitFlag.KernelHistory, False)
        return image, [k["hash"] for k in history if k.get("operation_count", 0) > 1000]

    monkeypatch.setattr(pilot, "_SHARES", collections.OrderedDict())
    first, kernels = render_kernels()
    measured = pilot.kept_share(key)
    assert measured.share > 0.0 and pilot.share_path(key).is_file()
    # A new process: nothing in memory; the pilot must not run.
    monkeypatch.setattr(pilot, "_SHARES", collections.OrderedDict())
    integrator = scene.integrator()

    def no_pilot(*args, **kwargs):
        raise AssertionError("the pilot ran although its share is stored")

    monkeypatch.setattr(integrator, "measure_sky_share", no_pilot)
    again, kernels_again = render_kernels()
    assert pilot.kept_share(key) == measured
    # The render's own kernel (the last) is the one the first process compiled.
    assert kernels_again[-1:] == kernels[-1:]
    np.testing.assert_allclose(again, first, rtol=1e-5, atol=1e-6)
    # Damaged: a warning naming the file, then measured again.
    pilot.share_path(key).write_text("{not json")
    monkeypatch.setattr(pilot, "_SHARES", collections.OrderedDict())
    with pytest.warns(RuntimeWarning, match="sky share"):
        assert pilot.kept_share(key) is None


def test_cloths_whose_tables_differ_in_cells_trace_one_callable():
    """Two cloths whose sky tables have cells of different sizes (tiles of 64^2 and 128^2
    texels) trace the same code (the cells' sizes are read, not literals): the pilot's
    kernel is no larger than with two cloths of one tile size (twice the code otherwise)."""
    import drjit as dr

    from mscloth.integrators import sky_share_pilot as pilot

    def kernel_operations(resolutions):
        scene = {"type": "scene", "integrator": {"type": "clothpath"},
                 "sensor": {"type": "perspective", "fov": 30,
                            "to_world": mi.ScalarTransform4f().look_at(origin=[0, -2, 3], target=[0, 0, 0],
                                                                       up=[0, 0, 1]),
                            "film": {"type": "hdrfilm", "width": 16, "height": 16}},
                 "sky": {"type": "constant", "radiance": 1.0}}
        for k, res in enumerate(resolutions):
            scene[f"square{k}"] = {"type": "rectangle",
                                   "to_world": mi.ScalarTransform4f().translate([k - 0.5, 0, 0]).scale(0.5),
                                   "bsdf": dict(ROUGH, resolution=res, uv_scale=10.0 + k)}
        scene = mi.load_dict(scene)
        integrator = scene.integrator()
        assert integrator.sky_table_possible(scene, pilot.PILOT_MAX_MIB)
        blocks = {s.bsdf().shading.sky_table.block for s in scene.shapes()}
        dr.set_flag(dr.JitFlag.KernelHistory, True)
        dr.kernel_history()
        integrator.sky_terms(scene, np.arange(16), np.arange(16), 1, 0, pilot.PILOT_MAX_MIB)
        history = dr.kernel_history()
        dr.set_flag(dr.JitFlag.KernelHistory, False)
        return blocks, max(k.get("operation_count", 0) for k in history)

    same_blocks, same = kernel_operations((64, 64))
    other_blocks, other = kernel_operations((64, 128))
    assert len(same_blocks) == 1 and len(other_blocks) == 2
    assert other < 1.1 * same, (same, other)


def test_a_pilot_near_the_threshold_measures_again_on_the_full_tables(monkeypatch):
    """Small tables read a cut a little off the full ones': a share refused by less than
    PILOT_MARGIN is measured again on the full tables (whose answer stands); one refused
    by more, or taken, is not."""
    from mscloth.integrators import sky_share_pilot as pilot

    scene = cloth_under_sky(ROUGH, 40.0, None)
    integrator = scene.integrator()
    calls = []

    def fake(cuts):
        def measure(scene, spp, max_mib=pilot.PILOT_MAX_MIB):
            calls.append(max_mib)
            cut = cuts[max_mib]
            return pilot.SkySharePilot(0.4 if cut >= pilot.MIN_VARIANCE_CUT else 0.0, 0.4, cut, 100)
        return measure

    low, above, below = (pilot.MIN_VARIANCE_CUT + d for d in (-pilot.PILOT_MARGIN, 0.01, -0.02))
    for small, full, expected_calls, share in ((low + 0.005, above, [pilot.PILOT_MAX_MIB, None], 0.4),
                                               (low + 0.005, below, [pilot.PILOT_MAX_MIB, None], 0.0),
                                               (low - 0.005, above, [pilot.PILOT_MAX_MIB], 0.0),
                                               (0.5, above, [pilot.PILOT_MAX_MIB], 0.4)):
        calls.clear()
        monkeypatch.setattr(integrator, "measure_sky_share", fake({pilot.PILOT_MAX_MIB: small, None: full}))
        assert integrator.decide_sky_share(scene, 4).share == share
        assert calls == expected_calls


def test_a_crops_pilot_is_the_frames_and_is_stored(monkeypatch, tmp_path):
    """A crop's pilot renders pixels of the whole frame, centred on their pixels as in the
    frame (a crop's camera sees points outside its window with pdf 0): its pixel estimates
    are the frame's but for its camera rays' few-ulp difference, which moves some paths
    (median relative difference 8e-4; 5e-2 when pixels outside the crop went uncentred),
    and its share is stored where the whole frame then reads it."""
    import collections

    from mscloth.integrators import sky_share_pilot as pilot

    monkeypatch.setenv("MSCLOTH_CACHE", str(tmp_path))
    monkeypatch.setattr(pilot, "_SHARES", collections.OrderedDict())
    crop = cloth_under_sky(ROUGH, 40.0, None, crop=(4, 2, 8, 5))
    full = cloth_under_sky(ROUGH, 40.0, None)
    key = pilot.scene_key(crop, 4)
    assert pilot.scene_key(full, 4) == key
    x, y = pilot.pilot_pixels(full.sensors()[0])
    frame, _ = full.integrator().sky_terms(full, x, y, 4, 3)
    cropped, _ = crop.integrator().sky_terms(crop, x, y, 4, 3)
    assert np.median(np.abs(cropped - frame) / np.abs(frame)) < 0.01
    measured = crop.integrator().pilot_sky_share(crop, 4)
    assert pilot.share_path(key).is_file()
    monkeypatch.setattr(pilot, "_SHARES", collections.OrderedDict())
    assert full.integrator().pilot_sky_share(full, 4) == measured


def test_the_pilot_does_not_depend_on_earlier_renders():
    """The pilot's renders stratify each pixel's samples as a render of one pass at its
    spp does, whatever the sensor's sampler was last set to: the same share before and
    after a render at another sample count (the built-in scenes' stratified sampler)."""
    scene = cloth_under_sky(ROUGH, 40.0, 0.0, sampler="multijitter")
    integrator = scene.integrator()
    before = integrator.measure_sky_share(scene, 4)
    mi.render(scene, spp=2, seed=1)
    assert integrator.measure_sky_share(scene, 4) == before


def test_the_pilot_renders_at_the_count_the_sampler_takes(monkeypatch, tmp_path):
    """A stratified sampler rounds a render's spp up to a square (8 -> 9): the pilot runs
    once, before the trace, at the count the render takes (it failed at the asked count,
    which the sampler's samples per wavefront cannot divide), and keeps its share by it."""
    import collections

    from mscloth.integrators import clothpath
    from mscloth.integrators import sky_share_pilot as pilot

    monkeypatch.setenv("MSCLOTH_CACHE", str(tmp_path))
    monkeypatch.setattr(clothpath, "SKY_TABLE_LANES", 16 * 16 * 4)
    monkeypatch.setattr(pilot, "_SHARES", collections.OrderedDict())
    scene = cloth_under_sky(ROUGH, 40.0, None, sampler="stratified")
    assert pilot.render_sample_count(scene.sensors()[0], 8) == 9
    integrator = scene.integrator()
    counts = []
    real = integrator.measure_sky_share

    def measure(scene, spp, *args):
        counts.append(spp)
        return real(scene, spp, *args)

    monkeypatch.setattr(integrator, "measure_sky_share", measure)
    image = np.asarray(mi.render(scene, spp=8, seed=2))
    assert np.all(np.isfinite(image))
    assert counts == [9] and pilot.kept_share(pilot.scene_key(scene, 9)) is not None
