"""Lobe-selection calibration: the sampler's proxies, times the measured ratios, average to
the lobes' albedos, and the calibrated sampler has less variance than the raw proxies."""
import drjit as dr
import mitsuba as mi
import numpy as np
import pytest

import mscloth
from mscloth.bsdf.lobe_calibration import CALIBRATED, MAX_SHARE_FACTOR, MIN_RATIO, LobeCalibration

mscloth.register()

TWILL = {"type": "cloth", "pattern": "twill-2-1-S", "multiscale": False,
         "diffuse_albedo": {"type": "rgb", "value": [0.42, 0.1, 0.08]},
         "specular_albedo": 0.45, "specular_transmittance": 0.25, "diffuse_transmittance": 0.05,
         "roughness": 0.3, "sheen_thickness": 0.3}


def lanes_at(mu, n, seed):
    rng = np.random.default_rng(seed)
    phi = rng.random(n) * 2.0 * np.pi
    s = np.sqrt(1.0 - mu * mu)
    si = dr.zeros(mi.SurfaceInteraction3f, n)
    si.wi = mi.Vector3f(s * np.cos(phi), s * np.sin(phi), np.full(n, mu))
    si.uv = mi.Point2f(rng.random(n), rng.random(n))
    return si, mi.Float(rng.random(n)), mi.Point2f(rng.random(n), rng.random(n))


def mean_and_se(x):
    x = np.asarray(x, dtype=np.float64)
    return x.mean(), x.std() / np.sqrt(x.size)


def test_calibrated_proxies_average_to_the_lobe_albedos():
    """At three of the table's cosines, on fresh texels and azimuths: each lobe's albedo
    (mean weight of lobe-only samples) equals its mean calibrated proxy within 5 standard
    errors of both estimates and of the table's own measurement (1024 lanes)."""
    bsdf = mi.load_dict(TWILL)
    cal = bsdf.fibre.calibration
    nodes = cal.nodes
    n = 16384
    for j in (3, 8, 13):
        mu = (j + 0.5) / nodes
        assert np.all(cal.ratios[:, j] > MIN_RATIO * cal.ratios.max(axis=1))  # not floored
        si, s1, s2 = lanes_at(mu, n, seed=100 + j)
        proxies = cal.scale(bsdf.fibre.point_proxies(si), si.wi.z)
        for slot, comps in CALIBRATED:
            lanes = np.zeros(n)
            for c in comps:
                ctx = mi.BSDFContext()
                ctx.component = c
                _, weight = bsdf.sample(ctx, si, s1, s2)
                lanes += np.asarray(weight, dtype=np.float64).mean(axis=0)
            albedo, se_a = mean_and_se(lanes)
            proxy, se_p = mean_and_se(np.asarray(proxies[slot]))
            # The table's ratio came from 1024 lanes: its error, relative, is about the
            # lanes' relative spread over sqrt(1024).
            se_table = proxy * np.hypot(se_a / albedo, se_p / proxy) * np.sqrt(n / 1024.0)
            tol = 5.0 * np.sqrt(se_a ** 2 + se_p ** 2 + se_table ** 2)
            assert abs(albedo - proxy) <= tol, (mu, slot, albedo, proxy, tol)
            assert albedo > 0.0


def weight_relvar(bsdf, theta_deg, n=200_000, footprint_texels=0.0):
    t = np.radians(theta_deg)
    si, s1, s2 = lanes_at(np.cos(t), n, seed=5)
    if footprint_texels:
        d = footprint_texels / bsdf.fibre.tile.tile_w
        si.uv = mi.Point2f(0.37, 0.61)
        si.duv_dx = mi.Vector2f(d, 0.0)
        si.duv_dy = mi.Vector2f(0.0, d)
    _, weight = bsdf.sample(mi.BSDFContext(), si, s1, s2)
    w = np.asarray(weight, dtype=np.float64).mean(axis=0)
    return w.mean(), w.var() / w.mean() ** 2


def test_calibration_cuts_the_variance_of_footprint_samples():
    """A 64-texel footprint at 60 degrees: the same mean weight (the albedo: sampling is
    unbiased either way, within 5 standard errors), and a relative variance of the weight
    at most half of the raw proxies' (measured: 0.19 against 0.66)."""
    bsdf = mi.load_dict(dict(TWILL, multiscale=True))
    calibrated = weight_relvar(bsdf, 60.0, footprint_texels=64.0)
    bsdf.fibre.calibration = bsdf.estimator.calibration = None
    raw = weight_relvar(bsdf, 60.0, footprint_texels=64.0)
    n = 200_000
    se = calibrated[0] * np.sqrt((calibrated[1] + raw[1]) / n)
    assert abs(calibrated[0] - raw[0]) <= 5.0 * se
    assert calibrated[1] <= 0.5 * raw[1], (calibrated, raw)


def test_the_share_passes_footprint_sampler_is_the_bsdfs_sample_over_whole_footprints():
    """The share passes sample through the footprint branch alone (a smaller kernel); over
    footprints above FOOTPRINT_TEXELS that is bsdf.sample exactly, lane by lane."""
    from mscloth.bsdf.lobes import enabled_lobes

    bsdf = mi.load_dict(dict(TWILL, multiscale=True))
    si, s1, s2 = lanes_at(0.6, 4096, seed=9)
    d = 64.0 / bsdf.fibre.tile.tile_w
    si.duv_dx = mi.Vector2f(d, 0.0)
    si.duv_dy = mi.Vector2f(0.0, 0.5 * d)
    ctx = mi.BSDFContext()
    bs, weight = bsdf.sample(ctx, si, s1, s2)
    bs2, weight2 = bsdf.shading.sample_footprint(enabled_lobes(ctx), si, s1, s2)
    for a, b in ((bs.wo, bs2.wo), (bs.pdf, bs2.pdf), (weight, weight2)):
        assert np.array_equal(np.asarray(a), np.asarray(b))
    assert np.array_equal(np.asarray(bs.sampled_component), np.asarray(bs2.sampled_component))
    assert np.count_nonzero(np.asarray(weight)[0]) > 2000  # lanes that sampled something


@pytest.mark.parametrize("theta", [20.0, 60.0])
def test_share_factors_cut_the_variance_of_footprint_samples(theta):
    """The footprint mixture's second calibration stage against the albedo ratios alone, on
    a 64-texel footprint: the same mean weight (within 5 standard errors) and at most 0.6
    times the weight's relative variance (measured here, with folded flake samples: 0.095 /
    0.094 -> 0.037 / 0.050 at 20 / 60 degrees, 0.39x / 0.53x; without share factors the
    ratio is 1). The factors stay within their bounds, and the fibre-level sampler keeps
    the albedo ratios."""
    bsdf = mi.load_dict(dict(TWILL, multiscale=True))
    factors = bsdf.estimator.calibration.factors
    assert np.all((factors >= 1.0 / MAX_SHARE_FACTOR) & (factors <= MAX_SHARE_FACTOR))
    assert np.all(bsdf.fibre.calibration.factors == 1.0)
    assert np.array_equal(bsdf.estimator.calibration.albedo_ratios, bsdf.fibre.calibration.albedo_ratios)
    shared = weight_relvar(bsdf, theta, footprint_texels=64.0)
    bsdf.estimator.calibration = LobeCalibration(bsdf.fibre.calibration.albedo_ratios)
    albedo_only = weight_relvar(bsdf, theta, footprint_texels=64.0)
    n = 200_000
    se = shared[0] * np.sqrt((shared[1] + albedo_only[1]) / n)
    assert abs(shared[0] - albedo_only[0]) <= 5.0 * se
    assert shared[1] <= 0.6 * albedo_only[1], (shared, albedo_only)


def test_calibration_tables_must_match():
    with pytest.raises(ValueError, match="factors of shape"):
        LobeCalibration(np.ones((5, 16)), np.ones((4, 16)))


def test_calibrations_are_cached_and_keyed_on_what_they_measure(tmp_path, monkeypatch):
    """A BSDF loaded again reads its calibration from the cache (the same arrays the
    measurement gave); another parameter value, other maps or other estimator constants
    measure anew; a damaged file is measured and written again, with a warning; a spatially
    varying texture is never cached (its key would need the texture's data)."""
    from mscloth.bsdf import calibration_cache
    from mscloth.bsdf.footprint_estimator import FootprintEstimator

    monkeypatch.setenv("MSCLOTH_CACHE", str(tmp_path))
    folder = tmp_path / calibration_cache.SUBDIR
    small = dict(TWILL, multiscale=True, resolution=64)

    def files():
        return sorted(folder.glob("*.npz")) if folder.is_dir() else []

    first = mi.load_dict(small)
    assert len(files()) == 1
    calls = []
    real = calibration_cache.save
    monkeypatch.setattr(calibration_cache, "save", lambda *a, **k: (calls.append(a[0]), real(*a, **k)))
    again = mi.load_dict(small)
    assert not calls  # read, not measured
    assert np.array_equal(again.fibre.calibration.ratios, first.fibre.calibration.ratios)
    assert np.array_equal(again.estimator.calibration.ratios, first.estimator.calibration.ratios)

    mi.load_dict(dict(small, specular_albedo=0.4))
    mi.load_dict(dict(small, pattern="twill-2-1"))
    monkeypatch.setattr(FootprintEstimator, "DEFENSIVE_COSINE", 0.2)
    mi.load_dict(small)
    assert len(calls) == 3 and len(set(calls)) == 3 and len(files()) == 4
    monkeypatch.undo()
    monkeypatch.setenv("MSCLOTH_CACHE", str(tmp_path))

    stored = files()[0]
    for path in files():
        path.write_bytes(b"not an npz")
    with pytest.warns(RuntimeWarning, match="ignoring cached calibration"):
        damaged = mi.load_dict(small)
    assert np.array_equal(damaged.fibre.calibration.ratios, first.fibre.calibration.ratios)
    assert stored.exists()

    before = len(files())
    texels = np.linspace(0.2, 0.4, 4 * 4 * 3).reshape(4, 4, 3)
    varying = dict(small, specular_albedo={"type": "bitmap", "data": mi.TensorXf(texels), "raw": True})
    assert mi.load_dict(varying).fibre.calibration is not None
    assert len(files()) == before
