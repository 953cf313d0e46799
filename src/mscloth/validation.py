"""Reference computations for checking multi-scale shading: the footprint BSDF's
expectation over its control-variate residual texel, and brute force (the Monte Carlo
average of the fibre-level BSDF over the same footprint). Used by tests and `make bench`."""
from __future__ import annotations

import drjit as dr
import mitsuba as mi
import numpy as np

from .bsdf.lobes import enabled_lobes
from .jit_arrays import lane_values


def _unit(v):
    v = np.asarray(v, dtype=float)
    return (v / np.linalg.norm(v)).tolist()


# The helpers below hand the BSDF its constants (directions, uv, footprint edges) as opaque
# values and its per-lane inputs in aligned memory (:func:`.jit_arrays.lane_values`): a
# test's kernels are then the same for every direction and footprint it tries, and the
# same from run to run, so Dr.Jit compiles a footprint kernel (up to 30 s) once, not once
# per case, and its kernel cache finds it the next time.
def constants(cls, n: int, *values):
    """``cls`` of the numbers ``values`` on ``n`` lanes, each an opaque array: computed
    inputs as wide as a render's, not literals that fold into the traced kernel."""
    return cls(*(dr.opaque(mi.Float, float(v), n) for v in values))


def direction(v, n: int):
    """The unit vector along ``v`` on ``n`` lanes (:func:`constants`): computed, as a
    render's directions are, so that one kernel serves every direction tested."""
    return constants(mi.Vector3f, n, *_unit(v))


def lanes(cls, *arrays):
    """``cls`` of per-lane NumPy ``arrays`` (one per component), 64-byte aligned."""
    return cls(*(lane_values(a) for a in arrays))


def non_delta_context():
    ctx = mi.BSDFContext()
    ctx.type_mask = +mi.BSDFFlags.All & ~+mi.BSDFFlags.Delta
    return ctx


def footprint_interaction(n: int, uv, half_texels: float, tile_texels: int, wi):
    """``n`` lanes at ``uv`` with a square footprint of half-width ``half_texels`` texels
    (uv_scale 1, a tile of ``tile_texels`` texels)."""
    si = dr.zeros(mi.SurfaceInteraction3f, n)
    si.wi = direction(wi, n)
    si.uv = constants(mi.Point2f, n, *uv)
    d = 2.0 * half_texels / tile_texels  # |du/dx| + |du/dy| = 2 * half-width
    si.duv_dx = constants(mi.Vector2f, n, d, 0.0)
    si.duv_dy = constants(mi.Vector2f, n, 0.0, d)
    return si


def footprint_expectation(bsdf, uv, half_texels, tile_texels, wi, wo, n=20000, seed=1, frozen=()):
    """(mean, standard error, footprint used?) of the red channel of the footprint eval
    over uniformly placed control-variate residual texels, uniform SAT corner rounding and
    probe choice, with the footprint shaded whole (the footprint branch, whatever its size).
    ``frozen``: those of these random numbers ("xi", "round", "probe") held at 1/2 in every
    lane (biased, but what the variance loses is their share)."""
    si = footprint_interaction(n, uv, half_texels, tile_texels, wi)
    enabled = enabled_lobes(non_delta_context())
    fr = bsdf.fibre.frame(si, True)
    rng = np.random.default_rng(seed)

    def draw(name):  # drawn whether frozen or not: the others stay the same numbers
        u = rng.random(n)
        return np.full(n, 0.5) if name in frozen else u
    xi = lanes(mi.Point2f, draw("xi"), draw("xi"))
    xi_round = lanes(mi.Point2f, draw("round"), draw("round"))
    u_probe = lanes(mi.Float, draw("probe"))
    st = bsdf.estimator.state(si, fr, enabled, xi, xi_round, u_probe)
    value = bsdf.estimator.eval(fr, st, fr.mirror(direction(wo, n)), enabled)
    v = np.array(value)[0]
    return float(v.mean()), float(v.std() / np.sqrt(n)), bool(np.array(st.fp.use)[0])


def probe_expectation(bsdf, si, wo, seed=1, grid=None, exact=None, probe=None, covered=False):
    """(mean, standard error) of the red channel of the footprint eval over random residual
    texels, SAT corner rounding and probe choice, one per lane of ``si``, with the
    footprint shaded whole; and the probe boxes each lane shaded
    (:meth:`probe_brute_force` takes them): the lanes' boxes (rounded, or exact), an array
    (boxes, 4, n) of x0, y0, x1, y1 (empty boxes where a probe has fewer parts).
    ``grid``: G of the G x G residual texels, ``exact``: exact SAT corners (default: the
    estimator's own); ``probe``: a number in [0, 1) that picks one probe for every lane
    (default: a random one each, as the pixel's samples spread over them); ``covered``:
    the probe shaded texel by texel (:meth:`.FootprintEstimator.eval_pdf_covered`) instead,
    over its exact boxes."""
    n = dr.width(si)
    enabled = enabled_lobes(non_delta_context())
    estimator = bsdf.estimator
    fr = bsdf.fibre.frame(si, True)
    rng = np.random.default_rng(seed)
    xi = lanes(mi.Point2f, rng.random(n), rng.random(n))
    xi_round = lanes(mi.Point2f, rng.random(n), rng.random(n))
    fp = estimator.footprint(si, fr, mi.Float(0.0), lanes(mi.Float, rng.random(n) if probe is None else np.full(n, probe)))
    exact = covered or (estimator.exact_corners() if exact is None else exact)
    st = estimator.state(si, fr, enabled, xi, xi_round, fp=fp, grid=grid, exact=exact)
    wo_m = fr.mirror(direction(wo, n))
    if covered:
        v = np.array(estimator.eval_pdf_covered(fr, st, wo_m, enabled)[0])[0]
    else:
        v = np.array(estimator.eval(fr, st, wo_m, enabled))[0]
    return float(v.mean()), float(v.std() / np.sqrt(n)), lane_boxes(estimator.shaded_boxes(fp, xi_round, exact)[0], n)


def lane_boxes(boxes, n: int) -> np.ndarray:
    """Boxes of a footprint ((x0, y0, x1, y1) per box, each a Float of one or ``n`` lanes)
    as an array (boxes, 4, n)."""
    return np.array([[np.broadcast_to(np.asarray(c, dtype=float), n) for c in b] for b in boxes])


def probe_brute_force(params: dict, boxes, tile_texels: int, wi, wo, seed=2):
    """(mean, standard error) of the fibre-level BSDF over the probe boxes of
    :func:`probe_expectation`, one point per lane: in one of its boxes picked by area, then
    uniform in it. Its expectation is what the footprint estimate's should be, its SAT means
    and residual texels being over the same boxes (exact up to float32 tables)."""
    point = mi.load_dict(dict(params, multiscale=False))
    rng = np.random.default_rng(seed)
    x0, y0, x1, y1 = boxes[:, 0], boxes[:, 1], boxes[:, 2], boxes[:, 3]  # (boxes, n)
    areas = np.maximum(x1 - x0, 0.0) * np.maximum(y1 - y0, 0.0)
    n = boxes.shape[2]
    cdf = np.cumsum(areas, axis=0) / areas.sum(axis=0)
    pick = np.minimum((rng.random(n)[None, :] >= cdf).sum(axis=0), len(boxes) - 1)
    lane = np.arange(n)
    px = x0[pick, lane] + rng.random(n) * (x1 - x0)[pick, lane]
    py = y0[pick, lane] + rng.random(n) * (y1 - y0)[pick, lane]
    si = dr.zeros(mi.SurfaceInteraction3f, n)
    si.uv = lanes(mi.Point2f, px / tile_texels, py / tile_texels)
    si.wi = direction(wi, n)
    v = np.array(point.eval(non_delta_context(), si, direction(wo, n)))[0]
    return float(v.mean()), float(v.std() / np.sqrt(n))


def brute_force(params: dict, uv, half_texels, tile_texels, wi, wo, n=200000, seed=2):
    """(mean, standard error) of the fibre-level BSDF over the footprint's area."""
    point = mi.load_dict(dict(params, multiscale=False))
    rng = np.random.default_rng(seed)
    p = np.asarray(uv) + (rng.random((n, 2)) * 2.0 - 1.0) * half_texels / tile_texels
    si = dr.zeros(mi.SurfaceInteraction3f, n)
    si.wi = direction(wi, n)
    si.uv = lanes(mi.Point2f, p[:, 0], p[:, 1])
    v = np.array(point.eval(non_delta_context(), si, direction(wo, n)))[0]
    return float(v.mean()), float(v.std() / np.sqrt(n))


def _edges(a_texels: float, shear: float, rotation: float):
    """The pixel footprint's edges (a, 0) and (shear a, a), turned by ``rotation`` radians."""
    c, s = float(np.cos(rotation)), float(np.sin(rotation))
    return ((a_texels * c, a_texels * s),
            (shear * a_texels * c - a_texels * s, shear * a_texels * s + a_texels * c))


def sheared_interaction(n: int, uv, a_texels: float, shear: float, tile_texels: int, wi, rotation: float = 0.0,
                        curvature: float = 0.0):
    """``n`` lanes at ``uv`` with the sheared pixel footprint of edges (a, 0) and
    (shear a, a) texels, turned by ``rotation`` radians (uv_scale 1, a tile of
    ``tile_texels`` texels), on a surface whose normal turns by ``curvature`` radians per
    UV unit (si.dn_du, si.dn_dv; 0: flat)."""
    si = footprint_interaction(n, uv, 0.0, tile_texels, wi)
    (ax, ay), (bx, by) = _edges(a_texels, shear, rotation)
    si.duv_dx = constants(mi.Vector2f, n, ax / tile_texels, ay / tile_texels)
    si.duv_dy = constants(mi.Vector2f, n, bx / tile_texels, by / tile_texels)
    si.dn_du = constants(mi.Vector3f, n, curvature, 0.0, 0.0)
    si.dn_dv = constants(mi.Vector3f, n, 0.0, curvature, 0.0)
    return si


def to_tilted(v, a, b):
    """``v`` (local) in the frame turned by the least rotation that takes z to the normal
    (a, b, 1)/|(a, b, 1)|: a point of a curved surface whose normal tilts by (a, b)."""
    r = dr.rsqrt(1.0 + a * a + b * b)
    kx, ky, c = -b * r, a * r, r  # k = z x n: sin(angle) times the axis
    kv = (kx * v.x + ky * v.y) * dr.rcp(1.0 + c)
    # Rodrigues, transposed: R^T v = c v - k x v + k (k.v)/(1 + c).
    return mi.Vector3f(c * v.x - ky * v.z + kx * kv, c * v.y + kx * v.z + ky * kv,
                       c * v.z - (kx * v.y - ky * v.x))


def _pixel_points(n: int, a_texels: float, shear: float, tile_texels: int, seed: int, rotation: float = 0.0):
    """(du, dv): ``n`` uniform points of the (turned) sheared pixel footprint, offsets from
    its centre."""
    rng = np.random.default_rng(seed)
    s, t = rng.random(n) - 0.5, rng.random(n) - 0.5
    (ax, ay), (bx, by) = _edges(a_texels, shear, rotation)
    return (s * ax + t * bx) / tile_texels, (s * ay + t * by) / tile_texels


def curved_pixel_expectation(bsdf, n: int, uv, a_texels: float, shear: float, tile_texels: int, wi, wo,
                             curvature: float, seed: int = 4):
    """(mean, standard error) of ``bsdf.eval`` over the samples of a pixel on a curved
    surface whose normal tilts by ``curvature`` radians per UV unit (a sphere of radius
    1/curvature in UV units), as ``clothpath`` hands them to a footprint BSDF: each sample
    at a random point of the pixel, with the pixel centre's uv and footprint and its own
    normal (the directions local to it)."""
    si = sheared_interaction(n, uv, a_texels, shear, tile_texels, wi, curvature=curvature)
    du, dv = _pixel_points(n, a_texels, shear, tile_texels, seed)
    a, b = lanes(mi.Float, curvature * du), lanes(mi.Float, curvature * dv)
    si.wi = to_tilted(direction(wi, n), a, b)
    return shading_expectation(bsdf, si, to_tilted(direction(wo, n), a, b), seed=seed + 1)


def scatter_shading_points(si, rng):
    """Give each lane of ``si`` its own random si.p (drawn from NumPy generator ``rng``):
    the footprint estimator's shading hash, and so each lane's probe, residual texels and
    rounding, then differ between lanes (interactions built with ``dr.zeros`` share one)."""
    n = dr.width(si)
    si.p = lanes(mi.Point3f, *(rng.random(n) * 10.0 for _ in range(3)))


def shading_expectation(bsdf, si, wo, seed=3):
    """(mean, standard error) of the red channel of ``bsdf.eval`` (non-delta lobes) over the
    lanes of ``si`` with random si.p: what a render averages over a pixel's samples at one
    uv (the shading point's hash picks the residual texels, the rounding, the probe and,
    for footprints of a few texels, footprint or fibre-level shading). ``wo``: one
    direction (normalised here), or a Vector3f of unit directions, one per lane."""
    n = dr.width(si)
    scatter_shading_points(si, np.random.default_rng(seed))
    if not isinstance(wo, mi.Vector3f):
        wo = direction(wo, n)
    v = np.array(bsdf.eval(non_delta_context(), si, wo))[0]
    return float(v.mean()), float(v.std() / np.sqrt(n))


def parallelogram_brute_force(params: dict, uv, a_texels: float, shear: float, tile_texels: int, wi, wo,
                              n=200000, seed=2, curvature: float = 0.0, rotation: float = 0.0):
    """(mean, standard error) of the fibre-level BSDF over the sheared (and turned) footprint
    of :func:`sheared_interaction`, each point shaded at its own normal (``curvature``: see
    :func:`curved_pixel_expectation`)."""
    point = mi.load_dict(dict(params, multiscale=False))
    du, dv = _pixel_points(n, a_texels, shear, tile_texels, seed, rotation)
    si = dr.zeros(mi.SurfaceInteraction3f, n)
    si.uv = lanes(mi.Point2f, uv[0] + du, uv[1] + dv)
    # The point's normal tilts by curvature * (du, dv): directions in its own frame.
    a, b = lanes(mi.Float, curvature * du), lanes(mi.Float, curvature * dv)
    si.wi = to_tilted(direction(wi, n), a, b)
    wo_local = to_tilted(direction(wo, n), a, b)
    v = np.array(point.eval(non_delta_context(), si, wo_local))[0]
    return float(v.mean()), float(v.std() / np.sqrt(n))
