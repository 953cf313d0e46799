"""What ``clothpath`` and its gap shadows expect of a footprint-aware BSDF.

Any ``mi.BSDF`` renders under ``clothpath``; a BSDF may in addition offer the members of
:class:`FootprintBSDF` (``cloth`` offers all of them). Each member is optional and found on
the instance, so a BSDF written elsewhere opts in by defining it; the integrators ask
through the functions below, never with ``hasattr`` of their own. This module knows no
BSDF class: the integrators stay independent of :mod:`mscloth.bsdf`.

Footprint convention (all members): the footprint of a shading point is the UV
parallelogram centred on ``si.uv`` spanned by ``si.duv_dx`` and ``si.duv_dy`` (zero: shade
the point), see :mod:`mscloth.integrators.footprint`.
"""
from __future__ import annotations

import inspect

from typing import Protocol, runtime_checkable

import drjit as dr
import mitsuba as mi


@runtime_checkable
class FootprintBSDF(Protocol):
    """The optional members of a BSDF that ``clothpath`` uses (each one on its own).

    ``footprint_shading``
        True when the BSDF shades whole footprints (multi-scale ``cloth``): at first hits it
        is handed the uv of the pixel centre (the pixel is its footprint's average) and
        ``pixel_offset``. Read only together with ``eval_pdf_sample_n``.
    """

    footprint_shading: bool

    def eval_pdf_sample_n(self, ctx, si, wos, sample1, sample2, active=True, pixel_offset=None,
                          pixel_filter="box", mis=True, exact_wos=None, sky_albedo=False):
        """``([value], [pdf], bs, weight)``: ``eval_pdf`` (times cos) at each direction of
        ``wos`` (local frame) and one ``sample``, sharing the work of one shading point.
        ``pixel_offset`` (``footprint_shading`` BSDFs only, at first hits): the camera
        sample's offset from its pixel centre in pixels, each coordinate in [-1/2, 1/2),
        -1 where unknown: the part of the footprint the sample stands for;
        ``pixel_filter`` (``box`` or ``tent``: ``clothpath``'s ``uv_filter``) the filter over
        the pixel that the offset places the sample in; ``mis`` (optional parameter)
        False: the caller uses the sample's ``bs.pdf`` only where it is positive (no MIS
        at the next hit, no ray cone from it), so a BSDF may report there the density
        given choices its weight depends on, if that is cheaper; ``exact_wos`` (optional
        parameter; a mask per lane, first hits only): the directions of ``wos`` (delta
        emitters' there) carry most of the light and no sampling noise of their own, so a
        BSDF's own noise at them is most of the pixel's: worth evaluating them with less,
        at more cost; ``sky_albedo`` (optional parameter) True, or a mask of lanes: two
        more values, ``(A, known)`` there: the mean directional albedo (RGB, delta lobes included) of the lobes the
        sample is drawn from, i.e. its weight's expectation, and 1 where it is known (0
        elsewhere, A 0): for ``clothpath``'s control variate of a uniform sky. Must use
        ``sample1``/``sample2`` as ``sample`` would (same random-number order)."""

    def footprint_texels(self, si, active=True):
        """``(width_u, width_v)``: the footprint's full widths in texels of the BSDF's
        pattern tile (the ``footprint_texels_*`` AOVs), 0 where inactive."""

    def prepare_sky_albedo(self, max_mib: float | None = None) -> bool:
        """Make ready what ``eval_pdf_sample_n``'s ``sky_albedo`` reads (before a render
        traces), within ``max_mib`` MiB if given (a pilot's coarser table); whether this
        BSDF gives it."""

    def gap_transmission(self, si, active=True):
        """The fraction of light crossing the surface straight along ``-si.wi`` through
        its gaps (a delta transmission lobe of the BSDF, a null interface to light
        transport), over the footprint in ``si.duv_dx/dy``. Shadow rays cross such
        surfaces (:mod:`.gap_shadows`); others block them."""


def shades_n_directions(bsdf) -> bool:
    """Whether ``bsdf`` evaluates several directions and samples one in one call."""
    return hasattr(bsdf, "eval_pdf_sample_n")


def shades_footprints(bsdf) -> bool:
    """Whether ``bsdf`` shades whole footprints (wants the pixel centre and offset)."""
    return shades_n_directions(bsdf) and bool(getattr(bsdf, "footprint_shading", False))


def has_footprint_texels(bsdf) -> bool:
    """Whether ``bsdf`` reports its footprint's size in texels."""
    return hasattr(bsdf, "footprint_texels")


def has_gap_transmission(bsdf) -> bool:
    """Whether shadow rays cross ``bsdf`` through its gaps (None, no surface: False)."""
    return bsdf is not None and hasattr(bsdf, "gap_transmission")


def eval_pdf_sample_n(bsdf, ctx, si, si_centred, wos, sample1, sample2, active=True, pixel_offset=None,
                      pixel_filter="box", exact_wos=None, mis=True, sky_albedo=False):
    """eval_pdf at each direction of ``wos`` and one sample: ([values], [pdfs], bs, weight).

    BSDFs with their own ``eval_pdf_sample_n`` (``cloth``) share the work of one shading
    point between all directions; those that shade whole footprints see ``si_centred``
    (uv at the pixel centre on first hits), ``pixel_offset``, ``pixel_filter`` and, where
    their method takes them, ``mis`` and ``exact_wos``. Others get eval_pdf / sample calls
    on ``si`` (one direction: eval_pdf_sample, exactly as ``path``). ``sky_albedo`` True
    (or a Float, 1 at the lanes that want it: ``dr.dispatch`` takes a Bool argument for its
    mask): ``(A, known)`` after them, ``(0, 0)`` from BSDFs that do not give it."""
    if sky_albedo is not False and not gives_sky_albedo(bsdf):
        out = eval_pdf_sample_n(bsdf, ctx, si, si_centred, wos, sample1, sample2, active, pixel_offset, pixel_filter,
                                exact_wos, mis)
        return tuple(out) + (mi.Color3f(0.0), mi.Float(0.0))
    if shades_footprints(bsdf):
        parameters = inspect.signature(bsdf.eval_pdf_sample_n).parameters
        extra = {}
        if not mis and "mis" in parameters:
            extra["mis"] = mis
        if exact_wos is not None and "exact_wos" in parameters:
            # (clothpath hands it over as a Float: dr.dispatch takes a Bool for its mask.)
            extra["exact_wos"] = exact_wos if isinstance(exact_wos, (bool, mi.Bool)) else exact_wos > 0.5
        if sky_albedo is not False:  # (given: gives_sky_albedo)
            extra["sky_albedo"] = sky_albedo if isinstance(sky_albedo, (bool, mi.Bool)) else sky_albedo > 0.5
        if extra:
            return bsdf.eval_pdf_sample_n(ctx, si_centred, wos, sample1, sample2, active, pixel_offset, pixel_filter,
                                          **extra)
        if pixel_filter == "box":  # (the arguments came later: BSDFs without them still work)
            return bsdf.eval_pdf_sample_n(ctx, si_centred, wos, sample1, sample2, active, pixel_offset)
        return bsdf.eval_pdf_sample_n(ctx, si_centred, wos, sample1, sample2, active, pixel_offset, pixel_filter)
    if shades_n_directions(bsdf):
        return bsdf.eval_pdf_sample_n(ctx, si, wos, sample1, sample2, active)
    if len(wos) == 1:
        value, pdf, bs, weight = bsdf.eval_pdf_sample(ctx, si, wos[0], sample1, sample2, active)
        return [value], [pdf], bs, weight
    values, pdfs = [], []
    for wo in wos:
        value, pdf = bsdf.eval_pdf(ctx, si, wo, active)
        values.append(value)
        pdfs.append(pdf)
    bs, weight = bsdf.sample(ctx, si, sample1, sample2, active)
    return values, pdfs, bs, weight


def gives_sky_albedo(bsdf) -> bool:
    """Whether ``bsdf``'s ``eval_pdf_sample_n`` takes ``sky_albedo``."""
    return shades_footprints(bsdf) and "sky_albedo" in inspect.signature(bsdf.eval_pdf_sample_n).parameters


def distinct_bsdfs(scene, keep) -> list:
    """The distinct BSDFs of ``scene``'s shapes for which ``keep(bsdf)`` is true (asked
    once per BSDF)."""
    found = []
    for shape in scene.shapes():
        bsdf = shape.bsdf()
        if bsdf is not None and all(bsdf is not b for b in found) and keep(bsdf):
            found.append(bsdf)
    return found


def prepare_sky_albedo(bsdf, max_mib: float | None = None) -> bool:
    """``bsdf.prepare_sky_albedo(max_mib)`` where it gives ``sky_albedo``
    (:func:`gives_sky_albedo`) and has one: whether its sampled direction's expected
    weight is known."""
    if bsdf is None or not (gives_sky_albedo(bsdf) and hasattr(bsdf, "prepare_sky_albedo")):
        return False
    return bool(bsdf.prepare_sky_albedo(max_mib))


def footprint_texels(bsdf, si, active=True):
    """``bsdf.footprint_texels`` where it has one, (0, 0) elsewhere."""
    if has_footprint_texels(bsdf):
        return bsdf.footprint_texels(si, active)
    return mi.Float(0.0), mi.Float(0.0)


def gap_transmission(bsdf, si, active=True):
    """``bsdf.gap_transmission`` where it has one, 0 (it blocks) elsewhere."""
    if has_gap_transmission(bsdf):
        return bsdf.gap_transmission(si, active)
    return mi.Float(0.0)


def call(bsdf, func, *args, active=True, default=None):
    """``func(bsdf, *args)`` for the BSDF of each lane where ``active``: ``dr.dispatch``
    over a ``BSDFPtr`` in JIT variants (once per distinct BSDF; lanes off get zeros, and
    no BSDF runs for them), a plain call on the one BSDF of scalar variants, which return
    ``default`` where the lane is off or there is no BSDF (a miss: None)."""
    if dr.is_jit_v(mi.Float):
        if active is not True:
            bsdf = dr.select(active, bsdf, dr.zeros(mi.BSDFPtr))
        return dr.dispatch(bsdf, func, *args)
    return func(bsdf, *args) if active and bsdf is not None else default
