"""Parameters of the ``cloth`` BSDF through ``mi.traverse`` (issue 23): every parameter
flagged differentiable has the gradient of central finite differences, at fibre level
(a small render) and multi-scale (footprints over a 16x16 grid of pixels); a changed
roughness rebuilds what was built from it.

Finite differences use the seed the gradient pass uses (``seed_grad``), so both see the
same samples and their noise cancels: what is left is the O(h^2) error of the central
difference and float32 rounding. Measured (2% steps): at most 0.14% of a parameter's own
derivative (thickness; 0.04% or less for the others), at both levels.
"""
import drjit as dr
import mitsuba as mi
import numpy as np
import pytest

import mscloth
from mscloth.bsdf.parameters import EXPOSED, SPECTRUM_PARAMETERS, exposure_flags
from mscloth.errors import ParameterError

mscloth.register()

RES = 16
CLOTH = {"type": "cloth", "pattern": "plain", "resolution": 64, "uv_scale": 4.0, "roughness": 0.35,
         "thickness": 1.5, "specular_albedo": 0.5, "specular_transmittance": 0.3, "diffuse_albedo": 0.3,
         "diffuse_transmittance": 0.1, "sheen_color": 0.6, "sheen_roughness": 0.45, "sheen_thickness": 0.4}
#: Central differences step each parameter by this fraction of its value.
STEP = 0.02
#: |AD - FD| <= RTOL |FD| + ATOL max |FD| over the parameters: 3.5x the largest error measured.
RTOL, ATOL = 0.005, 1e-5
#: Per-pixel, per-channel weights of the loss, so that a gradient wrong in one place shows.
WEIGHTS = np.random.default_rng(5).uniform(0.5, 1.5, (RES, RES, 3))


def differentiable(params):
    return [k for k in params.keys() if not params.flags(k) & mi.ParamFlags.NonDifferentiable]


def check_gradients(params, loss, ad_loss):
    """Compare d loss / d k by AD (``ad_loss()``, a Float of the differentiable ``params``)
    with central differences of ``loss()`` (float64), for every differentiable key."""
    keys = differentiable(params)
    fd = {}
    for k in keys:
        x = float(params[k][0])
        values = []
        for sign in (1.0, -1.0):
            params[k] = mi.Float(x * (1.0 + sign * STEP))
            params.update()
            values.append(loss())
        params[k] = mi.Float(x)
        params.update()
        fd[k] = (values[0] - values[1]) / (2.0 * STEP * x)
    for k in keys:
        dr.enable_grad(params[k])
    params.update()
    dr.backward(ad_loss())
    ad = {k: float(dr.grad(params[k])[0]) for k in keys}
    scale = max(abs(v) for v in fd.values())
    bad = {k: (ad[k], fd[k]) for k in keys if not abs(ad[k] - fd[k]) <= RTOL * abs(fd[k]) + ATOL * scale}
    assert not bad, f"AD vs FD gradients differ: {bad}"
    return keys, fd


# ----------------------------------------------------------------------------------------
# Fibre level: a render
# ----------------------------------------------------------------------------------------
def cloth_scene(bsdf: dict):
    """A rectangle of cloth seen at 45 degrees, lit by a constant sky (both sides) and a
    sun. Emitter sampling only (``direct``, no BSDF samples): each sample evaluates the BSDF
    at directions that do not depend on its parameters, so the render is differentiable
    sample by sample (BSDF samples move with the lobe-selection probabilities)."""
    return mi.load_dict({
        "type": "scene",
        "integrator": {"type": "direct", "bsdf_samples": 0, "emitter_samples": 2},
        "sensor": {"type": "perspective", "fov": 30,
                   "to_world": mi.ScalarTransform4f().look_at(origin=[0, -3, 3], target=[0, 0, 0], up=[0, 0, 1]),
                   "sampler": {"type": "independent", "sample_count": 4},
                   "film": {"type": "hdrfilm", "width": RES, "height": RES, "rfilter": {"type": "box"}}},
        "sky": {"type": "constant", "radiance": 0.5},
        "sun": {"type": "directional", "direction": [0.3, 0.5, -1.0], "irradiance": 3.0},
        "cloth": {"type": "rectangle", "bsdf": bsdf},
    })


def test_fibre_level_gradients_match_finite_differences():
    scene = cloth_scene(dict(CLOTH, multiscale=False))
    params = mi.traverse(scene)
    params.keep(r"cloth\.bsdf\..*")
    weights = mi.TensorXf(WEIGHTS.astype(np.float32))

    def loss():
        with dr.suspend_grad():
            image = np.array(mi.render(scene, seed=7, spp=4), dtype=np.float64)
        return float(np.mean(image * WEIGHTS))

    def ad_loss():
        return dr.mean(mi.render(scene, params=params, seed=3, seed_grad=7, spp=4) * weights, axis=None)

    keys, fd = check_gradients(params, loss, ad_loss)
    # Every exposed parameter but the uv scales is differentiable at fibre level, and moves
    # this image.
    assert sorted(keys) == sorted(f"cloth.bsdf.{n}" + (".value" if n in SPECTRUM_PARAMETERS else "")
                                  for n in EXPOSED if not n.startswith("uv_scale"))
    assert all(abs(v) > 0.0 for v in fd.values()), fd


# ----------------------------------------------------------------------------------------
# Multi-scale: footprints
# ----------------------------------------------------------------------------------------
#: The viewer (local frame) and the lights: a sun and a constant sky (both sides of the
#: cloth) seen along fixed directions, stratified over the sphere.
WI = np.array([0.0, -0.6, 0.8])
SUN, SUN_E, SKY_L, SKY_N = np.array([0.3, 0.5, 0.81]), 3.0, 0.5, 16


def unit(v):
    v = np.asarray(v, dtype=float) / np.linalg.norm(v)
    return mi.Vector3f(*(float(c) for c in v))


def sky_directions():
    rng = np.random.default_rng(2)
    k = np.arange(SKY_N)
    z = 1.0 - 2.0 * (k + rng.random(SKY_N)) / SKY_N
    phi = 2.0 * np.pi * rng.random(SKY_N)
    r = np.sqrt(1.0 - z * z)
    return np.stack([r * np.cos(phi), r * np.sin(phi), z], axis=1)


def footprint_image(bsdf, weights=None):
    """(RES, RES, 3) radiance of an orthographic view of the cloth, one footprint per pixel
    (16 texels wide: shaded whole), lit by the sun and the sky: a render without sampling,
    since footprint evaluation is deterministic per shading point. With ``weights``
    (RES, RES, 3): the mean of the image times them instead, as a Float (for AD).

    One eval over every (pixel, light direction) pair: 17 evals of the pixels traced one
    after the other made a kernel whose derivative took minutes to compile."""
    lights = [(SUN, SUN_E)] + [(w, SKY_L * 4.0 * np.pi / SKY_N) for w in sky_directions()]
    n = RES * RES
    m = n * len(lights)
    iy, ix = np.divmod(np.arange(m) % n, RES)
    wo = np.repeat(np.array([np.asarray(w) / np.linalg.norm(w) for w, _ in lights]), n, axis=0)
    si = dr.zeros(mi.SurfaceInteraction3f, m)
    si.wi = unit(WI)
    si.uv = mi.Point2f((ix + 0.5) / RES, (iy + 0.5) / RES)
    si.duv_dx = mi.Vector2f(1.0 / RES, 0.0)
    si.duv_dy = mi.Vector2f(0.0, 1.0 / RES)
    value = bsdf.eval(mi.BSDFContext(), si, mi.Vector3f(wo[:, 0], wo[:, 1], wo[:, 2]))
    scale = np.repeat([e for _, e in lights], n)
    if weights is None:
        values = np.array(value, dtype=np.float64).T * scale[:, None]
        return values.reshape(len(lights), RES, RES, 3).sum(axis=0)
    c = np.tile(weights.reshape(n, 3), (len(lights), 1)) * scale[:, None] / (n * 3)
    return dr.sum(value[0] * mi.Float(c[:, 0]) + value[1] * mi.Float(c[:, 1]) + value[2] * mi.Float(c[:, 2]))


@pytest.fixture(scope="module")
def multiscale_cloth():
    return mi.load_dict(dict(CLOTH, multiscale=True))


def test_multiscale_gradients_match_finite_differences(multiscale_cloth):
    bsdf = multiscale_cloth
    params = mi.traverse(bsdf)

    def loss():
        with dr.suspend_grad():
            return float(np.mean(footprint_image(bsdf) * WEIGHTS))

    try:
        keys, fd = check_gradients(params, loss, lambda: footprint_image(bsdf, WEIGHTS))
    finally:
        for k in params.keys():
            dr.disable_grad(params[k])
    # Roughness is baked into the footprint's directional tables: not differentiable here.
    assert "roughness" not in keys and "thickness" in keys and "sheen_roughness" in keys
    assert all(abs(v) > 0.0 for v in fd.values()), fd


def test_traverse_flags_follow_the_table(multiscale_cloth):
    """``traverse`` flags each parameter as parameters.EXPOSED says, per mode: roughness is
    differentiable at fibre level only, the uv scales nowhere."""
    for bsdf in (mi.load_dict({"type": "cloth", "multiscale": False, "visibility": False}), multiscale_cloth):
        multiscale = bsdf.multiscale
        params = mi.traverse(bsdf)
        for key in params.keys():
            name = key.split(".")[0]
            assert params.flags(key) == +exposure_flags(name, multiscale), key
        assert sorted(k.split(".")[0] for k in params.keys()) == sorted(EXPOSED)
        nondiff = {k for k in params.keys() if params.flags(k) & mi.ParamFlags.NonDifferentiable}
        assert nondiff == ({"uv_scale", "uv_scale_v", "roughness"} if multiscale else {"uv_scale", "uv_scale_v"})


# ----------------------------------------------------------------------------------------
# Changed build parameters
# ----------------------------------------------------------------------------------------
def test_changed_roughness_rebuilds_the_footprint_tables(multiscale_cloth):
    """After params['roughness'] = x; params.update() the footprint (its mean D from the
    directional SAT) shades as a BSDF loaded with roughness x: same tables, same eval and
    pdf; before the fix it kept the tables of the old roughness."""
    bsdf = multiscale_cloth
    before = np.array(footprint_image(bsdf))
    params = mi.traverse(bsdf)
    params["roughness"] = 0.5
    params.update()
    fresh = mi.load_dict(dict(CLOTH, multiscale=True, roughness=0.5))
    assert bsdf.table_key == fresh.table_key and bsdf.table_key.roughness == 0.5
    after = np.array(footprint_image(bsdf))
    assert np.abs(after - before).max() > 0.02 * before.max()  # the roughness shows
    np.testing.assert_allclose(after, np.array(footprint_image(fresh)), rtol=1e-6, atol=1e-7)
    n = 64
    si = dr.zeros(mi.SurfaceInteraction3f, n)
    si.wi = unit(WI)
    si.uv = mi.Point2f(np.linspace(0.0, 1.0, n, endpoint=False), 0.3)
    si.duv_dx, si.duv_dy = mi.Vector2f(1.0 / RES, 0.0), mi.Vector2f(0.0, 1.0 / RES)
    wo = unit(SUN)
    np.testing.assert_allclose(np.array(bsdf.pdf(mi.BSDFContext(), si, wo)),
                               np.array(fresh.pdf(mi.BSDFContext(), si, wo)), rtol=1e-6)


def test_changed_roughness_at_fibre_level_keeps_the_tables():
    """At fibre level shading reads only the visibility tables, which do not depend on the
    roughness: a change keeps them and shades as a freshly loaded BSDF does."""
    bsdf = mi.load_dict(dict(CLOTH, multiscale=False))
    tables = bsdf.footprint_data
    params = mi.traverse(bsdf)
    params["roughness"] = 0.2
    params.update()
    assert bsdf.footprint_data is tables and bsdf.build.roughness == 0.2
    fresh = mi.load_dict(dict(CLOTH, multiscale=False, roughness=0.2))
    np.testing.assert_allclose(np.array(footprint_image(bsdf)), np.array(footprint_image(fresh)),
                               rtol=1e-6, atol=1e-7)


def test_a_roughness_the_tables_cannot_take_is_a_clear_error():
    """direction_rank 300 fits the 32^2 bins of roughness 0.1, not the 16^2 of 0.3."""
    bsdf = mi.load_dict({"type": "cloth", "roughness": 0.1, "direction_rank": 300, "multiscale": False,
                         "visibility": False})
    params = mi.traverse(bsdf)
    params["roughness"] = 0.3
    with pytest.raises(ParameterError, match=r"cloth \[.*\]: roughness 0.3 .*direction_rank.*reload the scene"):
        params.update()


def test_changed_shading_parameters_are_checked_and_rebuild_the_samplers():
    bsdf = mi.load_dict({"type": "cloth", "multiscale": False, "visibility": False})
    params = mi.traverse(bsdf)
    sampler, diffuse = bsdf.fibre.samplers.sheen, bsdf.fibre.samplers.diffuse
    params["sheen_thickness"] = 0.7
    params.update()
    # The tables a scene with sheen_thickness 0.7 has (shared: the same ones).
    assert bsdf.fibre.samplers.sheen is not sampler and bsdf.fibre.samplers.diffuse is not diffuse
    other = mi.load_dict({"type": "cloth", "multiscale": False, "visibility": False, "sheen_thickness": 0.7})
    assert bsdf.fibre.samplers.sheen is other.fibre.samplers.sheen
    assert bsdf.fibre.samplers.diffuse is other.fibre.samplers.diffuse
    # uv_scale_v was derived from uv_scale (and the square tile): it still is.
    params["uv_scale"] = 3.0
    params.update()
    assert float(bsdf.params.uv_scale_v[0]) == 3.0
    params["thickness"] = -1.0
    with pytest.raises(ParameterError, match=r"cloth \[.*\]: parameter 'thickness' .* got -1"):
        params.update()


def test_gradients_flow_through_several_directions_at_once():
    """eval_pdf_sample_n evaluates its directions in one symbolic loop, which reverse-mode
    AD cannot cross: where a parameter carries a gradient the directions are unrolled, and
    the gradient of two directions' values at once is the sum of each one's alone."""
    bsdf = mi.load_dict(dict(CLOTH, multiscale=False))
    params = mi.traverse(bsdf)
    key = next(k for k in params.keys() if k.endswith("thickness") and "sheen" not in k)
    rng = np.random.default_rng(3)
    n = 2000
    si = dr.zeros(mi.SurfaceInteraction3f, n)
    si.wi = dr.normalize(mi.Vector3f(rng.random(n) - 0.5, rng.random(n) - 0.5, rng.random(n) + 0.2))
    si.uv = mi.Point2f(rng.random(n), rng.random(n))
    wos = [dr.normalize(mi.Vector3f(rng.random(n) - 0.5, rng.random(n) - 0.5, rng.random(n) + 0.1)) for _ in range(2)]
    ctx = mi.BSDFContext()

    def gradient(loss_of):
        dr.enable_grad(params[key])
        params.update()
        try:
            dr.backward(loss_of())
            return float(dr.grad(params[key])[0])
        finally:
            dr.disable_grad(params[key])
            params.update()

    def both():
        values = bsdf.eval_pdf_sample_n(ctx, si, wos, mi.Float(0.5), mi.Point2f(0.5, 0.5))[0]
        return dr.sum(values[0] + values[1], axis=None)

    together = gradient(both)
    alone = sum(gradient(lambda wo=wo: dr.sum(bsdf.eval(ctx, si, wo), axis=None)) for wo in wos)
    assert together != 0.0
    assert together == pytest.approx(alone, rel=1e-4)


def test_gradients_flow_through_a_shiny_footprint_sample(monkeypatch):
    """Shiny cloth weighs a sampled direction at a texel and reports the footprint
    mixture's density from a loop over its texels: the gradients of the weight and of the
    density with respect to the flakes' thickness come back, not zero, and equal those of
    the code with every texel loop unrolled (one traced copy per texel)."""
    from mscloth.bsdf.footprint_estimator import FootprintEstimator
    rng = np.random.default_rng(4)
    n = 4000
    si = dr.zeros(mi.SurfaceInteraction3f, n)
    si.wi = dr.normalize(mi.Vector3f(rng.random(n) - 0.5, rng.random(n) - 0.5, rng.random(n) + 0.2))
    si.uv = mi.Point2f(rng.random(n), rng.random(n))
    si.duv_dx = mi.Vector2f(0.1, 0.0)
    si.duv_dy = mi.Vector2f(0.0, 0.1)
    si.p = mi.Point3f(*(mi.Float(rng.random(n)) for _ in range(3)))
    sample1, sample2 = mi.Float(rng.random(n)), mi.Point2f(rng.random(n), rng.random(n))

    def gradients():
        bsdf = mi.load_dict(dict(CLOTH, multiscale=True, pattern="satin-8-3", roughness=0.1))
        assert bsdf.estimator.sample_at_texel()
        params = mi.traverse(bsdf)
        key = next(k for k in params.keys() if k.endswith("thickness") and "sheen" not in k)
        out = []
        for part in ("weight", "pdf"):
            dr.enable_grad(params[key])
            params.update()
            try:
                bs, weight = bsdf.sample(mi.BSDFContext(), si, sample1, sample2)
                dr.backward(dr.sum(weight[0] if part == "weight" else bs.pdf, axis=None))
                out.append(float(dr.grad(params[key])[0]))
            finally:
                dr.disable_grad(params[key])
                params.update()
        return out

    as_built = gradients()
    monkeypatch.setattr(FootprintEstimator, "LOOP_TEXELS", False)
    unrolled = gradients()
    assert all(g != 0.0 for g in as_built), as_built
    np.testing.assert_allclose(as_built, unrolled, rtol=1e-5)


# ----------------------------------------------------------------------------------------
# clothpath renders
# ----------------------------------------------------------------------------------------
def test_clothpath_refuses_gradients_in_one_line():
    """A clothpath render with a gradient on a cloth parameter: one ParameterError, whether
    the gradient comes through mi.render's params (its backward pass) or the integrator's
    render would record it; the primal renders (mi.render without params, or under
    dr.suspend_grad). Before, the sheen parameters'
    gradient kernel failed LLVM's verifier and Dr.Jit aborted the process."""
    from mscloth.integrators.clothpath import NOT_DIFFERENTIABLE

    scene = mi.load_dict({
        "type": "scene", "integrator": {"type": "clothpath", "max_depth": 3},
        "sensor": {"type": "perspective", "fov": 35,
                   "to_world": mi.ScalarTransform4f().look_at(origin=[0, 0, 3], target=[0, 0, 0], up=[0, 1, 0]),
                   "film": {"type": "hdrfilm", "width": 8, "height": 8}},
        "sky": {"type": "constant", "radiance": 0.8},
        "cloth": {"type": "rectangle", "bsdf": {"type": "cloth", "pattern": "plain", "uv_scale": 12}}})
    params = mi.traverse(scene)
    key = "cloth.bsdf.sheen_roughness"
    dr.enable_grad(params[key])
    params.update()
    message = NOT_DIFFERENTIABLE.split(":")[1].strip()
    try:
        with pytest.raises(Exception, match=message) as caught:
            dr.backward(dr.mean(mi.render(scene, params, spp=1), axis=None))
        assert "clothpath: renders are not differentiable" in str(caught.value)
        with pytest.raises(ParameterError, match=message):  # the render recorded for AD
            scene.integrator().render(scene, spp=1)
        with dr.suspend_grad():
            assert np.all(np.isfinite(np.array(scene.integrator().render(scene, spp=1))))
        assert np.all(np.isfinite(np.array(mi.render(scene, spp=1))))  # no params: the primal
    finally:
        dr.disable_grad(params[key])
        params.update()
