"""Tests of the pure scattering maths: SGGX (sggx.py), SpongeCake (spongecake.py), sheen (sheen.py).

docs/design.md §3 (the point BSDF) and §6 (validation). Statistical checks use fixed seeds and
compare a Monte Carlo estimate with its reference to within 5 standard errors, the standard
error being computed from the samples themselves (plus, where stated, a small floor for the
float32 arithmetic of the package). Deterministic checks use tolerances derived from float32
rounding (eps32 = 2^-24 ≈ 6e-8 per operation).

The slab reference of test 3 is written here in NumPy float64 from the physics of a
single-scattering microflake slab, sharing no code with the package.
"""
from __future__ import annotations

import functools
import math

import numpy as np
import pytest

import mscloth  # noqa: F401  (sets DRJIT_LIBLLVM_PATH before Dr.Jit starts)
import mitsuba as mi
import drjit as dr

if mi.variant() is None:  # normally done by conftest.py
    mi.set_variant("llvm_ad_rgb")

from mscloth.scattering import sggx, sheen, spongecake  # noqa: E402

EPS32 = 2.0 ** -24
N_SIGMA = 5.0


# --------------------------------------------------------------------------- helpers


def unit(v):
    v = np.asarray(v, dtype=np.float64)
    return v / np.linalg.norm(v, axis=-1, keepdims=True)


def dir_theta(theta_deg, phi_deg=0.0):
    """Unit vector at polar angle theta from +z and azimuth phi (degrees)."""
    th, ph = math.radians(theta_deg), math.radians(phi_deg)
    return np.array([math.sin(th) * math.cos(ph), math.sin(th) * math.sin(ph), math.cos(th)])


def vec(a):
    """NumPy (3,) or (N, 3) -> mi.Vector3f (width 1 or N)."""
    a = np.asarray(a)
    if a.ndim == 1:
        return mi.Vector3f(*[float(x) for x in a])
    a = a.astype(np.float32)
    return mi.Vector3f(a[:, 0], a[:, 1], a[:, 2])


def flt(x):
    """Python float or NumPy array -> mi.Float."""
    if np.ndim(x) == 0:
        return mi.Float(float(x))
    return mi.Float(np.asarray(x, dtype=np.float32))


def npf(x):
    """Dr.Jit array -> float64 NumPy ((N,) for Float/Bool as bool, (N, 3) for vectors)."""
    a = np.array(x)
    if a.dtype == bool:
        return a
    a = a.astype(np.float64)
    return a.T if a.ndim == 2 else a


def mean_and_se(x):
    """Sample mean and its standard error (float64)."""
    x = np.asarray(x, dtype=np.float64)
    return x.mean(), x.std(ddof=1) / math.sqrt(x.size)


def uniform_sphere(n, seed):
    """n i.i.d. uniform directions as (mi.Vector3f, solid-angle pdf 1/(4 pi))."""
    u = np.random.default_rng(seed).random((n, 2), dtype=np.float32)
    return mi.warp.square_to_uniform_sphere(mi.Point2f(u[:, 0], u[:, 1])), 1.0 / (4.0 * math.pi)


def random_unit(rng, n):
    return unit(rng.normal(size=(n, 3)))


def random_upper(rng, n, zmin=0.0):
    """Uniform directions on the upper hemisphere with z >= zmin."""
    z = rng.uniform(zmin, 1.0, n)
    phi = rng.uniform(0.0, 2 * math.pi, n)
    r = np.sqrt(1.0 - z * z)
    return np.stack([r * np.cos(phi), r * np.sin(phi), z], axis=1)


def sggx_matrix(t, alpha):
    """Explicit 3x3 SGGX matrix S = alpha^2 t t^T + (I - t t^T) (float64)."""
    t = unit(t)
    tt = np.outer(t, t)
    return alpha * alpha * tt + np.eye(3) - tt


def ndf_reference(m, S):
    """D(m) = 1 / (pi sqrt(det S) (m^T S^-1 m)^2), straight from the formula via numpy.linalg."""
    q = np.einsum("ni,ij,nj->n", m, np.linalg.inv(S), m)
    return 1.0 / (math.pi * math.sqrt(np.linalg.det(S)) * q * q)


def sigma_reference(w, S):
    """sigma(w) = sqrt(w^T S w) for (N, 3) or (3,) w."""
    w = np.atleast_2d(w)
    return np.sqrt(np.einsum("ni,ij,nj->n", w, S, w))


def chi2_passes(sample_func, pdf_func, seed=0, sample_count=1_000_000, ires=16):
    """Mitsuba's Pearson chi^2 test on the sphere at its default 1% significance.

    ``ires=16`` trapezoid points per cell side instead of the default 4: with α = 0.15 the
    fibre band is only a few cells wide and the default quadrature of the pdf is off by
    4e-4 of the total mass (pdf sum 0.9996), enough for 10^6 samples to reject a correct
    sampler. At 16 the pdf sums to 1 − 1e-5.
    Returns (passed, messages, integrated pdf mass).
    """
    test = mi.chi2.ChiSquareTest(
        domain=mi.chi2.SphericalDomain(),
        sample_func=sample_func,
        pdf_func=pdf_func,
        sample_dim=2,
        sample_count=sample_count,
        ires=ires,
        seed=seed,
    )
    ok = test.run(quiet=True)
    return ok, test.messages, float(test.pdf_sum[0])


# --------------------------------------------------------------------------- 1. SGGX


SGGX_ALPHAS = [0.1, 0.3, 0.7, 1.0]
SGGX_TANGENTS = {
    "in-plane": unit([1.0, 0.0, 0.0]),
    "in-plane-diag": unit([1.0, -1.0, 0.0]),
    "out-of-plane": unit([0.3, 0.5, 0.81]),
    "normal": unit([0.0, 0.0, 1.0]),
}
SGGX_OMEGAS = [unit([0.35, 0.2, 0.91]), dir_theta(80.0, 30.0), unit([1.0, 0.0, 0.0]),
               unit([-0.2, 0.1, -0.97])]


@pytest.mark.parametrize("alpha", SGGX_ALPHAS)
def test_sggx_projected_area_identity(alpha):
    """∫ max(0, ω·m) D(m) dm = σ(ω) (the SGGX normalisation, docs/design.md §3).

    Uniform-sphere Monte Carlo over m, 2^21 samples shared by all (t, ω) pairs; the
    integrand is bounded by D_max = 1/(π α), so the estimator has finite variance and its
    standard error is computed from the samples. Assert |MC − σ| < 5 SE + 1e-5 (float32
    evaluation of D and σ: a few eps32 relative). Also checks σ against sqrt(ωᵀSω) and D
    against the explicit-matrix formula with numpy.linalg.
    """
    n = 1 << 21
    m, pdf = uniform_sphere(n, seed=11)
    m_np = npf(m)
    for tname, t in SGGX_TANGENTS.items():
        S = sggx_matrix(t, alpha)
        d = sggx.ndf(m, vec(t), alpha)
        d_np = npf(d)
        # The package's inverse-free D equals the textbook formula.
        np.testing.assert_allclose(d_np, ndf_reference(m_np, S), rtol=1e-5, err_msg=tname)
        for w in SGGX_OMEGAS:
            integrand = np.maximum(m_np @ w, 0.0) * d_np / pdf
            est, se = mean_and_se(integrand)
            sigma = float(npf(sggx.projected_area(vec(w), vec(t), alpha))[0])
            assert sigma == pytest.approx(float(sigma_reference(w, S)[0]), rel=1e-6)
            assert abs(est - sigma) < N_SIGMA * se + 1e-5, (tname, w, est, sigma, se)


def test_sggx_isotropic_limit():
    """α = 1 makes S = I: D(m) = 1/π for every m and σ(ω) = 1 for every ω (float32 exact-ish)."""
    rng = np.random.default_rng(3)
    m = random_unit(rng, 1000)
    t = random_unit(rng, 1000)
    d = npf(sggx.ndf(vec(m), vec(t), 1.0))
    s = npf(sggx.projected_area(vec(m), vec(t), 1.0))
    np.testing.assert_allclose(d, 1.0 / math.pi, rtol=1e-6)
    np.testing.assert_allclose(s, 1.0, rtol=1e-6)


@pytest.mark.parametrize("alpha", [0.01, 0.05, 0.12, 0.4])
@pytest.mark.parametrize("terms", [3, 4])
def test_ndf_mixture_is_the_weighted_sum_of_ndfs(alpha, terms):
    """The bilinear mix of direction bins' D with a division per pair of terms (the residual
    texels' control variate) equals the sum of the single NDFs: at shiny roughness, where
    D spans orders of magnitude between bins, for peaks (m along the fibre's normal plane)
    and tails, non-unit m, and an odd count (its last term alone)."""
    rng = np.random.default_rng(23)
    n = 4000
    t = random_unit(rng, n)
    ms = [random_unit(rng, n) * rng.uniform(0.9, 1.1, (n, 1)) for _ in range(terms)]
    # A quarter of the lanes put the first m in the fibre's normal plane: D's peak.
    peak = np.cross(t, random_unit(rng, n))
    ms[0][: n // 4] = unit(peak[: n // 4])
    w = rng.random((terms, n))
    w /= w.sum(axis=0)
    got = npf(sggx.ndf_mixture([vec(m) for m in ms], vec(t), alpha, [mi.Float(x) for x in w]))
    want = sum(w[j] * npf(sggx.ndf(vec(ms[j]), vec(t), alpha)) for j in range(terms))
    np.testing.assert_allclose(got, want, rtol=2e-6 * terms, atol=0.0)
    assert np.isfinite(got).all() and want.max() / want.min() > (1e3 if alpha < 0.15 else 10.0)


@pytest.mark.parametrize("alpha", [0.05, 0.3])
def test_eval_specular_at_shared_directions_matches_eval_specular_from(alpha):
    """Many tangents at one direction pair (a footprint's residual texels) evaluated from the
    pair's shared cosines give :func:`spongecake.eval_specular_from`'s values: reflection and
    transmission, grazing and invalid (wo at the horizon) directions included."""
    rng = np.random.default_rng(29)
    n = 3000
    wi = random_unit(rng, n)
    wi[:, 2] = np.abs(wi[:, 2])
    wo = random_unit(rng, n)
    wo[:10, 2] = 0.0  # at the horizon: zero both ways
    t = random_unit(rng, n)
    wi_, wo_, t_ = vec(wi), vec(wo), vec(t)
    sigma_i = sggx.projected_area(wi_, t_, alpha)
    sigma_o = sggx.projected_area(wo_, t_, alpha)
    d = sggx.ndf(dr.normalize(wi_ + wo_), t_, alpha)
    dirs = spongecake.SpecularDirections.of(wi_, wo_)
    got = npf(spongecake.eval_specular_at(d, sigma_i, sigma_o, dirs, 2.0))
    want = npf(spongecake.eval_specular_from(d, sigma_i, sigma_o, wi_, wo_, 2.0)[0])
    np.testing.assert_allclose(got, want, rtol=1e-6, atol=0.0)
    assert (got[:10] == 0.0).all() and (got > 0.0).sum() > n // 2


# --------------------------------------------------------------------------- 2. chi^2 of samplers


CHI2_CONFIGS = [
    # (wi, t, alpha)
    (dir_theta(30.0, 20.0), unit([1.0, 0.0, 0.0]), 0.3),
    (dir_theta(85.0, 0.0), unit([0.3, 0.5, 0.81]), 0.3),
    (dir_theta(85.0, 90.0), unit([1.0, 0.0, 0.0]), 0.7),
    (dir_theta(50.0, 200.0), unit([0.6, -0.8, 0.2]), 0.15),
    (dir_theta(0.0), unit([0.0, 0.0, 1.0]), 0.5),
    (dir_theta(60.0, 45.0), unit([0.0, 1.0, 0.0]), 1.0),
]


@pytest.mark.parametrize("wi,t,alpha", CHI2_CONFIGS)
def test_visible_normal_sampling_chi2(wi, t, alpha):
    """Histogram of sample_visible_normal matches visible_normal_pdf (Pearson χ², 1%)."""
    wi_v, t_v = vec(wi), vec(t)
    ok, msg, mass = chi2_passes(
        lambda s: sggx.sample_visible_normal(wi_v, t_v, alpha, s),
        lambda m: sggx.visible_normal_pdf(wi_v, m, t_v, alpha),
    )
    assert ok, msg
    assert abs(mass - 1.0) < 1e-3, mass  # the VNDF is normalised


@pytest.mark.parametrize("wi,t,alpha", CHI2_CONFIGS)
def test_specular_sampling_chi2(wi, t, alpha):
    """sample_specular's directions (either side of the surface) match pdf_specular (χ², 1%).

    The phase function D(h)/(4σ(i)) is normalised over the whole sphere, so no sample is
    lost and the pdf is tested on the full sphere.
    """
    wi_v, t_v = vec(wi), vec(t)
    ok, msg, mass = chi2_passes(
        lambda s: spongecake.sample_specular(wi_v, t_v, alpha, s)[0],
        lambda wo: spongecake.pdf_specular(wi_v, wo, t_v, alpha),
    )
    assert ok, msg
    assert abs(mass - 1.0) < 1e-3, mass  # the phase function is normalised


# --------------------------------------------------------------------------- 3. slab reference


def sample_vndf_by_rejection(rng, wi, t, alpha, n):
    """n flake normals with density ∝ max(0, wi·m) D(m), by rejection (float64, no package code).

    Proposal: the fibre-like D depends only on u = m·t, as (a² + u²)^-2 with
    a² = α²/(1 − α²); propose u with density ∝ 1/(a² + u²) on [−1, 1] (u = a tan θ, θ
    uniform) and a uniform azimuth around t. Its solid-angle density is
    g(m) = 1/(2π Z (a² + u²)), Z = (2/a) atan(1/a), and D/g ≤ M = 2 Z α/(1 − α²), so
    accepting with probability max(0, wi·m) D(m)/(M g(m)) ≤ 1 gives the target exactly.
    D itself is the explicit-matrix formula (ndf_reference).
    """
    assert 0.0 < alpha < 1.0
    S = sggx_matrix(t, alpha)
    t = unit(t)
    b1, b2 = np.linalg.svd(t[None, :])[2][1:]  # orthonormal complement of t
    a = math.sqrt(alpha * alpha / (1.0 - alpha * alpha))
    Z = 2.0 / a * math.atan(1.0 / a)
    M = 2.0 * Z * alpha / (1.0 - alpha * alpha)
    accept_rate = float(sigma_reference(wi, S)[0]) / M  # ∫ max(0, wi·m) D dm = σ(wi)
    out, have = [], 0
    while have < n:
        k = int((n - have) / accept_rate * 1.2) + 1000
        theta = rng.uniform(-1.0, 1.0, k) * math.atan(1.0 / a)
        u = np.clip(a * np.tan(theta), -1.0, 1.0)
        phi = rng.uniform(0.0, 2.0 * math.pi, k)
        r = np.sqrt(1.0 - u * u)
        m = u[:, None] * t + r[:, None] * (np.cos(phi)[:, None] * b1 + np.sin(phi)[:, None] * b2)
        g = 1.0 / (2.0 * math.pi * Z * (a * a + u * u))
        ratio = np.maximum(m @ wi, 0.0) * ndf_reference(m, S) / (M * g)
        assert ratio.max() <= 1.0 + 1e-9, "rejection bound violated"
        keep = m[rng.random(k) < ratio]
        out.append(keep)
        have += len(keep)
    return np.concatenate(out)[:n]


def slab_single_scattering_mc(wi, t, alpha, thickness, n, seed):
    """Analog single-scattering simulation of a SpongeCake slab (float64 NumPy).

    Depth is in optical-depth units: along ω the extinction per unit depth is
    Λ(ω) = σ(ω)/|cos θ|. A photon enters the top along −wi, collides at depth τ with
    P(τ' > τ) = e^{−τ Λi}; if τ ≥ T it leaves unscattered. Otherwise it reflects on a
    flake normal m drawn from the visible normals of wi (sample_vndf_by_rejection), o =
    2(wi·m)m − wi, and escapes through the top (o.z > 0, depth τ to cross) or the bottom
    (o.z < 0, depth T − τ) with probability e^{−depth Λ(o)}; that probability is tallied
    as R or T. Returns dict of (mean, standard error) for R, T and R+T.
    """
    rng = np.random.default_rng(seed)
    S = sggx_matrix(t, alpha)
    lam_i = float(sigma_reference(wi, S)[0]) / wi[2]
    tau = rng.exponential(size=n) / lam_i
    scattered = tau < thickness
    m = sample_vndf_by_rejection(rng, wi, t, alpha, int(scattered.sum()))
    o = 2.0 * (m @ wi)[:, None] * m - wi
    lam_o = sigma_reference(o, S) / np.abs(o[:, 2])
    up = o[:, 2] > 0.0
    ts = tau[scattered]
    escape = np.exp(-np.where(up, ts, thickness - ts) * lam_o)
    r_tally = np.zeros(n)
    t_tally = np.zeros(n)
    r_tally[scattered] = np.where(up, escape, 0.0)
    t_tally[scattered] = np.where(up, 0.0, escape)
    return {"R": mean_and_se(r_tally), "T": mean_and_se(t_tally),
            "RT": mean_and_se(r_tally + t_tally)}


@functools.lru_cache(maxsize=None)
def package_reflectance(wi, t, alpha, thickness, n=1 << 22, seed=5):
    """R(i) = ∫_{o.z>0} eval_specular dω and T(i) = ∫_{o.z<0} eval_specular dω, uniform-sphere MC.

    (wi, t are tuples so the result can be cached.) Returns dict of (mean, SE).
    """
    wo, pdf = uniform_sphere(n, seed)
    value, reflect = spongecake.eval_specular(vec(np.array(wi)), wo, vec(np.array(t)),
                                              alpha, thickness)
    v = npf(value) / pdf
    r = npf(reflect)
    return {"R": mean_and_se(np.where(r, v, 0.0)), "T": mean_and_se(np.where(r, 0.0, v)),
            "RT": mean_and_se(v)}


SLAB_CONFIGS = [
    # (wi, t, alpha, T)
    (unit([0.35, 0.2, 0.91]), unit([0.3, 0.5, 0.81]), 0.3, 1.7),  # docs/design.md §3 known value
    (dir_theta(40.0, 10.0), unit([1.0, 0.0, 0.0]), 0.1, 0.5),  # thin, sharp, in-plane t
    (dir_theta(75.0, 30.0), unit([0.2, -0.4, 0.9]), 0.7, 3.0),  # grazing-ish, out-of-plane t
    (dir_theta(75.0, 100.0), unit([1.0, 1.0, 0.0]), 0.1, 5.0),  # grazing-ish, sharp, thick
    (dir_theta(20.0, 250.0), unit([0.0, 0.6, 0.8]), 0.5, 0.2),  # near-normal, thin
]


def _key(cfg):
    wi, t, alpha, thickness = cfg
    return tuple(float(x) for x in wi), tuple(float(x) for x in t), alpha, thickness


@pytest.mark.parametrize("cfg", SLAB_CONFIGS, ids=[f"slab{i}" for i in range(len(SLAB_CONFIGS))])
def test_spongecake_matches_slab_simulation(cfg):
    """Hemispherical R and T from eval_specular equal an independent slab simulation.

    Both sides are Monte Carlo; assert |R_pkg − R_slab| < 5 sqrt(SE_pkg² + SE_slab²) + 1e-5
    (the floor covers float32 evaluation in the package, ~1e-6 relative). This checks
    D, σ, Λ, G_r, G_t, h = normalize(i+o) and the 1/(4 cos i) factor together.
    """
    wi, t, alpha, thickness = cfg
    pkg = package_reflectance(*_key(cfg))
    ref = slab_single_scattering_mc(wi, t, alpha, thickness, n=400_000, seed=7)
    for k in ("R", "T"):
        (a, sa), (b, sb) = pkg[k], ref[k]
        assert abs(a - b) < N_SIGMA * math.hypot(sa, sb) + 1e-5, (k, a, sa, b, sb)


def test_spongecake_known_value():
    """docs/design.md §3: t = n(0.3, 0.5, 0.81), α = 0.3, T = 1.7, ωi = n(0.35, 0.2, 0.91).

    R ≈ 0.0168, T ≈ 0.2075 (given to 4 digits, hence the 5e-4 floor on top of 5 SE of the
    integration), unscattered e^{−TΛi} = 0.45291 (float64 here: 0.4529091; float32 in the
    package: asserted to 2e-6, and to 4 digits against the quoted value).
    """
    wi, t, alpha, thickness = SLAB_CONFIGS[0]
    u = float(npf(spongecake.unscattered_transmittance(vec(wi), vec(t), alpha, thickness))[0])
    lam_i = float(sigma_reference(wi, sggx_matrix(t, alpha))[0]) / wi[2]
    assert u == pytest.approx(math.exp(-thickness * lam_i), abs=2e-6)
    assert abs(u - 0.45291) < 5e-5
    pkg = package_reflectance(*_key(SLAB_CONFIGS[0]))
    for k, expected in (("R", 0.0168), ("T", 0.2075)):
        est, se = pkg[k]
        assert abs(est - expected) < N_SIGMA * se + 5e-4, (k, est, se, expected)


# --------------------------------------------------------------------------- 4. attenuation terms


def g_t_reference(li, lo_abs, T):
    """G_t in float64: closed form (e^{−T Li} − e^{−T|Lo|})/(|Lo| − Li), stable near equality.

    Written as e^{−T a} · (−expm1(−T(b−a)))/(b−a) with a = min, b = max, which is algebraically
    the closed form and stays accurate for b − a → 0 (limit T e^{−T a}).
    """
    a, b = np.minimum(li, lo_abs), np.maximum(li, lo_abs)
    d = b - a
    safe = np.where(d > 0, d, 1.0)
    phi = np.where(d > 0, -np.expm1(-T * safe) / safe, T)
    return np.exp(-T * a) * phi


def f32_inputs(*xs):
    """Round inputs to float32 (as the package sees them), back to float64 for references."""
    return [np.asarray(x, dtype=np.float32).astype(np.float64) for x in xs]


def test_transmission_attenuation_equal_lambda_limit():
    """G_t at Li = |Lo| is T e^{−T L}; 1e-6 away it is continuous; swapping Li, |Lo| is symmetric.

    Reference in float64. Tolerance: e^{−T L} in float32 has relative error ≈ eps32·(T L + 2)
    from rounding T·L (T L ≤ 60 here) plus a few ulp, so rtol = 8 eps32 (T L + 2).
    Continuity: the exact change over ΔL = 1e-6 is ≤ T ΔL/2 relative; the float32 result at
    L + 1e-6 must equal the float64 value there to the same rtol, and the two float32 results
    may differ by at most that exact change plus both rounding errors.
    """
    rng = np.random.default_rng(4)
    L = rng.uniform(0.05, 6.0, 2000)
    T = rng.uniform(0.01, 10.0, 2000)
    L, T = f32_inputs(L, T)
    rtol = 8 * EPS32 * (T * L + 2.0)

    g_eq = npf(spongecake.transmission_attenuation(flt(L), flt(-L), flt(T)))
    np.testing.assert_array_less(np.abs(g_eq / (T * np.exp(-T * L)) - 1.0), rtol)

    Lp = f32_inputs(L + 1e-6)[0]
    g_near = npf(spongecake.transmission_attenuation(flt(L), flt(-Lp), flt(T)))
    ref_near = g_t_reference(L, Lp, T)
    np.testing.assert_array_less(np.abs(g_near / ref_near - 1.0), rtol)
    exact_change = np.abs(ref_near / (T * np.exp(-T * L)) - 1.0)
    np.testing.assert_array_less(np.abs(g_near / g_eq - 1.0), exact_change + 2 * rtol)

    # Symmetric in swapping Li and |Lo| (the exit side of o does not matter).
    L2 = f32_inputs(rng.uniform(0.05, 6.0, 2000))[0]
    g_ab = npf(spongecake.transmission_attenuation(flt(L), flt(-L2), flt(T)))
    g_ba = npf(spongecake.transmission_attenuation(flt(L2), flt(-L), flt(T)))
    np.testing.assert_allclose(g_ab, g_ba, rtol=4 * EPS32, atol=0)


def test_transmission_attenuation_closed_form():
    """G_t equals (e^{−T Li} − e^{−T|Lo|})/(|Lo| − Li) (float64, direct) away from equality.

    Pairs with T|Lo − Li| ≥ 1e-2 (the direct float64 form is accurate there: cancellation
    costs at most 1e-16/1e-2). Float32 tolerance: rounding of T·a in the exponent
    (eps32·T a), and the cancellation in 1 − e^{−x} for x = T(b − a) ≥ 1e-2 inside the
    package (≈ 2 eps32 / x relative), so rtol = 8 eps32 (T a + 2 + 2/x).
    """
    rng = np.random.default_rng(5)
    n = 20000
    li = rng.uniform(0.01, 8.0, n)
    lo = rng.uniform(0.01, 8.0, n)
    T = 10.0 ** rng.uniform(-2, 1, n)
    li, lo, T = f32_inputs(li, lo, T)
    x = T * np.abs(lo - li)
    keep = x >= 1e-2
    li, lo, T, x = li[keep], lo[keep], T[keep], x[keep]
    closed = (np.exp(-T * li) - np.exp(-T * lo)) / (lo - li)
    got = npf(spongecake.transmission_attenuation(flt(li), flt(-lo), flt(T)))
    a = np.minimum(li, lo)
    rtol = 8 * EPS32 * (T * a + 2.0 + 2.0 / np.minimum(x, 1.0))
    np.testing.assert_array_less(np.abs(got / closed - 1.0), rtol)


def test_reflection_attenuation_closed_form_and_limit():
    """G_r = (1 − e^{−T s})/s, s = Li + Lo; for s → 0 (s = 1e-6) it tends to T.

    Float64 closed form via the direct expression where T s ≥ 1e-2 (accurate there) and the
    stable −expm1 form elsewhere. rtol = 8 eps32 (2 + 2/min(Ts, 1)) as for G_t but with
    the package's series branch below 1e-2 (error ≤ (Ts)^4/120 + a few eps32).
    At s = 1e-6 the exact relative deviation from T is T s/2 ≤ 5e-6 for T ≤ 10.
    """
    rng = np.random.default_rng(6)
    n = 20000
    li = 10.0 ** rng.uniform(-4, 1, n)
    lo = 10.0 ** rng.uniform(-4, 1, n)
    T = 10.0 ** rng.uniform(-2, 1, n)
    li, lo, T = f32_inputs(li, lo, T)
    s = li + lo
    x = T * s
    ref = np.where(x >= 1e-2, (1.0 - np.exp(-x)) / np.where(x > 0, s, 1.0), -np.expm1(-x) / s)
    got = npf(spongecake.reflection_attenuation(flt(li), flt(lo), flt(T)))
    rtol = 8 * EPS32 * (2.0 + 2.0 / np.minimum(x, 1.0) * (x >= 1e-2))
    np.testing.assert_array_less(np.abs(got / ref - 1.0), rtol)

    T_small = f32_inputs(np.array([0.01, 0.5, 1.7, 10.0]))[0]
    tiny = np.float32(5e-7)  # s = 1e-6
    got = npf(spongecake.reflection_attenuation(flt(np.full(4, tiny)), flt(np.full(4, tiny)),
                                                flt(T_small)))
    s = 2.0 * float(tiny)
    np.testing.assert_array_less(np.abs(got / T_small - 1.0), T_small * s / 2 + 8 * EPS32)
    np.testing.assert_allclose(got, -np.expm1(-T_small * s) / s, rtol=8 * EPS32)


# --------------------------------------------------------------------------- 5. reciprocity


def test_eval_specular_reciprocity():
    """f(i, o) = f(o, i) for the specular lobe (eval carries |cos o|, so divide it out).

    Reflection (o up): compare eval(i, o)/|cos o| with eval(o, i)/|cos i|. Transmission
    (o down): the package wants the first argument up, so use the z-mirrored configuration
    (mirror i, o and t), which is physically the same slab seen from below:
    f(i, o; t) = f(M o, M i; M t). Directions are kept 0.05 from grazing and |i + o| ≥ 0.05
    (h well defined). rtol 1e-4: float32 evaluation of D (squared quadratic form), exp and
    normalisation, each a few eps32, amplified at most ~100x by |i + o| ≥ 0.05 and α ≥ 0.05.
    """
    rng = np.random.default_rng(8)
    n = 200_000
    wi = random_upper(rng, n, zmin=0.05)
    wo = random_unit(rng, n)
    t = random_unit(rng, n)
    alpha = rng.uniform(0.05, 1.0, n)
    T = 10.0 ** rng.uniform(-1, 1, n)
    keep = (np.abs(wo[:, 2]) > 0.05) & (np.linalg.norm(wi + wo, axis=1) > 0.05)
    wi, wo, t, alpha, T = wi[keep], wo[keep], t[keep], alpha[keep], T[keep]
    mirror = np.array([1.0, 1.0, -1.0])
    up = wo[:, 2] > 0
    wi2 = np.where(up[:, None], wo, wo * mirror)
    wo2 = np.where(up[:, None], wi, wi * mirror)
    t2 = np.where(up[:, None], t, t * mirror)

    f1, r1 = spongecake.eval_specular(vec(wi), vec(wo), vec(t), flt(alpha), flt(T))
    f2, r2 = spongecake.eval_specular(vec(wi2), vec(wo2), vec(t2), flt(alpha), flt(T))
    f1 = npf(f1) / np.abs(wo[:, 2])
    f2 = npf(f2) / np.abs(wo2[:, 2])
    assert np.array_equal(npf(r1), up) and np.array_equal(npf(r2), up)
    # Where the exact value is a normal float32 it must be > 0: G_t >= ~e^{-T min(Λi, |Λo|)}
    # and Λ <= 1/|cos|. Beyond T/max(cos) = 50 transmission may underflow to 0 (legitimately).
    representable = T / np.maximum(wi[:, 2], np.abs(wo[:, 2])) < 50.0
    assert (f1[representable] > 0).all()
    np.testing.assert_allclose(f1, f2, rtol=1e-4, atol=0)


# --------------------------------------------------------------------------- 6. sampling weights


def sample_weights(wi, t, alpha, thickness, n, seed):
    """eval/pdf for n samples of sample_specular (pdf > 0 only)."""
    u = np.random.default_rng(seed).random((n, 2), dtype=np.float32)
    wi_v, t_v = vec(wi), vec(t)
    wo, pdf = spongecake.sample_specular(wi_v, t_v, alpha, mi.Point2f(u[:, 0], u[:, 1]))
    value, _ = spongecake.eval_specular(wi_v, wo, t_v, alpha, thickness)
    value, pdf = npf(value), npf(pdf)
    assert (pdf > 0).all()
    return value / pdf


@pytest.mark.parametrize("cfg", SLAB_CONFIGS, ids=[f"slab{i}" for i in range(len(SLAB_CONFIGS))])
def test_sample_specular_weight(cfg):
    """Path weight eval/pdf = Λi·G ≤ 1 (docs/design.md §3), and its mean is R + T.

    Bound: 1 + 1e-4 (float32 evaluation of eval and pdf separately, a few eps32 each, with
    D cancelling only approximately). Mean: compared with the uniform-sphere integral of
    test 3 to 5 combined standard errors + 1e-5 (float32 floor).
    """
    wi, t, alpha, thickness = cfg
    w = sample_weights(wi, t, alpha, thickness, n=1 << 20, seed=9)
    assert np.isfinite(w).all() and (w >= 0).all()
    assert w.max() <= 1.0 + 1e-4, w.max()
    est, se = mean_and_se(w)
    ref, ref_se = package_reflectance(*_key(cfg))["RT"]
    assert abs(est - ref) < N_SIGMA * math.hypot(se, ref_se) + 1e-5, (est, se, ref, ref_se)


def test_sample_specular_weight_bound_random():
    """eval/pdf ≤ 1 + 1e-4 over random (wi, t, α, T, sample), wi not grazing (z ≥ 1e-3)."""
    rng = np.random.default_rng(10)
    n = 500_000
    wi = random_upper(rng, n, zmin=1e-3)
    t = random_unit(rng, n)
    alpha = 10.0 ** rng.uniform(-2, 0, n)
    T = 10.0 ** rng.uniform(-3, 1.5, n)
    u = rng.random((n, 2), dtype=np.float32)
    wi_v, t_v, a_v, T_v = vec(wi), vec(t), flt(alpha), flt(T)
    wo, pdf = spongecake.sample_specular(wi_v, t_v, a_v, mi.Point2f(u[:, 0], u[:, 1]))
    value, _ = spongecake.eval_specular(wi_v, wo, t_v, a_v, T_v)
    value, pdf = npf(value), npf(pdf)
    ok = pdf > 0
    assert ok.mean() > 0.999
    w = value[ok] / pdf[ok]
    assert np.isfinite(w).all()
    assert w.max() <= 1.0 + 1e-4, w.max()


# --------------------------------------------------------------------------- 7. sheen


SHEEN_CHI2 = [(dir_theta(30.0, 0.0), 0.5), (dir_theta(80.0, 60.0), 0.3), (dir_theta(60.0, 10.0), 1.0)]


@pytest.mark.parametrize("wi,alpha_s", SHEEN_CHI2)
def test_sheen_sampling_chi2(wi, alpha_s):
    """sample_sheen matches pdf_sheen (χ², 1%): samples folded to the upper hemisphere,
    none lost, so pdf_sheen integrates to 1 there and is 0 below."""
    wi_v = vec(wi)

    def sample(s):
        wo, _ = sheen.sample_sheen(wi_v, alpha_s, s)
        return wo, dr.select(wo.z > 0, 1.0, 0.0)

    ok, msg, _ = chi2_passes(sample, lambda wo: sheen.pdf_sheen(wi_v, wo, alpha_s))
    assert ok, msg


def test_sheen_sampling_loses_no_sample_at_grazing_incidence():
    """Every folded sheen sample lies above the surface, also at 85 degrees, where most
    unfolded visible-normal reflections point below."""
    wi_v = vec(dir_theta(85.0, 20.0))
    rng = np.random.default_rng(5)
    s = mi.Point2f(rng.random(10000), rng.random(10000))
    wo, pdf = sheen.sample_sheen(wi_v, 0.5, s)
    raw, _ = spongecake.sample_specular(wi_v, mi.Vector3f(0, 0, 1), 0.5, s)
    assert np.mean(np.array(raw.z) < 0) > 0.2  # the case folding is for
    assert np.all(np.array(wo.z) >= 0) and np.all(np.array(pdf) > 0)


TABULATED_SHEEN_CASES = [(dir_theta(0.0, 0.0), 0.5, 0.3), (dir_theta(30.0, 0.0), 0.5, 0.3), (dir_theta(80.0, 60.0), 0.3, 0.2),
                         (dir_theta(88.0, -100.0), 0.5, 0.3), (dir_theta(60.0, 10.0), 1.0, 1.0),
                         (dir_theta(45.0, 200.0), 0.05, 0.3)]


@pytest.mark.parametrize("wi,alpha_s,Ts", TABULATED_SHEEN_CASES)
def test_tabulated_sheen_sampling_chi2(wi, alpha_s, Ts):
    """TabulatedSheenSampler.sample matches its pdf (χ², 1%): at normal incidence (no
    azimuth of wi to measure from), inside incident-angle bands,
    at 88°, for a peaked lobe (α_s = 0.05: the cosine floor keeps every cell positive) and
    at azimuths other than 0."""
    wi_v = vec(wi)
    sampler = sheen.TabulatedSheenSampler.build(alpha_s, Ts)

    def sample(s):
        wo, _ = sampler.sample(wi_v, s)
        return wo, dr.select(wo.z > 0, 1.0, 0.0)

    ok, msg, _ = chi2_passes(sample, lambda wo: sampler.pdf(wi_v, wo))
    assert ok, msg


@pytest.mark.parametrize("theta", [20.0, 60.0, 80.0, 85.0, 88.0])
def test_tabulated_sheen_weights_are_nearly_constant(theta):
    """The tabulated sampler's weight f/pdf is the sheen albedo up to the table's
    piecewise-constant error: relative variance < 0.01 where the folded visible normals
    give 0.046-0.19 (α_s 0.5, T_s 0.3, 2^16 samples); the returned pdf is pdf(wo) (but on
    cell borders, where the two cells' densities both hold); the mean weight agrees with
    the folded sampler's (the same albedo) within 5 standard errors."""
    wi_v = vec(dir_theta(theta, 35.0))
    sampler = sheen.TabulatedSheenSampler.build(0.5, 0.3)
    rng = np.random.default_rng(3)
    n = 1 << 16
    s = mi.Point2f(rng.random(n), rng.random(n))
    wo, pdf = sampler.sample(wi_v, s)
    same = np.isclose(npf(sampler.pdf(wi_v, wo)), npf(pdf), rtol=1e-5)
    assert same.mean() > 0.999
    w = npf(sheen.eval_sheen(wi_v, wo, 0.5, 0.3)) / npf(pdf)
    wo_f, pdf_f = sheen.sample_sheen(wi_v, 0.5, s)
    w_f = npf(sheen.eval_sheen(wi_v, wo_f, 0.5, 0.3)) / npf(pdf_f)
    assert w.var() / w.mean() ** 2 < 0.01
    assert w_f.var() / w_f.mean() ** 2 > 0.03  # what the table is for
    se = np.sqrt((w.var() + w_f.var()) / n)
    assert abs(w.mean() - w_f.mean()) < 5 * se + 1e-6


def test_tabulated_sheen_pdf_is_zero_below_and_rejects_a_bad_table():
    sampler = sheen.TabulatedSheenSampler.build(0.5, 0.3)
    wi_v = vec(dir_theta(50.0, 0.0))
    assert float(npf(sampler.pdf(wi_v, vec(dir_theta(120.0, 30.0))))[0]) == 0.0
    assert float(npf(sampler.pdf(wi_v, vec(dir_theta(60.0, 30.0))))[0]) > 0.0
    with pytest.raises(ValueError, match="non-negative values of shape"):
        sheen.TabulatedSheenSampler(np.ones((2, 3, 4)), 2, 3, 5)
    with pytest.raises(ValueError, match="all zero"):
        sheen.TabulatedSheenSampler(np.zeros((2, 3, 4)), 2, 3, 4)


@pytest.mark.parametrize("alpha_s,Ts", [(0.5, 0.3), (0.4, 0.6), (0.5, 0.0), (0.05, 2.0)])
def test_fuzz_cosine_sampling_chi2(alpha_s, Ts):
    """FuzzCosineSampler.sample matches its pdf (χ², 1%), for a thin, a thick, no fuzz
    (plain cosine) and a peaked, very thick one."""
    sampler = sheen.FuzzCosineSampler(alpha_s, Ts)

    def sample(s):
        wo = sampler.sample(s)
        return wo, dr.select(wo.z > 0, 1.0, 0.0)

    def pdf(wo):
        return dr.select(wo.z > 0, sampler.pdf(wo), 0.0)

    ok, msg, _ = chi2_passes(sample, pdf)
    assert ok, msg


@pytest.mark.parametrize("alpha_s,Ts", [(0.5, 0.3), (0.4, 0.6)])
def test_fuzz_cosine_weights_are_nearly_constant(alpha_s, Ts):
    """|cos o| T_sheen(o) / pdf is constant up to the table's interpolation (relative
    variance < 1e-3), where cosine sampling leaves T_sheen(o)'s variance (> 0.04)."""
    sampler = sheen.FuzzCosineSampler(alpha_s, Ts)
    rng = np.random.default_rng(4)
    n = 1 << 16
    s = mi.Point2f(rng.random(n), rng.random(n))
    wo = sampler.sample(s)
    target = npf(sheen.sheen_transmittance(wo, alpha_s, Ts)) * npf(wo.z) / np.pi
    w = target / npf(sampler.pdf(wo))
    assert w.var() / w.mean() ** 2 < 1e-3
    wc = mi.warp.square_to_cosine_hemisphere(s)
    t = npf(sheen.sheen_transmittance(wc, alpha_s, Ts))
    assert t.var() / t.mean() ** 2 > 0.04
    # The pdf of the lower mirror image is the same (the callers pick the side).
    below = mi.Vector3f(wo.x, wo.y, -wo.z)
    np.testing.assert_allclose(npf(sampler.pdf(below)), npf(sampler.pdf(wo)))


def test_sheen_transmittance_and_lower_hemisphere():
    """sheen_transmittance ∈ (0, 1] and equals e^{−T_s σ_s/|cos|} with t = n; sheen eval is 0 below.

    Directions with |cos| ≥ 0.05 and T_s ≤ 2 keep T_s Λ ≤ 40, so e^{−T_s Λ} ≥ 4e-18 is a
    normal float32 (> 0 must hold). rtol 8 eps32 (T_s Λ (1 + 1/σ²) + 2): the exponentials'
    rounding as above plus the cancellation in σ² (see below).
    """
    rng = np.random.default_rng(12)
    n = 100_000
    w = random_unit(rng, n)
    w = w[np.abs(w[:, 2]) >= 0.05]
    n = len(w)
    alpha = rng.uniform(0.01, 1.0, n)
    Ts = rng.uniform(0.0, 2.0, n)
    w32, alpha, Ts = vec(w), *f32_inputs(alpha, Ts)
    tr = npf(sheen.sheen_transmittance(w32, flt(alpha), flt(Ts)))
    assert ((tr > 0) & (tr <= 1)).all()
    wf = npf(w32)
    lam = np.sqrt(alpha ** 2 * wf[:, 2] ** 2 + (1 - wf[:, 2] ** 2)) / np.abs(wf[:, 2])
    # sigma^2 = 1 - (1 - α²) z² in float32 loses ~4 eps32 absolute to cancellation, i.e.
    # 4 eps32/σ² relative, which the exponent T_s Λ carries.
    sigma2 = lam ** 2 * wf[:, 2] ** 2
    rtol = 8 * EPS32 * (Ts * lam * (1.0 + 1.0 / sigma2) + 2.0)
    np.testing.assert_array_less(np.abs(tr / np.exp(-Ts * lam) - 1.0), rtol)

    wi = random_upper(rng, n, zmin=0.01)
    wo = random_upper(rng, n, zmin=0.0) * np.array([1.0, 1.0, -1.0])
    f = npf(sheen.eval_sheen(vec(wi), vec(wo), flt(alpha), flt(Ts + 0.1)))
    assert (f == 0).all()
    f_up = npf(sheen.eval_sheen(vec(wi), vec(wo * np.array([1.0, 1.0, -1.0])), flt(alpha),
                                flt(Ts + 0.1)))
    assert (f_up[np.abs(wo[:, 2]) > 1e-5] > 0).all()


@pytest.mark.parametrize("theta", [0.0, 45.0, 80.0, 89.0])
@pytest.mark.parametrize("alpha_s,Ts", [(0.3, 0.5), (1.0, 3.0), (0.05, 10.0)])
def test_sheen_energy(theta, alpha_s, Ts):
    """Sheen reflectance + what passes the fuzz unscattered ≤ 1 (single scattering, albedo 1).

    R_s(i) = ∫_{o.z>0} eval_sheen dω by uniform-sphere MC (2^20 samples); assert
    R_s + e^{−T_s Λ_s(i)} ≤ 1 + 5 SE + 1e-5. Also R_s > 0.
    """
    wi = dir_theta(theta, 0.0)
    wo, pdf = uniform_sphere(1 << 20, seed=13)
    f = npf(sheen.eval_sheen(vec(wi), wo, alpha_s, Ts)) / pdf
    r, se = mean_and_se(f)
    tr = float(npf(sheen.sheen_transmittance(vec(wi), alpha_s, Ts))[0])
    assert r > 0
    assert r + tr <= 1.0 + N_SIGMA * se + 1e-5, (r, se, tr)


# --------------------------------------------------------------------------- 8. robustness


def test_no_nan_or_inf():
    """10^6 random (wi, wo, t, α, T) including exactly grazing wi (z = 0), z = 1e-8, wo = −wi,
    wo = mirror(wi), wo = wi, t = n and t = wi: every function returns finite values ≥ 0 and
    sampled directions are finite unit vectors.
    """
    rng = np.random.default_rng(14)
    n = 1_000_000
    wi = random_upper(rng, n)
    k = n // 10
    # Exactly grazing and nearly grazing incident directions.
    phi = rng.uniform(0, 2 * math.pi, 2 * k)
    wi[:k] = np.stack([np.cos(phi[:k]), np.sin(phi[:k]), np.zeros(k)], axis=1)
    wi[k:2 * k] = np.stack([np.cos(phi[k:]), np.sin(phi[k:]), np.full(k, 1e-8)], axis=1)
    wi[2 * k:2 * k + 100] = [0.0, 0.0, 1.0]
    wo = random_unit(rng, n)
    sel = rng.integers(0, 5, n)
    wo = np.where((sel == 0)[:, None], -wi, wo)
    wo = np.where((sel == 1)[:, None], wi * np.array([-1.0, -1.0, 1.0]), wo)
    wo = np.where((sel == 2)[:, None], wi, wo)
    t = random_unit(rng, n)
    tsel = rng.integers(0, 6, n)
    t = np.where((tsel == 0)[:, None], np.array([0.0, 0.0, 1.0]), t)
    t = np.where((tsel == 1)[:, None], wi, t)
    alpha = 10.0 ** rng.uniform(-3, 0, n)
    alpha[:50] = 1e-3
    alpha[50:100] = 1.0
    T = 10.0 ** rng.uniform(-4, math.log10(50.0), n)
    u = rng.random((n, 2), dtype=np.float32)

    wi_v, wo_v, t_v, a_v, T_v = vec(wi), vec(wo), vec(t), flt(alpha), flt(T)
    s_v = mi.Point2f(u[:, 0], u[:, 1])

    def check(name, x):
        x = npf(x)
        assert np.isfinite(x).all(), f"{name}: {np.count_nonzero(~np.isfinite(x))} non-finite"
        assert (x >= 0).all(), f"{name}: {np.count_nonzero(x < 0)} negative"

    def check_dir(name, w):
        w = npf(w)
        assert np.isfinite(w).all(), f"{name}: non-finite direction"
        np.testing.assert_allclose(np.linalg.norm(w, axis=1), 1.0, atol=1e-4, err_msg=name)

    check("eval_specular", spongecake.eval_specular(wi_v, wo_v, t_v, a_v, T_v)[0])
    check("pdf_specular", spongecake.pdf_specular(wi_v, wo_v, t_v, a_v))
    wo_s, pdf_s = spongecake.sample_specular(wi_v, t_v, a_v, s_v)
    check_dir("sample_specular", wo_s)
    check("sample_specular pdf", pdf_s)
    check("eval at sampled wo", spongecake.eval_specular(wi_v, wo_s, t_v, a_v, T_v)[0])
    check("unscattered_transmittance", spongecake.unscattered_transmittance(wi_v, t_v, a_v, T_v))
    check_dir("sample_visible_normal", sggx.sample_visible_normal(wi_v, t_v, a_v, s_v))
    check("visible_normal_pdf", sggx.visible_normal_pdf(wi_v, wo_v, t_v, a_v))

    check("eval_sheen", sheen.eval_sheen(wi_v, wo_v, a_v, T_v))
    check("pdf_sheen", sheen.pdf_sheen(wi_v, wo_v, a_v))
    wo_h, pdf_h = sheen.sample_sheen(wi_v, a_v, s_v)
    check_dir("sample_sheen", wo_h)
    check("sample_sheen pdf", pdf_h)
    tr_i = npf(sheen.sheen_transmittance(wi_v, a_v, T_v))
    tr_o = npf(sheen.sheen_transmittance(wo_v, a_v, T_v))
    for name, tr in (("sheen_transmittance(wi)", tr_i), ("sheen_transmittance(wo)", tr_o)):
        assert np.isfinite(tr).all() and ((tr >= 0) & (tr <= 1)).all(), name
