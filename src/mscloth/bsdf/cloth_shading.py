"""One shading call of the ``cloth`` BSDF: the choice between the footprint estimator
(multi-scale) and the fibre-level BSDF at a point of the footprint, and what Mitsuba's
interface returns (values, densities, a sample record), for every variant.

The plugin (:mod:`.cloth`) forwards each ``mi.BSDF`` method here; ``clothpath`` reaches
:meth:`ClothShading.shade` through ``eval_pdf_sample_n``, several directions per call.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import drjit as dr
import mitsuba as mi

from ..scattering import spongecake
from ..lanes import pick
from .fibre_bsdf import FibreBSDF, edges_in_texels
from .footprint_estimator import FootprintEstimator
from .lobes import GAP, SHEEN, lobe_types
from .shading_state import ViewFrame


@dataclass
class SampleRecord:
    """A sampled direction (world's local frame) with its density, component and weight."""

    wo: Any
    pdf: Any
    component: Any
    weight: Any


def branch(cond, lanes_of, true_fn, false_fn, label):
    """``dr.if_stmt`` on the per-lane ``cond``: a packet whose lanes all take one side skips
    the other's work. In JIT variants ``cond`` is widened to the lanes of ``lanes_of`` first:
    a footprint from constant si.duv_dx/dy (tests, calibration) and the evaluated parameters
    is a single value, and Dr.Jit 1.5.0's if_stmt on a one-value condition that is not a
    literal returns one-value outputs from wider inputs (and then fails to run)."""
    if dr.is_jit_v(mi.Float):
        cond = cond & dr.full(mi.Bool, True, dr.width(lanes_of))
    return dr.if_stmt(args=(), cond=cond, true_fn=true_fn, false_fn=false_fn, label=label)


def _unzip(pairs):
    """[(a, b), ...] -> ([a, ...], [b, ...])."""
    return [p[0] for p in pairs], [p[1] for p in pairs]


def eval_pdf_each(eval_pdf, directions, gradients=False, loop=True):
    """([values], [pdfs]) of ``eval_pdf(wo, unrolled)`` at each of ``directions``. In JIT
    variants two or more directions go through one symbolic loop, so the traced code holds
    one copy of the evaluation instead of one per direction: the footprint BSDF's is most
    of a render kernel, and its compilation most of a first picture's wait (it also runs
    faster: docs/performance-log.md L38). Where ``gradients`` flow (reverse-mode AD does not
    cross symbolic loops), or without ``loop``, one traced copy per direction instead;
    ``eval_pdf``'s ``unrolled`` is ``gradients``: its own loops must unroll too."""
    n = len(directions)
    if n < 2 or not dr.is_jit_v(mi.Float) or gradients or not loop:
        return _unzip([eval_pdf(wo, gradients) for wo in directions])
    lanes = dr.width(directions)

    def body(i, values, pdfs):
        value, pdf = eval_pdf(pick(directions, i), False)
        values = tuple(dr.select(i == k, value, old) for k, old in enumerate(values))
        pdfs = tuple(dr.select(i == k, pdf, old) for k, old in enumerate(pdfs))
        return i + 1, values, pdfs

    state = (dr.zeros(mi.UInt32, lanes), tuple(dr.zeros(mi.Color3f, lanes) for _ in range(n)),
             tuple(dr.zeros(mi.Float, lanes) for _ in range(n)))
    _, values, pdfs = dr.while_loop(state=state, cond=lambda i, values, pdfs: i < n, body=body,
                                    labels=("i", "values", "pdfs"), label="cloth_directions")
    return list(values), list(pdfs)


class ClothShading:
    """The shading of a ``cloth`` BSDF: its fibre-level BSDF and, when multi-scale, the
    footprint estimator over it."""

    #: Evaluate a shading point's directions (the emitter samples', the sampled one) in one
    #: symbolic loop rather than one traced copy each (:func:`eval_pdf_each`). False:
    #: unrolled (experiments).
    LOOP_DIRECTIONS = True

    def __init__(self, fibre: FibreBSDF, estimator: FootprintEstimator | None):
        self.fibre = fibre
        self.estimator = estimator
        #: The sky albedo table (:mod:`.sky_albedo`), built on request
        #: (:meth:`.cloth.ClothBSDF.prepare_sky_albedo`).
        self.sky_table = None

    def shade(self, enabled, si, wos, samples, active, pixel_offset=None, pixel_filter="box", mis=True,
              exact_wos=None, sky_albedo=False):
        """eval_pdf at the world-frame directions ``wos`` and, if ``samples`` =
        (sample1, sample2) is given, one sample: ([values], [pdfs], (bs, weight) or ()).
        ``pixel_offset``: the sample's offset from its pixel's centre, in pixels along
        the footprint's edges si.duv_dx, si.duv_dy (each in [-1/2, 1/2); below: not
        known), which picks its probe (:meth:`.FootprintEstimator.footprint`) and
        fibre-level point; ``pixel_filter``: the filter over the pixel (``box`` or ``tent``,
        ``clothpath``'s ``uv_filter``) that places them; ``mis`` False: the sample's density
        is read only for its sign, and footprints whose sample is weighed at a texel (shiny
        ones; rough ones where ``exact_wos`` marks their probe for texel-by-texel shading)
        report the one given that texel instead of the mixture's
        (:meth:`.FootprintEstimator.pdf`);
        ``exact_wos`` (a mask, or None): lanes whose directions ``wos`` carry most of the
        light, where rough cloth's probes of few texels are shaded texel by texel at them
        (:meth:`.FootprintEstimator.emitter_covered_texels`) and their sampled direction is
        weighed at its texel (``EMITTER_COVERED_AT_TEXEL``);
        ``sky_albedo`` True, or a mask of the lanes that want it: also (A, known) of
        :meth:`probe_albedo` there, a fourth value.

        Footprints of a texel or more take the multi-scale branch, smaller ones the
        fibre-level one; a symbolic if, so a packet of lanes that all take one branch
        skips the other's work."""
        fr = self.fibre.frame(si, active, pixel_offset, pixel_filter)
        wos = [fr.mirror(wo) for wo in wos]
        albedo = (mi.Color3f(0.0), mi.Float(0.0))
        if self.estimator is None:
            values, pdfs, record = self._point_branch(si, fr, enabled, wos, samples, active)
        else:
            # One hash and one footprint per shading point, for the branch choice and
            # for the branch taken.
            estimator = self.estimator
            exact_wos = self._exact_wos(si, fr, wos, exact_wos)
            hashed, fp = self._hashed_footprint(si, fr, exact_wos)
            if sky_albedo is not False:
                want = mi.Bool(active) & sky_albedo
                if isinstance(sky_albedo, bool) or not dr.is_jit_v(mi.Float) or self._gradients(si, fr, wos):
                    albedo = self.probe_albedo(fr, fp, hashed, want)
                else:  # (only camera rays' first hits want it: packets of later vertices skip the reads)
                    albedo = branch(want, (si, wos, samples), true_fn=lambda: self.probe_albedo(fr, fp, hashed, want),
                                    false_fn=lambda: (mi.Color3f(0.0), mi.Float(0.0)), label="cloth_sky_albedo")
            values, pdfs, record = branch(
                fp.use, (si, wos, samples),
                true_fn=lambda: self._footprint_branch(si, fr, enabled, wos, samples, active, fp, hashed, mis,
                                                       exact_wos),
                false_fn=lambda: self._point_branch(si, fr, enabled, wos, samples, active, fp, hashed[0]),
                label="cloth_footprint")
        values = [dr.select(active, v, 0.0) for v in values]
        pdfs = [dr.select(active, p, 0.0) for p in pdfs]
        sample = self._bsdf_sample(SampleRecord(*record)) if record else ()
        return (values, pdfs, sample) if sky_albedo is False else (values, pdfs, sample, albedo)

    def _exact_wos(self, si, fr: ViewFrame, wos, exact_wos):
        """``exact_wos`` where a probe may be shaded texel by texel at the emitters, else None."""
        estimator = self.estimator
        if exact_wos is not None and not (
                estimator.covered_texels() == 0 and estimator.emitter_covered_texels() > 0 and wos
                and not self._gradients(si, fr, wos)):
            return None
        return exact_wos

    def probe_albedo(self, fr: ViewFrame, fp, hashed, active):
        """(A, known): the mean directional albedo (delta lobes included) of what the
        shading point of footprint ``fp`` and hash ``hashed`` samples its direction from
        (the probe of the footprint branch, the texel of the fibre-level one), from the
        sky albedo table (:mod:`.sky_albedo`); known 1 where the table gives it, else 0
        (and A 0)."""
        table = self.sky_table
        if table is None:
            return mi.Color3f(0.0), mi.Float(0.0)
        xi = hashed[0]
        if fp.point_xi is not None:
            xi = dr.select(fp.point_known, fp.point_xi, xi)
        x, y = self.estimator.point_in_footprint(fr, fp, xi)
        known = mi.Bool(active)
        # Lanes that want none read cell (0, 0), all of them: the same cache lines.
        x, y = dr.select(known, x, 0.0), dr.select(known, y, 0.0)
        albedo = table.probe_albedo(fp.boxes, fp.split, fp.use & known, x, y, fr.wi, fr.flip, hashed[1])
        # (Probes of few texels read A a few per cent off, a cell's Monte Carlo mean or a
        # block's: still far less error at 16 spp than without it; performance log L60.)
        return mi.Color3f(dr.select(known, albedo, 0.0)), dr.select(known, mi.Float(1.0), mi.Float(0.0))

    def _hashed_footprint(self, si, fr: ViewFrame, exact_wos=None):
        """(the shading hash (xi, xi_round, u), the footprint it picks): one of each per
        shading point, for the branch choice and for the branch taken (``exact_wos``: see
        :meth:`shade`)."""
        hashed = self.estimator.shading_hash(si)
        return hashed, self.estimator.footprint(si, fr, hashed[2], exact_emitters=exact_wos)

    def sample_footprint(self, enabled, si, sample1, sample2, active=True):
        """(BSDFSample3f, weight) of the footprint branch alone, for footprints known to be
        over ``FOOTPRINT_TEXELS`` (the share calibration's): the kernel then holds no
        fibre-level branch (a fifth fewer operations than :meth:`shade`'s)."""
        fr = self.fibre.frame(si, active)
        hashed, fp = self._hashed_footprint(si, fr)
        record = self._footprint_branch(si, fr, enabled, [], (sample1, sample2), active, fp, hashed)[2]
        return self._bsdf_sample(SampleRecord(*record))

    def _point_branch(self, si, fr: ViewFrame, enabled, wos, samples, active, fp=None, xi=None):
        """(values, pdfs, sample record) of the fibre-level BSDF at the texel under
        si.uv (or, for a small footprint ``fp``, under the point ``xi`` of it, uniform in
        [0,1)^2: the shading hash's), for the mirrored directions ``wos`` and, if given,
        one sample."""
        fibre = self.fibre
        x, y = fr.x, fr.y
        if fp is not None:
            if fp.point_xi is not None:
                # The sample's own point of the pixel: brute force, exactly.
                xi = dr.select(fp.point_known, fp.point_xi, xi)
            x, y = self.estimator.point_in_footprint(fr, fp, xi)
        pt = fibre.read_visibility(fibre.texel(fr, x, y))
        probs = fibre.lobe_probabilities(pt, enabled)

        def eval_pdf(wo, unrolled):
            return fibre.eval_pdf(pt, wo, enabled, probs)

        sampled = None
        if samples is not None:
            wo, ok, component, gap_ok = fibre.sample(pt, probs, enabled, *samples, active)
            sampled = (wo, ok, component, gap_ok, probs[GAP], fibre.gap_value(fr, pt.yarn))
        return self._evaluate(si, fr, eval_pdf, wos, sampled)

    def _footprint_branch(self, si, fr: ViewFrame, enabled, wos, samples, active, fp, hashed, mis=True,
                          exact_wos=None):
        """The same for the footprint BSDF (multi-scale shading) of footprint ``fp``,
        with the shading hash ``hashed`` it came from."""
        estimator = self.estimator
        xi, xi_round, _ = hashed

        def shade(grid=None, exact=None, covered=False, emitters_covered=False):
            st = estimator.state(si, fr, enabled, xi, xi_round, fp=fp, grid=grid, exact=exact)

            def eval_pdf(wo, unrolled):
                if covered or emitters_covered:
                    return estimator.eval_pdf_covered(fr, st, wo, enabled, unrolled)
                return estimator.eval_pdf(fr, st, wo, enabled, unrolled)

            # Weigh the sampled direction at the texel that lent its tangent: shiny cloth,
            # and lanes whose emitter directions carry most of the light.
            weigh_at_texel = estimator.sample_at_texel() or (
                emitters_covered and estimator.EMITTER_COVERED_AT_TEXEL)
            sampled = None
            if samples is not None:
                sampled = estimator.sample(fr, st, enabled, *samples, active, weigh_at_texel)
            at_texel = None
            if sampled is not None:
                sampled, chosen = sampled[:-1], sampled[-1]
                if weigh_at_texel:
                    value, pdf = estimator.texel_eval_pdf(fr, st, chosen, sampled[0], enabled)
                    # (Where gradients flow the pdf's texel loop unrolls, as eval_pdf's.)
                    density = estimator.pdf(fr, st, sampled[0], enabled, self._gradients(si, fr)) if mis else pdf
                    at_texel = (value, pdf, density)
                elif emitters_covered:
                    value, pdf = estimator.eval_pdf(fr, st, sampled[0], enabled)
                    at_texel = (value, pdf, pdf)
            return self._evaluate(si, fr, eval_pdf, wos, sampled, at_texel)

        small = shade
        covered = estimator.covered_texels()
        emitter_covered = estimator.emitter_covered_texels()
        if exact_wos is not None:  # (shade: only where the rule applies)
            def small():
                return branch(exact_wos & (fp.covered_count() <= emitter_covered), (si, wos, samples),
                              true_fn=lambda: shade(emitters_covered=True), false_fn=shade,
                              label="cloth_covered_emitters")
        # Probes of few texels shaded texel by texel (a packet of larger ones skips it),
        # except where gradients flow: there each texel would be a traced copy.
        if covered > 0 and not self._gradients(si, fr, wos):
            def small():
                return branch(fp.covered_count() <= covered, (si, wos, samples),
                              true_fn=lambda: shade(covered=True), false_fn=shade, label="cloth_covered_probe")
        large = estimator.large_probe_grid()
        if large is None:
            return small()
        # Large probes take a finer residual grid and rounded SAT corners (their rounding
        # noise is small); a packet of small ones skips the grid's texels.
        texels, grid = large
        return branch(fp.probe_texels() >= texels, (si, wos, samples), true_fn=lambda: shade(grid, False),
                      false_fn=small, label="cloth_large_probe")

    def _evaluate(self, si, fr: ViewFrame, eval_pdf, wos, sampled, at_sample=None):
        """(values, pdfs, sample record or ()) of a branch: ``eval_pdf`` at the directions
        ``wos`` and at the sampled one (``sampled``: what the branch's sample returned, with
        its gap's pdf and value; None without a sample), all in one loop
        (:func:`eval_pdf_each`); ``at_sample``: the sampled direction's (value, pdf)
        if the branch has them already."""
        directions = list(wos) + ([sampled[0]] if sampled is not None and at_sample is None else [])
        gradients = self._gradients(si, fr, directions)
        values, pdfs = eval_pdf_each(eval_pdf, directions, gradients, self.LOOP_DIRECTIONS)
        if sampled is None:
            return values, pdfs, ()
        if at_sample is None:
            value, pdf = values.pop(), pdfs.pop()
            density = pdf
        else:
            value, pdf, density = at_sample
        record = self._sample_record(si, fr, value, pdf, *sampled, density=density)
        return values, pdfs, record

    def _gradients(self, si, fr: ViewFrame, directions=()) -> bool:
        """Whether gradients flow through a shading point (its directions, the interaction,
        the shading parameters): loops over directions and texels then unroll."""
        p = self.fibre.params
        return dr.grad_enabled(directions, si, fr.k, p.roughness, p.thickness, p.sheen_roughness, p.sheen_thickness)

    @staticmethod
    def _sample_record(si, fr: ViewFrame, value, pdf, wo, ok, component, gap_ok, gap_pdf, gap_value, density=None):
        """(wo in the world's local frame, pdf, component, weight) of a sampled mirrored
        direction with its ``value`` and ``pdf`` (weight = value / pdf), or of the gap: a
        tuple, the output of a symbolic if. ``density``: the sampling density to report
        (MIS), where ``pdf`` is the density given a choice the weight depends on."""
        ok &= pdf > 0.0
        weight = dr.select(ok, value / dr.select(ok, pdf, 1.0), 0.0)
        gap_ok &= gap_pdf > 0.0
        gap_weight = gap_value / dr.select(gap_ok, gap_pdf, 1.0)
        density = pdf if density is None else density
        return (dr.select(gap_ok, -si.wi, fr.mirror(wo)),
                dr.select(gap_ok, gap_pdf, dr.select(ok, density, 0.0)),
                dr.select(gap_ok, mi.UInt32(GAP), component),
                dr.select(gap_ok, mi.Color3f(gap_weight), weight))

    @staticmethod
    def _bsdf_sample(record: SampleRecord):
        """(BSDFSample3f, weight) of a sample record. Built after the branches: values
        that are the same literal in both branches of a symbolic if (eta = 1) trip
        Dr.Jit's LLVM code generation inside virtual calls."""
        bs = dr.zeros(mi.BSDFSample3f)
        bs.wo = record.wo
        bs.pdf = record.pdf
        bs.eta = 1.0
        bs.sampled_component = record.component
        type_of = [mi.UInt32(+f) for f in lobe_types()]
        sampled_type = type_of[SHEEN]
        for c in range(1, 6):
            sampled_type = dr.select(record.component == c, type_of[c], sampled_type)
        bs.sampled_type = sampled_type
        return bs, record.weight

    # ------------------------------------------------------------------
    # What clothpath asks besides shading
    # ------------------------------------------------------------------
    def footprint_texels(self, si, active=True):
        """Full widths (u, v) in texels of this tile of the footprint in si.duv_dx/dy."""
        p = self.fibre.params
        (ax, ay), (bx, by) = edges_in_texels(p.uv_scale, p.uv_scale_v, self.fibre.tile, si)
        wu, wv = dr.abs(ax) + dr.abs(bx), dr.abs(ay) + dr.abs(by)
        ok = active & dr.isfinite(wu) & dr.isfinite(wv)
        return dr.select(ok, wu, 0.0), dr.select(ok, wv, 0.0)

    def gap_transmission(self, si, active=True):
        """Fraction of light crossing the cloth straight along -si.wi through its gaps:
        T_sheen(i)^2 (1 - I), with I the yarn coverage of the footprint in
        si.duv_dx/dy (multi-scale; below 8 texels, possibly of the texel at the point
        fibre-level shading takes) or of the texel (used by clothpath's shadow rays).
        The footprint's I is its mean over the stochastically rounded box, the one the
        footprint BSDF shades (or, with exact corners, the box it rounds, the same in
        expectation): the crossing lets through what the BSDF's gap lobe does at the
        same point."""
        fibre = self.fibre
        fr = fibre.frame(si, active)
        estimator = self.estimator
        if estimator is None:
            yarn = fibre.texel(fr, fr.x, fr.y).yarn
        else:
            (xi, xi_round, _), fp = self._hashed_footprint(si, fr)
            data = fibre.footprint_data

            def texel_yarn():  # at the point the fibre-level branch shades
                return fibre.texel(fr, *estimator.point_in_footprint(fr, fp, xi)).yarn

            def footprint_yarn():
                # One read per corner of the rounded box (exact corners took four, and
                # were most of what a shadow ray crossing cloth cost). Its mean stays in
                # [0, 1]: over the exact area it did not, and the clip below then let
                # light through gap-free footprints (docs/decisions.md).
                _, q = estimator.shaded_boxes(fp, xi_round)
                return data.scalar_sats.integral(q, data.GAP) / q.area

            # Packets whose lanes all have a footprint skip the texel read; packets
            # without one (shadow rays from vertices shaded at a point) the table reads.
            yarn = branch(fp.use & active, (si, active), true_fn=footprint_yarn, false_fn=texel_yarn,
                          label="cloth_gap_footprint")
        return dr.select(active & (dr.abs(si.wi.z) > spongecake.COS_EPSILON),
                         fibre.gap_value(fr, dr.clip(yarn, 0.0, 1.0)), 0.0)
