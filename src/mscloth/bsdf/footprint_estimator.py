"""The footprint (multi-scale) estimator of the ``cloth`` BSDF: the pixel footprint's probe
box, the SAT means over it with the control-variate residual texels (Eq. 9-14 with CCV),
and the mixture that samples it; tests and :mod:`mscloth.validation` call it through its
public methods.

The estimator is one class for every Mitsuba variant: it reads ``mi`` and ``dr`` of the
variant active when it is called, and builds on a :class:`.fibre_bsdf.FibreBSDF` for the
fibre-level pieces (texels, sheen, visibility, the lobe mixture) and its data (tables,
live parameters), read at call time. Its own lobe ``calibration`` is set by the plugin
(:func:`.lobe_calibration.calibrate`, which measures the footprint mixture with it).
"""
from __future__ import annotations

import dataclasses
from dataclasses import dataclass

import drjit as dr
import mitsuba as mi

from ..scattering import sggx, spongecake
from .fibre_bsdf import FibreBSDF, edges_in_texels
from ..lanes import logical_not, pick
from .lobe_mixture import SpecularHalfVectors, lobe_weights
from .lobes import DIFFUSE_REFLECTION, DIFFUSE_TRANSMISSION, GAP, SHEEN, SPECULAR_REFLECTION, SPECULAR_TRANSMISSION
from .sat_queries import RectQuery, RectUnion, hemisphere_triangle_bins, round_box
from ..pixel_filter import quadratic_bspline_quantile
from .shading_state import Texel, ViewFrame


@dataclass
class Footprint:
    """The pixel footprint of a shading point, in texel coordinates of the tile."""

    #: Whether to shade the footprint whole (else fibre level at a point in it).
    use: mi.Bool
    #: The probe: (x0, y0, x1, y1), the box of the slice's own area and centre.
    box: tuple
    #: (ax, ay, bx, by): the parallelogram's edges (zero where not finite).
    edges: tuple
    #: The boxes shaded whole, their SAT means summed: ``box`` alone, or where ``split``
    #: the boxes of the slice's parts (:meth:`FootprintEstimator.footprint`; the other
    #: entries then empty boxes (cx, cy, cx, cy)).
    boxes: list
    split: mi.Bool | bool
    #: The camera sample's place in its probe's cell, uniform in [0,1)^2 (None, or
    #: negative, where the sample's pixel offset is not known; None under a tent pixel
    #: filter, which spends it on the probe's offset).
    within: mi.Point2f | None = None
    #: The fibre-level branch's point of the parallelogram ((1/2, 1/2): its centre): the
    #: camera sample's own (in [0,1)^2; under a tent pixel filter, in [-1, 2)^2), where
    #: ``point_known``; None where no pixel offset is known.
    point_xi: mi.Point2f | None = None
    point_known: mi.Bool | None = None

    def probe_texels(self):
        """Texels in the probe: its boxes' areas summed (empty parts add nothing)."""
        return box_areas(self.boxes)[1]

    def covered_grids(self) -> list[TexelGrid]:
        """The whole texels under each of the probe's boxes (:class:`TexelGrid`)."""
        return [TexelGrid.of(*b) for b in self.boxes]

    def covered_count(self):
        """How many texels the probe's boxes cover, partly or whole (a texel under two
        parts counts twice)."""
        grids = self.covered_grids()
        return sum((g.count for g in grids[1:]), grids[0].count)


@dataclass
class TexelGrid:
    """The whole texels a box (x0, y0, x1, y1) covers, partly or whole: ``columns`` x
    ``rows`` from texel (first_x, first_y) on (floats; none for an empty box)."""

    box: tuple
    first_x: mi.Float
    first_y: mi.Float
    columns: mi.Float
    rows: mi.Float

    @staticmethod
    def of(x0, y0, x1, y1) -> TexelGrid:
        fx, fy = dr.floor(x0), dr.floor(y0)
        nonempty = (x1 > x0) & (y1 > y0)
        return TexelGrid(box=(x0, y0, x1, y1), first_x=fx, first_y=fy,
                         columns=dr.select(nonempty, dr.ceil(x1) - fx, 0.0),
                         rows=dr.select(nonempty, dr.ceil(y1) - fy, 0.0))

    @property
    def count(self):
        return self.columns * self.rows

    def texel(self, k):
        """(x, y, the texel's area under the box) of the ``k``-th texel (a float in
        [0, count), row by row)."""
        x0, y0, x1, y1 = self.box
        row = dr.floor((k + 0.5) * dr.rcp(dr.maximum(self.columns, 1.0)))
        x = self.first_x + (k - row * self.columns)
        y = self.first_y + row
        return x, y, ((dr.minimum(x1, x + 1.0) - dr.maximum(x0, x))
                      * (dr.minimum(y1, y + 1.0) - dr.maximum(y0, y)))


def box_areas(boxes):
    """Each box's (x0, y0, x1, y1) area, and their total (new values: a Dr.Jit ``+=`` would
    change the first area in place)."""
    areas = [(x1 - x0) * (y1 - y0) for x0, y0, x1, y1 in boxes]
    return areas, sum(areas[1:], areas[0])


@dataclass
class FootprintState:
    """Everything of a footprint that does not depend on the outgoing direction, shared by
    eval, pdf and sample (:meth:`FootprintEstimator.state`)."""

    fp: Footprint
    #: The SAT query of the shaded boxes (rounded or exact), and the inverse of their area.
    q: RectQuery | RectUnion
    inv_area: mi.Float
    #: Yarn coverage and mean yarn colour over the shaded boxes.
    yarn_mean: mi.Float | None = None
    yarn_albedo: mi.Color3f | None = None
    #: The footprint's mean t t^T over its yarn (xx, xy, xz, yy, yz, zz; mirrored frame);
    #: None when no specular lobe is enabled.
    moments: tuple | None = None
    #: The control-variate residual texels (:class:`.shading_state.Texel`).
    texels: list[Texel] | None = None
    #: Every cluster's mean viewer-side visibility, and the footprint's share of each
    #: cluster's yarn; None without visibility.
    cvis_i: list | None = None
    fractions: list | None = None
    #: The sampling mixture's lobe probabilities, its defensive cosine share and the
    #: lower (transmission) part of that share.
    probs: list | None = None
    eps_c: mi.Float | None = None
    eps_lower: mi.Float | None = None


def shading_hash(si):
    """Deterministic pseudo-random numbers per shading point, from si.uv and si.p:
    (xi, xi_round, u), two 2D points and one number: the stratified texels, the
    SAT rounding, and the choice between footprint and fibre-level shading and of the
    probe (:meth:`FootprintEstimator.footprint`; xi: the point of fibre-level shading in
    the footprint), in eval(), where Mitsuba passes no random numbers. si.p
    varies between the samples of one pixel, whose footprints ``clothpath`` centres
    on the same uv. Two TEAs (~40 ops each): four words give the points their top
    24 bits each, and u the words' low bytes."""
    def bits(x):  # 24 bits of a float's fractional part
        return mi.UInt32((x - dr.floor(x)) * 16777216.0)

    a = bits(si.uv.x * 997.0 + si.uv.y * 31.0 + si.p.x * 1.618 + si.p.z * 0.577)
    b = bits(si.uv.y * 991.0 + si.uv.x * 37.0 + si.p.y * 1.414 + si.p.z * 0.318)
    v0, v1 = mi.sample_tea_32(a, b)
    v2, v3 = mi.sample_tea_32(v0, v1)

    def unit24(v):  # 24 bits -> [0, 1)
        return mi.Float(v) * (1.0 / 16777216.0)

    def unit(v):  # the top 24 bits -> [0, 1)
        return unit24(v >> 8)

    low = ((v0 & 255) << 16) | ((v1 & 255) << 8) | (v2 & 255)  # 24 bits
    return mi.Point2f(unit(v0), unit(v1)), mi.Point2f(unit(v2), unit(v3)), unit24(low)


def _channels(x):
    """The three channels of a colour, or a Float three times."""
    if isinstance(x, mi.Color3f):
        return x[0], x[1], x[2]
    return x, x, x


def _table_tangent(fr: ViewFrame, tangent):
    """A texel's tangent (mirrored frame) back in the maps' frame of the tables."""
    return mi.Vector3f(tangent.x, tangent.y, fr.sign * tangent.z)


class FootprintEstimator:
    """The footprint BSDF of a multi-scale ``cloth`` BSDF, over its fibre-level BSDF.

    The tuning constants below are class attributes, so that experiments
    (``bench/common.py``'s ``--attr NAME=VALUE``) change them for every cloth BSDF."""

    #: Footprint area (texels) below which shading is fibre level (at the camera sample's
    #: own point: brute force), above which it is the footprint's; linear blend between.
    #: Under a stratified pixel sampler at 16 spp, point samples beat the footprint up to
    #: 1-2 texels per sample (satin near: squared bias 1.7e-4 -> 1.8e-5, noise per sample
    #: 0.024 -> 0.017; docs/performance-log.md L24).
    POINT_TEXELS = 16.0
    FOOTPRINT_TEXELS = 32.0
    #: ... but by the fibres' roughness: (below this roughness, POINT_TEXELS,
    #: FOOTPRINT_TEXELS), first match; else the two above. With exact SAT corners and 4 x 4
    #: residual texels (below) shiny cloth's footprint beats point samples down to a few
    #: texels: satin-plane near, noise per sample 0.033 (16 / 32) -> 0.016 (4 / 8) -> 0.0077
    #: (2 / 4), squared bias 1.6e-5 at 2 / 4, for +25% time; the satin spheres' near -24% at
    #: 4 / 8 (performance log L48); 0.0083 -> 0.0063 at 1 / 2 (bias 2.0e-5) for +1% time
    #: (L51).
    BLEND_TEXELS_BY_ROUGHNESS = ((0.15, 1.0, 2.0),)
    #: ... and where a shading point's emitter directions are marked exact
    #: (``exact_emitters`` of :meth:`footprint`) and probes of few texels are shaded texel by texel there
    #: (:meth:`emitter_covered_texels`): the sun's light then has no noise of its own in
    #: the footprint branch, which a point sample keeps. Denim near, noise per sample
    #: 0.00118 -> 0.000275 at 1 / 2, squared bias 1.1e-6 (performance log L57).
    EXACT_BLEND_TEXELS = (1.0, 2.0)
    #: Most probes (slices) across a footprint (more: boxes that fit long turned slices
    #: better, more variance between them). 8 left satin-plane's squared bias at
    #: 3.9e-4 / 3.6e-4 (middle / far), 16 at 6e-5 / 2.6e-5 for 11% / 34% more noise per
    #: sample (docs/performance-log.md L16).
    MAX_PROBES = 16
    #: Least number of cells along each edge (of 2 texels or more) of the parallelogram,
    #: probes being cells: 2 halves the bias of turned footprints (their edges blurred
    #: over smaller cells); under a stratified pixel sampler at 16 spp for 3-7% more noise
    #: (satin: bias^2 2.4e-4 / 1.7e-4 -> 5.1e-5 / 1.1e-4 middle / far; performance log L24).
    CELLS = 2
    #: ... but only where fewer slices than this cover the footprint, by the fibres'
    #: roughness: (below this roughness, slices), first match; else always. Shiny cloth
    #: keeps one cell across footprints cut into MAX_PROBES slices, long thin ones towards
    #: a horizon (two: 5-20x satin-plane's noise for no bias gained); on rough cloth two
    #: cut the probes' edge bias (sphere and drape 10-30%; denim's 7x / 2.4x in L24 was
    #: before exact corners and the tilt rule below, which gives flat denim one cell
    #: again at no bias) for up to 11% more noise on the sky-lit plane (performance log
    #: L24, L30, L31, L57).
    CELLS_BELOW_BY_ROUGHNESS = ((0.15, 16),)
    #: The slice count for every roughness instead (experiments), or None.
    CELLS_BELOW = None
    #: ... and only where the shading normal turns by more than this (radians) across
    #: the footprint (:meth:`normal_tilt`); None: wherever the rules above put them. The
    #: sample's cell lies around its own hit point, whose normal shades it: on curved
    #: cloth the cells keep each texel with the normal it is seen at (one cell: the
    #: sphere's squared bias 2.4e-5 -> 1.5e-4 middle, the drape's 5.9e-5 -> 1.5e-4). On
    #: flat cloth a cell only adds variance between the probes: one cell, denim far noise
    #: per sample 1.14e-5 -> 6.2e-6, satin-plane near 0.0061 -> 0.0048, the plane middle
    #: -11% (performance log L56, L57).
    CELLS_TILT = 1e-3

    # The footprint BSDF is sampled as a mixture: a lobe chosen by the footprint's
    # averages (so the gap, diffuse and specular shares match the footprint form), the
    # specular lobe from one of the stratified residual texels, and a defensive cosine
    # component that keeps every direction reachable.
    DEFENSIVE_COSINE = 0.1
    #: The least share of the defensive cosine on either side of the surface.
    DEFENSIVE_MIN_SIDE = 0.1

    #: Without per-cluster tables, the specular residual's control variate takes the
    #: footprint's mean visibility (unbiased) rather than each texel's cluster's, below a
    #: tile (over whole tiles the base is exact for the latter, which varies less).
    CONSISTENT_VISIBILITY_CV = True

    #: The control-variate residual's texels: one in each cell of a G x G grid over the
    #: shaded box, G by the fibres' roughness: (below this roughness, G), first match;
    #: else 2. Each texel costs ~7% of a brute-force sample; the residual's variance is
    #: that of the fibre-level D about its binned copy, large on shiny fibres. Roughness
    #: 0.12, 3 against 2: noise per sample (16 spp) -31% far on the satin spheres, -43% /
    #: -78% middle / far on satin-plane, for +10-22% time. With exact corners (below), 4
    #: against 3: satin-plane middle 0.0015 -> 0.00069, satin far -11%, for +4-10% time
    #: (5: 0.00048 for +30%, with the bias, 2e-5, then most of the middle's error at 16
    #: spp). Rough cloth (0.3-0.4), 2 against 1: noise x time equal on the plane, -20 to
    #: -50% on sphere, drape and denim (performance log L25, L27, L48).
    RESIDUAL_GRIDS = ((0.15, 4),)
    #: G for every roughness instead (experiments), or None.
    RESIDUAL_GRID = None
    #: A finer grid for large probes: (below this roughness, from this many texels in the
    #: probe's boxes, G), first match; else none. On satin-plane far away (probes of
    #: 256-1000 texels) the residual is most of the noise and falls faster than 1/G^2:
    #: noise per sample 0.00058 / 0.00031 / 0.00024 / 0.00020 at G = 3 / 4 / 5 / 6, the
    #: bias 8e-6 throughout; whole-frame time per sample the same at G = 4 and 5, +10% at
    #: 6. In the middle (smaller probes) G = 4 for every probe bought -11% noise for +15%
    #: time. A symbolic branch, so the packets of small probes skip the finer grid's
    #: texels (performance log L46). Since the middle's probes are shaded texel by texel
    #: (COVERED_TEXELS_BY_ROUGHNESS), G = 6: far noise per sample -19% for +4% time (L53).
    LARGE_PROBE_GRIDS = ((0.15, 256.0, 6),)
    #: (texels, G) for every roughness instead (experiments: LARGE_PROBE_TEXELS and
    #: LARGE_PROBE_GRID), or None.
    LARGE_PROBE_TEXELS = None
    LARGE_PROBE_GRID = 5

    #: Place the residual texels by the camera sample's place in its probe's cell where it
    #: is known (else by the shading hash), so that a stratified pixel sampler stratifies
    #: them between a pixel's samples as it does the probes (satin: noise per sample -3 to
    #: -11%). The corners' rounding stays the hash's: drawn from the same place it made the
    #: texels' positions depend on the rounded box, a bias (performance log L24).
    STRATIFY = True

    #: Each probe (slice) shaded as SUB_PROBES boxes, its parts cut along the edge the
    #: footprint's slices cut, by the fibres' roughness: (below this roughness, parts),
    #: first match; else 1; only where the slice fills less than SPLIT_BELOW_FIT of its
    #: bounding box (turned slices, which one box fits worst). Two parts, shiny cloth:
    #: squared bias 3.7e-5 / 3.1e-5 -> 2.3e-5 / 8e-6 (satin-plane middle / far), 4.9e-5 /
    #: 1.0e-4 -> 2.9e-5 / 6.8e-5 (satin) for a few % more time per sample; cut along the
    #: slice's own long edge instead, satin gained nothing; four parts raised the noise
    #: far away (docs/performance-log.md L44, L45).
    SUB_PROBES_BY_ROUGHNESS = ((0.15, 2),)
    #: The part count for every roughness instead (experiments), or None.
    SUB_PROBES = None
    SPLIT_BELOW_FIT = 0.7
    #: ... and slices of at least this many texels below this fit: (texels, fit), or None.
    #: The probes' blurred ends were most of shiny cloth's remaining bias (satin-plane:
    #: 64 slices instead of 16 left none, for 30x the noise); splitting slices of 16
    #: texels or more below a fit of 0.9: squared bias middle / far 2.0e-5 / 1.3e-5 ->
    #: 9e-6 / 4.6e-6, noise +6% / -5%, +4% time; smaller slices split that way raised the
    #: near bias 1.6e-5 -> 7e-5 (performance log L49).
    SPLIT_BELOW_FIT_LARGE = (16.0, 0.9)

    #: Read the probes' SAT corners exactly (bilinear, four reads per corner and channel)
    #: instead of rounding them stochastically to whole texels (one read), by the fibres'
    #: roughness: (below this roughness, True), first match; else False. Large probes
    #: (LARGE_PROBE_GRIDS) keep the rounding. On shiny cloth the rounding was most of the
    #: noise of mid-sized probes: satin-plane noise per sample near / middle / far
    #: 0.045 / 0.0073 / 0.00022 -> 0.033 / 0.0015 / 0.00018 (every probe exact), for 33% more
    #: time per sample; rough cloth gained less than it paid (sphere -1 to -7% noise for +14%
    #: time) (performance log L48).
    EXACT_CORNERS_BY_ROUGHNESS = ((0.15, True),)
    #: Exact corners for every roughness (True) or none (False) instead (experiments), or None.
    EXACT_CORNERS = None

    #: Weigh the sampled direction by the fibre-level BSDF of the texel that lent its
    #: tangent instead of evaluating the footprint BSDF there, by the fibres' roughness:
    #: (below this roughness, True), first match; else False. The weight f_k / p_k (p_k:
    #: the mixture's density given texel k, uniform over the probe whichever lobe is
    #: picked) is unbiased for the footprint's; the sample's reported density stays the
    #: mixture's (MIS). It saves one footprint evaluation of the directions a first hit
    #: evaluates (two under a sun and a uniform sky) for the noise of a texel instead of a
    #: footprint in what the sampled direction carries: on shiny cloth under a sun little
    #: (satin-plane: noise +4%, time per sample -25%); where the sky or bounced light is
    #: most of the noise and the cloth has gaps, much (the rough sphere scene: +50-120%
    #: for -10%) (performance log L52).
    SAMPLE_AT_TEXEL_BY_ROUGHNESS = ((0.15, True),)
    #: True or False for every roughness instead (experiments), or None.
    SAMPLE_AT_TEXEL = None

    #: Probes whose boxes cover at most this many texels (partly or whole) are shaded by
    #: every one of them, each weighted by its area under the boxes (:meth:`eval_pdf_covered`),
    #: instead of by the SAT means and residual texels: the fibre-level mean over the boxes
    #: itself, without the residual texels' noise, by the fibres' roughness: (below this
    #: roughness, texels), first match; else none. On shiny cloth the residual texels were
    #: most of the middle distance's noise, in probes of under 32 texels
    #: (docs/performance-log.md L53).
    COVERED_TEXELS_BY_ROUGHNESS = ((0.15, 128),)
    #: The count for every roughness instead (experiments; 0: none), or None.
    COVERED_TEXELS = None

    #: Where ``clothpath`` says a first hit's emitter directions carry most of its light
    #: (``exact_wos``: a sun over a dim sky), probes of at most this many covered texels
    #: are shaded texel by texel at those directions (the sampled one weighed at its texel:
    #: EMITTER_COVERED_AT_TEXEL), by roughness: (below, texels), first match; else none. For rough
    #: cloth, which COVERED_TEXELS_BY_ROUGHNESS leaves out: under a sun its residual
    #: texels' noise is the pixel's (denim middle: noise per sample 0.000349 -> 0.000178,
    #: for +5% time); under a bright sky it is not, and the lanes keep the SAT means
    #: (performance log L53, L56). Since their sampled direction is weighed at its texel,
    #: 32 texels cost what 16 did: denim middle 0.000188 -> 0.0000899 (64: 0.0000694 for
    #: +4.6% time; 128: 0.0000646, +10%), near and far unchanged (L58).
    EMITTER_COVERED_TEXELS_BY_ROUGHNESS = ((float("inf"), 32),)
    #: The count for every roughness instead (experiments), or None.
    EMITTER_COVERED_TEXELS = None
    #: ... and there the sampled direction is weighed at its texel (as
    #: SAMPLE_AT_TEXEL_BY_ROUGHNESS does for shiny cloth): the emitter directions carry
    #: most of those lanes' light and the sampled one little, so one footprint evaluation
    #: fewer costs little noise. Denim: time per sample 2.35x -> 1.99x brute force's,
    #: noise per sample near / middle +13% / +4%, far and the bias unchanged (performance
    #: log L58). The share calibration never shades these lanes (no TUNING key).
    EMITTER_COVERED_AT_TEXEL = True

    #: Sum the residual texels' terms in a symbolic loop (:meth:`eval_pdf`); False: one
    #: traced copy per texel (experiments; where gradients flow, always).
    LOOP_TEXELS = True

    #: The tuning constants above (a cached calibration, measured with them, keys on them).
    TUNING = ("POINT_TEXELS", "FOOTPRINT_TEXELS", "BLEND_TEXELS_BY_ROUGHNESS",
              "EXACT_BLEND_TEXELS", "MAX_PROBES", "CELLS", "CELLS_BELOW", "CELLS_BELOW_BY_ROUGHNESS", "CELLS_TILT",
              "DEFENSIVE_COSINE", "DEFENSIVE_MIN_SIDE",
              "CONSISTENT_VISIBILITY_CV", "RESIDUAL_GRIDS", "RESIDUAL_GRID", "STRATIFY",
              "SUB_PROBES_BY_ROUGHNESS", "SUB_PROBES", "SPLIT_BELOW_FIT", "SPLIT_BELOW_FIT_LARGE",
              "LARGE_PROBE_GRIDS", "LARGE_PROBE_TEXELS", "LARGE_PROBE_GRID",
              "EXACT_CORNERS_BY_ROUGHNESS", "EXACT_CORNERS", "SAMPLE_AT_TEXEL_BY_ROUGHNESS",
              "SAMPLE_AT_TEXEL", "COVERED_TEXELS_BY_ROUGHNESS", "COVERED_TEXELS",
              "EMITTER_COVERED_TEXELS_BY_ROUGHNESS", "EMITTER_COVERED_TEXELS")

    def __init__(self, fibre: FibreBSDF, roughness: float):
        self.fibre = fibre
        #: The fibres' roughness as a number (the BSDF's parameter is a live Float): it
        #: sizes the residual grid (:meth:`residual_grid`).
        self.roughness = roughness
        #: :class:`.lobe_calibration.LobeCalibration` of the footprint mixture's lobe
        #: choice (None: the raw proxies).
        self.calibration = None

    def shading_hash(self, si):
        """:func:`shading_hash`: the estimator's random numbers (xi, xi_round, u) of the
        shading point. A method, so that a test or an experiment can replace it (on one
        estimator, or on the class)."""
        return shading_hash(si)

    # ------------------------------------------------------------------
    # The footprint and its probe
    # ------------------------------------------------------------------
    def edges_texels(self, si):
        """The pixel footprint's edges si.duv_dx, si.duv_dy in texels of this tile."""
        p = self.fibre.params
        return edges_in_texels(p.uv_scale, p.uv_scale_v, self.fibre.tile, si)

    def footprint(self, si, fr: ViewFrame, u, u_probe=None, exact_emitters=None) -> Footprint:
        """The pixel footprint's probe (a texel box), and whether to shade it as one.

        Convention (docs/architecture.md): the footprint is the parallelogram spanned by
        si.duv_dx and si.duv_dy, centred on si.uv. It is cut along one edge into the n
        slices (n <= ``MAX_PROBES``) whose bounding boxes cover the least area (one for
        an axis-aligned rectangle; the edge that does better), and one slice (by the
        sample's pixel offset where ``fr`` knows it, else by ``u``) is shaded as the box of
        its own area and centre (the probe): as hardware anisotropic filtering does, with
        the probes taken one per sample. The expected probe is the parallelogram with its
        edges blurred over a fraction of a slice, not its bounding box, at one box's reads.

        Footprints covering fewer than ``POINT_TEXELS`` texels (:meth:`blend_texels`) are
        shaded fibre level at a point drawn uniformly in the parallelogram (exactly the
        fibre-level BSDF at si.uv for a zero footprint), those over ``FOOTPRINT_TEXELS``
        whole, and those
        between by one or the other, picked by ``u`` with a weight linear in the
        area: both estimate the same footprint mean, and a footprint of a few texels
        was noisier than a fibre-level sample. ``u_probe`` (default: ``u`` rescaled
        within the footprint's share) picks the probe. ``exact_emitters`` (a mask, or None):
        lanes whose emitter directions are marked exact where rough cloth's probes of few
        texels are shaded texel by texel there; they blend between ``EXACT_BLEND_TEXELS``
        instead (their larger probes, too, by the SAT means and residual texels).

        Under ``clothpath``'s tent ``uv_filter`` (``fr.pixel_filter``), where the sample's
        place in its pixel is known, the probe also moves by a tent offset of up to a pixel
        along each edge and the fibre-level point sits at the quadratic B-spline's quantile
        of that place: both then estimate the footprint under box x tent.
        """
        (ax, ay), (bx, by) = self.edges_texels(si)
        finite = dr.isfinite(ax) & dr.isfinite(ay) & dr.isfinite(bx) & dr.isfinite(by)
        la2, lb2 = ax * ax + ay * ay, bx * bx + by * by
        area = dr.abs(ax * by - ay * bx)
        length = dr.safe_sqrt(dr.maximum(la2, lb2))
        # Width across the long edge; a degenerate (line) footprint covers a texel's width.
        width = area * dr.select(length > 0.0, dr.rcp(length), 0.0)
        texels = dr.maximum(length, 1.0) * dr.maximum(width, 1.0)
        p_use = self._footprint_share(texels, *self.blend_texels())
        if exact_emitters is not None:
            p_use = dr.select(exact_emitters, self._footprint_share(texels, *self.EXACT_BLEND_TEXELS), p_use)
        p_use = dr.select(finite & (length > 0.0), p_use, 0.0)
        # (p_use > 0) first: a zero footprint of constant si.duv_dx/dy is then a literal
        # False, and the symbolic if traces the fibre-level branch alone.
        use = (p_use > 0.0) & (u < p_use)
        one_number = True  # u_probe alone picks the cell: along the slices, then across
        known = point_xi = None
        tent = fr.pixel_filter == "tent"
        if u_probe is None:
            u_probe = dr.minimum(u * dr.select(p_use > 0.0, dr.rcp(p_use), 0.0), 0.99999994)
            u_probe_a = u_probe_b = u_probe
            offset = fr.pixel_offset
            if offset is not None:
                # The slice the sample lies in: with a stratified sampler (multijitter
                # stratifies each pixel axis), a pixel's samples spread evenly over
                # its slices, and the probes' variance between them mostly cancels.
                known = (offset.x >= -0.5) & (offset.y >= -0.5)
                x = dr.clip(offset.x + 0.5, 0.0, 0.99999994)
                y = dr.clip(offset.y + 0.5, 0.0, 0.99999994)
                point_xi = mi.Point2f(x, y)
                if tent:  # the point at the B-spline's quantile (stratified as the sample)
                    point_xi = mi.Point2f(quadratic_bspline_quantile(x) + 0.5, quadratic_bspline_quantile(y) + 0.5)
                u_probe_a = dr.select(known, x, u_probe)
                u_probe_b = dr.select(known, y, u_probe)
                one_number = False
        else:
            u_probe_a = u_probe_b = u_probe

        def slicing(l_x, l_y, l2, s_x, s_y):
            """(n, the n slices' bounding-box area) cutting edge l into n slices: the n
            that minimises that area, |lx||ly|/n + |lx||sy| + |sx||ly| + n|sx||sy|, at
            most one per texel of l and MAX_PROBES (1 for an axis-aligned rectangle)."""
            lxy = dr.abs(l_x * l_y)
            sxy = dr.abs(s_x * s_y)
            best = dr.safe_sqrt(lxy * dr.rcp(dr.maximum(sxy, 1e-12)))
            n = dr.clip(dr.round(dr.minimum(best, dr.safe_sqrt(l2))), 1.0, float(self.MAX_PROBES))
            box = (dr.abs(l_x) * dr.rcp(n) + dr.abs(s_x)) * (dr.abs(l_y) * dr.rcp(n) + dr.abs(s_y))
            return n, n * box

        # Slices along whichever edge leaves the probes less area outside the pixel.
        n_a, cover_a = slicing(ax, ay, la2, bx, by)
        n_b, cover_b = slicing(bx, by, lb2, ax, ay)
        along_a = cover_a <= cover_b
        n = dr.select(along_a, n_a, n_b)
        u_probe = dr.select(along_a, u_probe_a, u_probe_b)  # edge a: the pixel's x step
        lx, ly = dr.select(along_a, ax, bx), dr.select(along_a, ay, by)
        sx, sy = dr.select(along_a, bx, ax), dr.select(along_a, by, ay)
        # At least CELLS cells along each edge of two texels or more, where the slices
        # alone are fewer than cells_below().
        few = n < float(self.cells_below())
        if self.CELLS_TILT is not None:
            few &= self.normal_tilt(si) > float(self.CELLS_TILT)
        n = dr.maximum(n, dr.select(few & (dr.safe_sqrt(lx * lx + ly * ly) >= 2.0), float(self.CELLS), 1.0))
        v_probe = dr.select(along_a, u_probe_b, u_probe_a)
        if one_number:  # its remainder within the slice
            v_probe = u_probe * n - dr.floor(u_probe * n)
        m = dr.select(few & (dr.safe_sqrt(sx * sx + sy * sy) >= 2.0), float(self.CELLS), 1.0)
        offset = (dr.floor(u_probe * n) + 0.5) * dr.rcp(n) - 0.5
        offset_s = (dr.floor(v_probe * m) + 0.5) * dr.rcp(m) - 0.5
        within = None
        if known is not None:
            within = mi.Point2f(u_probe * n - dr.floor(u_probe * n), v_probe * m - dr.floor(v_probe * m))
            if tent:
                # Box x tent: the probe moves by a tent offset of up to a pixel along each
                # edge, from the sample's place in its cell (uniform and independent of
                # the cell: the probes stay stratified). The residual texels then take
                # the hash: placed by the same numbers, their place in the box would
                # depend on the box's.
                offset = offset + dr.select(known, mi.warp.interval_to_tent(within.x), 0.0)
                offset_s = offset_s + dr.select(known, mi.warp.interval_to_tent(within.y), 0.0)
                within = None
            else:
                within = dr.select(known, within, mi.Point2f(-1.0, -1.0))
        cx = fr.x + dr.select(finite, offset * lx + offset_s * sx, 0.0)
        cy = fr.y + dr.select(finite, offset * ly + offset_s * sy, 0.0)
        sx, sy = sx * dr.rcp(m), sy * dr.rcp(m)
        # The probe: the box of the slice's own area and centre (:meth:`_part_box`).
        px, py = lx * dr.rcp(n), ly * dr.rcp(n)
        rx, ry = self._part_box(px, py, sx, sy, finite)
        box = (cx - rx, cy - ry, cx + rx, cy + ry)
        boxes, split = [box], False
        parts = self.sub_probes()
        if parts > 1:
            # A turned slice filling little of its bounding box is shaded as the boxes of
            # its parts, cut as the footprint is (along edge l): the probes then follow
            # the region of parts x n slices, at one sample per slice.
            slice_area = dr.abs(px * sy - py * sx)
            fit = slice_area * dr.rcp(dr.maximum((dr.abs(px) + dr.abs(sx)) * (dr.abs(py) + dr.abs(sy)), 1e-30))
            below = self.SPLIT_BELOW_FIT
            if self.SPLIT_BELOW_FIT_LARGE is not None:
                slice_texels, wider = self.SPLIT_BELOW_FIT_LARGE
                below = dr.select(slice_area >= slice_texels, wider, below)
            split = finite & (fit < below)
            prx, pry = self._part_box(px * (1.0 / parts), py * (1.0 / parts), sx, sy, finite)
            boxes = []
            for j in range(parts):
                t = (j + 0.5) / parts - 0.5
                pcx, pcy = cx + t * px, cy + t * py
                part = (pcx - prx, pcy - pry, pcx + prx, pcy + pry)
                whole = box if j == 0 else (cx, cy, cx, cy)
                boxes.append(tuple(dr.select(split, a, b) for a, b in zip(part, whole)))
        # The point branch's parallelogram (zero where not finite: the texel at si.uv).
        edges = tuple(dr.select(finite, e, 0.0) for e in (ax, ay, bx, by))
        return Footprint(use=use, box=box, edges=edges, boxes=boxes, split=split, within=within,
                         point_xi=point_xi, point_known=known)

    @staticmethod
    def _footprint_share(texels, point_texels: float, footprint_texels: float):
        """The share of samples shading a footprint of ``texels`` whole: 0 under
        ``point_texels``, 1 over ``footprint_texels``, linear between (a step at
        ``point_texels`` where they are equal: experiments)."""
        span = footprint_texels - point_texels
        if span > 0.0:
            return dr.clip((texels - point_texels) * (1.0 / span), 0.0, 1.0)
        return dr.select(texels >= point_texels, 1.0, 0.0)

    @staticmethod
    def normal_tilt(si):
        """How far (radians, for small turns) the shading normal turns across the pixel
        footprint: the larger of |dn/duv si.duv_dx| and |dn/duv si.duv_dy|. Zero where
        si.dn_du, si.dn_dv were not computed (``clothpath`` asks for them: RayFlags.dNSdUV,
        which RayFlags.All leaves out; per UV on meshes too:
        :func:`.integrators.footprint.uv_normal_derivatives`) and on flat shapes."""
        if dr.width(si.dn_du) == 0 or dr.width(si.dn_dv) == 0:  # (a default-constructed si)
            return mi.Float(0.0)
        ta = si.dn_du * si.duv_dx.x + si.dn_dv * si.duv_dx.y
        tb = si.dn_du * si.duv_dy.x + si.dn_dv * si.duv_dy.y
        tilt = dr.maximum(dr.norm(ta), dr.norm(tb))
        return dr.select(dr.isfinite(tilt), tilt, 0.0)

    @staticmethod
    def _part_box(px, py, sx, sy, finite):
        """(rx, ry): the half sides of the box of the parallelogram (edges p, s)'s own area
        and centre, its sides in the ratio of the parallelogram's extents (square roots of
        its covariance's diagonal), at least a texel wide. Where the ends are slanted the
        box cuts into it as far as it reaches beyond, so the pixel's edges blur over a
        fraction of a slice instead of the bounding box's overhang adding texels from
        outside the pixel: 2-10% of bias at 12^2 texels sheared
        (bench/footprint_bias_scan.py, docs/performance-log.md L15)."""
        var_x = px * px + sx * sx
        var_y = py * py + sy * sy
        area = dr.abs(px * sy - py * sx)
        aspect = dr.sqrt(dr.sqrt(var_x * dr.rcp(dr.maximum(var_y, 1e-30))))
        area_ok = (area > 1e-6) & (var_x > 0.0) & (var_y > 0.0)
        rx_fit = 0.5 * dr.sqrt(area) * aspect
        ry_fit = 0.25 * area * dr.rcp(dr.maximum(rx_fit, 1e-30))
        rx = dr.select(area_ok, rx_fit, 0.5 * (dr.abs(px) + dr.abs(sx)))
        ry = dr.select(area_ok, ry_fit, 0.5 * (dr.abs(py) + dr.abs(sy)))
        rx = dr.select(finite, dr.maximum(rx, 0.5), 0.5)
        ry = dr.select(finite, dr.maximum(ry, 0.5), 0.5)
        return rx, ry

    def point_in_footprint(self, fr: ViewFrame, fp: Footprint, xi):
        """Texel coordinates of the point ``xi`` (uniform in [0,1)^2) of the footprint's
        parallelogram, where the fibre-level branch shades."""
        ax, ay, bx, by = fp.edges
        return (fr.x + (xi.x - 0.5) * ax + (xi.y - 0.5) * bx,
                fr.y + (xi.x - 0.5) * ay + (xi.y - 0.5) * by)

    def shaded_boxes(self, fp: Footprint, xi_round, exact: bool = False):
        """The footprint's probe boxes as they are shaded, and their SAT query (a
        :class:`.sat_queries.RectUnion` where the probe has parts): ``exact``, the boxes
        themselves (bilinear corners, four reads each); else with their corners rounded
        stochastically to whole texels by ``xi_round`` (one read each; the same mean in
        expectation, with the rounding's noise)."""
        sats = self.fibre.footprint_data.scalar_sats
        if exact:
            boxes = list(fp.boxes)
            queries = [sats.query(*b) for b in boxes]
        else:
            boxes = [round_box(*b, xi_round.x, xi_round.y) for b in fp.boxes]
            queries = [sats.query_on_grid(*b) for b in boxes]
        return boxes, queries[0] if len(queries) == 1 else RectUnion(queries, fp.split)

    # ------------------------------------------------------------------
    # The footprint's state: SAT means, residual texels, sampling mixture
    # ------------------------------------------------------------------
    def state(self, si, fr: ViewFrame, enabled, xi=None, xi_round=None, u_probe=None, fp: Footprint | None = None,
              grid: int | None = None, exact: bool | None = None) -> FootprintState:
        """Everything of the footprint that does not depend on the outgoing direction,
        computed once per shading point and shared by eval, pdf and sample: the SAT
        means over the footprint, the control-variate residual texel, the viewer-side
        visibilities and the sampling mixture.

        ``xi`` (2D in [0,1)) places the residual texels, ``xi_round`` rounds the SATs'
        corners and ``u_probe`` picks the probe along the footprint (:meth:`footprint`);
        by default all three are a hash of (si.uv, si.p), so eval is a deterministic
        function of (si, wo). ``fp``: the footprint :meth:`footprint` gave for these
        numbers, if the caller has it already. ``grid``: G of the G x G residual texels
        (default :meth:`residual_grid`; :meth:`large_probe_grid` for large probes).
        ``exact``: read the SATs at the boxes' exact corners rather than rounded ones
        (default :meth:`exact_corners`; large probes keep the rounding)."""
        fibre = self.fibre
        fd = fibre.footprint_data
        sats = fd.scalar_sats
        uniform_albedo = fibre.tile.uniform_yarn_colour
        if xi is None or fp is None:
            hashed = self.shading_hash(si)
            if xi is None:
                xi, xi_round = hashed[:2]
            if fp is None:
                fp = self.footprint(si, fr, hashed[2], u_probe)
        xi_round = mi.Point2f(0.5, 0.5) if xi_round is None else xi_round
        if self.STRATIFY and fp.within is not None:
            known = fp.within.x >= 0.0
            xi = dr.select(known, fp.within, xi)
        # Every mean is the exact mean over the boxes shaded: the exact ones (four reads
        # per corner and channel), or the boxes with their corners rounded stochastically
        # to whole texels (expected extent: the footprint's; one read, with the rounding's
        # noise). Rounded integrals normalised by the exact area instead were unbiased
        # but not bounded: at 2-4 texels
        # the yarn coverage of a gap-free footprint read 0.54-1.62, so the gap lobe let
        # light through where there are no gaps (its negative values cannot be sampled)
        # and lobe probabilities reached -39 and +40 (docs/performance-log.md L10).
        boxes, q = self.shaded_boxes(fp, xi_round, self.exact_corners() if exact is None else exact)
        inv_area = dr.rcp(q.area)

        # Every channel at once (gap, moments, cluster histogram, albedo): packets of four
        # neighbouring channels per corner read. Uniformly coloured yarns stop before the
        # albedo channels (4 packets instead of 5 with 8 clusters).
        needed = sats.channels if uniform_albedo is None else -(-fd.ALBEDO // 4) * 4
        means = [value * inv_area for value in sats.integrals(q, 0, needed)]

        def mean(channel):
            return means[channel]

        st = FootprintState(fp=fp, q=q, inv_area=inv_area)
        # Clipped: float cancellation between the SAT corners leaves ~1e-9 either side,
        # and a negative coverage made a lobe probability negative, the defensive share's
        # root below NaN, and so the pdf (performance log L28).
        st.yarn_mean = yarn_mean = dr.clip(mean(fd.GAP), 0.0, 1.0)
        inv_yarn = dr.select(yarn_mean > 1e-6, dr.rcp(yarn_mean), 0.0)
        if uniform_albedo is not None:
            st.yarn_albedo = uniform_albedo
        else:
            st.yarn_albedo = mi.Color3f(*[mean(fd.ALBEDO + c) * inv_yarn for c in range(3)])
        if enabled[SPECULAR_REFLECTION] or enabled[SPECULAR_TRANSMISSION]:
            # The footprint's mean SGGX matrix over its yarn texels:
            # S = I - (1 - alpha^2) <t t^T>, from the mean of t t^T.
            m = [mean(fd.MOMENTS + j) * inv_yarn for j in range(6)]
            sgn = fr.sign
            st.moments = (m[0], m[1], sgn * m[2], m[3], sgn * m[4], m[5])

        # The texels of the control-variate residual, one uniform in each cell of a grid
        # over the footprint (stratified: 1/n of the variance of one texel or less).
        st.texels = texels = self._stratified_texels(fr, boxes, xi, grid or self.residual_grid())
        if fibre.use_visibility:
            st.cvis_i = cvis_i = fd.cluster_visibilities(fr.wi, fr.flip)
            bins_i = fd.visibility_bins(fr.wi)  # once, not once per texel
            for t_ in texels:
                t_.cluster = fd.cluster_of(t_.ix, t_.iy)
                t_.vis = fd.texel_visibility(t_.ix, t_.iy)
                t_.v_i = fd.visibility_in_bins(t_.vis, bins_i, fr.flip)
                t_.cvis_i = pick(cvis_i, t_.cluster)
            # The footprint's share of each cluster's yarn (diffuse lobes, specular base).
            st.fractions = [mean(fd.CLUSTERS + c) for c in range(fd.clusters)]

        # The sampling mixture: lobes chosen by the footprint's own averages (yarn
        # coverage, yarn colour, mean SGGX matrix), the specular lobe from the tangent
        # of one of the residual texels, and a defensive cosine component.
        k = fr.k.with_yarn_albedo(st.yarn_albedo)
        scattered = mi.Float(0.0)
        if st.moments is not None:
            sigma_i = sggx.mean_sigma(st.moments, fr.wi, fibre.params.roughness)
            scattered = 1.0 - spongecake.unscattered_transmittance_from(sigma_i, fr.wi, fibre.params.thickness)
        st.probs = lobe_weights(k, fr.wi, yarn_mean, fr.t_sheen_i, scattered, enabled, self.calibration)
        # Scaled by the square root of the yarn lobes' share: it guards them (the residual
        # texels' tangents may miss some of the footprint's), and the sheen, sampled from
        # its own table, needs no guard. A fixed share spent a tenth of the samples at
        # grazing angles, where the sheen is almost all (weight variance at 88 degrees:
        # 0.029 -> 0.001); the root keeps a little more at middle angles, where the cosine
        # still helps the transmitted flake lobe (docs/performance-log.md L1).
        probs = st.probs
        yarn_share = probs[SPECULAR_REFLECTION] + probs[DIFFUSE_REFLECTION] + probs[DIFFUSE_TRANSMISSION]
        st.eps_c = eps_c = self.DEFENSIVE_COSINE * dr.sqrt(yarn_share)
        # Its lower (transmission) share follows the diffuse lobes' split, at least a
        # tenth on either side: at grazing angles a fixed half wasted 5% of samples.
        p_dr, p_dt = probs[DIFFUSE_REFLECTION], probs[DIFFUSE_TRANSMISSION]
        diffuse = p_dr + p_dt
        lower = dr.select(diffuse > 0.0, p_dt / dr.select(diffuse > 0.0, diffuse, 1.0), 0.5)
        st.eps_lower = eps_c * dr.clip(lower, self.DEFENSIVE_MIN_SIDE, 1.0 - self.DEFENSIVE_MIN_SIDE)
        return st

    def _by_roughness(self, fixed, rule, otherwise):
        """``fixed`` if set, else the value of the first (below, value) of ``rule`` whose
        bound exceeds the fibres' roughness, else ``otherwise``."""
        if fixed is not None:
            return fixed
        for below, value in rule:
            if self.roughness < below:
                return value
        return otherwise

    def residual_grid(self) -> int:
        """G: the residual texels are G x G (RESIDUAL_GRIDS, or RESIDUAL_GRID if set)."""
        return int(self._by_roughness(self.RESIDUAL_GRID, self.RESIDUAL_GRIDS, 2))

    def large_probe_grid(self) -> tuple[float, int] | None:
        """(texels, G): probes of at least that many texels take G x G residual texels
        (LARGE_PROBE_GRIDS, or LARGE_PROBE_TEXELS and LARGE_PROBE_GRID if set); None: the
        same grid for every probe."""
        fixed = None if self.LARGE_PROBE_TEXELS is None else (self.LARGE_PROBE_TEXELS, self.LARGE_PROBE_GRID)
        rule = tuple((below, (texels, g)) for below, texels, g in self.LARGE_PROBE_GRIDS)
        found = self._by_roughness(fixed, rule, None)
        return None if found is None else (float(found[0]), int(found[1]))

    def blend_texels(self) -> tuple[float, float]:
        """(point, footprint): footprints under the first many texels are shaded fibre
        level, over the second whole, blended between (BLEND_TEXELS_BY_ROUGHNESS, else
        POINT_TEXELS and FOOTPRINT_TEXELS)."""
        rule = tuple((below, (point, whole)) for below, point, whole in self.BLEND_TEXELS_BY_ROUGHNESS)
        point, whole = self._by_roughness(None, rule, (self.POINT_TEXELS, self.FOOTPRINT_TEXELS))
        return float(point), float(whole)

    def sample_at_texel(self) -> bool:
        """Whether the sampled direction is weighed at the texel that lent its tangent
        (SAMPLE_AT_TEXEL_BY_ROUGHNESS, or SAMPLE_AT_TEXEL if set)."""
        return bool(self._by_roughness(self.SAMPLE_AT_TEXEL, self.SAMPLE_AT_TEXEL_BY_ROUGHNESS, False))

    def covered_texels(self) -> int:
        """Probes covering at most this many texels are shaded texel by texel
        (COVERED_TEXELS_BY_ROUGHNESS, or COVERED_TEXELS if set); 0: none."""
        return int(self._by_roughness(self.COVERED_TEXELS, self.COVERED_TEXELS_BY_ROUGHNESS, 0))

    def emitter_covered_texels(self) -> int:
        """Probes covering at most this many texels are shaded texel by texel at the
        emitters' directions (EMITTER_COVERED_TEXELS_BY_ROUGHNESS, or
        EMITTER_COVERED_TEXELS if set); 0: none."""
        return int(self._by_roughness(self.EMITTER_COVERED_TEXELS, self.EMITTER_COVERED_TEXELS_BY_ROUGHNESS, 0))

    def exact_corners(self) -> bool:
        """Whether probes other than large ones read their SAT corners exactly
        (EXACT_CORNERS_BY_ROUGHNESS, or EXACT_CORNERS if set)."""
        return bool(self._by_roughness(self.EXACT_CORNERS, self.EXACT_CORNERS_BY_ROUGHNESS, False))

    def sub_probes(self) -> int:
        """Parts per probe (SUB_PROBES_BY_ROUGHNESS, or SUB_PROBES if set)."""
        return int(self._by_roughness(self.SUB_PROBES, self.SUB_PROBES_BY_ROUGHNESS, 1))

    def cells_below(self) -> float:
        """Slices under which a footprint gets CELLS cells across (CELLS_BELOW_BY_ROUGHNESS,
        or CELLS_BELOW if set)."""
        return float(self._by_roughness(self.CELLS_BELOW, self.CELLS_BELOW_BY_ROUGHNESS, float("inf")))

    @staticmethod
    def _strata(g):
        """(cell x, cell y, offset x, offset y) of each residual texel: the offsets of
        their shared random numbers form a rotated lattice (2x2: the quarter steps), so
        each texel stays uniform in its cell and together they spread further."""
        if g == 2:
            return ((0.0, 0.0, 0.0, 0.0), (1.0, 0.0, 0.5, 0.25), (0.0, 1.0, 0.25, 0.75), (1.0, 1.0, 0.75, 0.5))
        n = g * g
        return tuple((float(k % g), float(k // g), ((k * 7) % n) / n, ((k * 5) % n + 0.5) / n) for k in range(n))

    def _stratified_texels(self, fr: ViewFrame, boxes, xi, g: int) -> list[Texel]:
        """The residual texels, one uniform in each cell of a grid over the shaded boxes
        the SAT means cover (from ``xi``); the grid's first axis runs through the boxes
        one after the other, each its share of the total area, so that the texels are
        uniform over them as the means weigh them."""
        fibre = self.fibre
        areas, total = box_areas(boxes)
        texels = []
        for qx, qy, cx, cy in self._strata(g):
            sx = xi.x + cx
            sy = xi.y + cy
            u = (qx + sx - dr.floor(sx)) * (1.0 / g)  # in [0, 1)
            v = (qy + sy - dr.floor(sy)) * (1.0 / g)
            x0, y0, x1, y1 = boxes[0]
            if len(boxes) > 1:  # the box the area fraction u falls in, u rescaled within it
                t = u * total
                start = areas[0]
                u = t * dr.rcp(dr.maximum(areas[0], 1e-30))
                for b, a in zip(boxes[1:], areas[1:]):
                    take = (t >= start) & (a > 0.0)
                    u = dr.select(take, (t - start) * dr.rcp(dr.maximum(a, 1e-30)), u)
                    x0, y0, x1, y1 = (dr.select(take, p, q) for p, q in zip(b, (x0, y0, x1, y1)))
                    start = start + a  # not +=: that would change areas[0] in place
                u = dr.clip(u, 0.0, 0.99999994)
            texels.append(fibre.texel(fr, x0 + u * (x1 - x0), y0 + v * (y1 - y0)))
        return texels

    # ------------------------------------------------------------------
    # The footprint BSDF: eval, pdf, sample (mirrored frame)
    # ------------------------------------------------------------------
    def eval(self, fr: ViewFrame, st: FootprintState, wo, enabled):
        """Footprint-averaged non-delta f*|cos o| (Eq. 9-14 with CCV), mirrored frame."""
        return self.eval_pdf(fr, st, wo, enabled, unrolled=True)[0]

    def eval_pdf(self, fr: ViewFrame, st: FootprintState, wo, enabled, unrolled=False):
        """(:meth:`eval`, the density of the footprint mixture's non-delta directions) at
        ``wo`` (mirrored frame), their residual texels' terms in one pass
        (:meth:`_texel_sums`: a symbolic loop unless ``unrolled``)."""
        fibre = self.fibre
        fd = fibre.footprint_data
        roughness, thickness = fibre.params.roughness, fibre.params.thickness
        wi = fr.wi
        k = fr.k
        texels = st.texels
        n = len(texels)
        cos_o = wo.z
        up = cos_o > 0.0
        valid = spongecake.directions_valid(wi, wo)
        yarn_albedo = st.yarn_albedo
        specular = enabled[SPECULAR_REFLECTION] or enabled[SPECULAR_TRANSMISSION]
        diffuse = enabled[DIFFUSE_REFLECTION] or enabled[DIFFUSE_TRANSMISSION]
        samplers = fibre.samplers
        fold = samplers.fold_share(k, enabled)

        vbar_p = v_p = None
        if fibre.use_visibility:
            # Each residual texel's cluster's mean v_c(i) v_c(o).
            cvis_o = fibre.cluster_visibilities_o(fr, wo)
            vbar_p = [t_.cvis_i * pick(cvis_o, t_.cluster) for t_ in texels]
            # Each texel's own V(p, i) V(p, o), before the texels' loop: the direction's
            # bins once, and the loop picks one value instead of five words.
            wo_up, back_o = fibre.outgoing_side(fr.flip, wo)
            bins_o = fd.visibility_bins(wo_up)
            v_p = [t_.v_i * fd.visibility_in_bins(t_.vis, bins_o, back_o) for t_ in texels]
        if specular:
            h, h2, half, folded2 = self._half_vectors(wi, wo)
            # The tables hold D of the maps' own tangents; the mirrored frame flips their
            # z, so a viewer below looks up the mirror image of h (then folded up again).
            h_table = mi.Vector3f(h.x, h.y, fr.sign * h.z)
            h_table = dr.select(h_table.z < 0.0, -h_table, h_table)
            # The three bins around h with their barycentric weights, deterministically: a
            # random pick of one bin was most of the estimator's own noise on shiny cloth
            # near and in the middle distance (docs/performance-log.md L15); three instead
            # of the bilinear four, the same noise for 6% less time (L52).
            bins, weights = hemisphere_triangle_bins(h_table, fd.dr)
            centres = fd.bin_centres_of(bins)
            d_yarn = fd.d_integral(st.q, bins, weights) * st.inv_area  # mean over P of D I
            # What every texel shares, computed once outside their loop: the squared
            # lengths of the directions (the half vectors' above).
            wi2, wo2 = dr.dot(wi, wi), dr.dot(wo, wo)
            centre_norms = [dr.squared_norm(c) for c in centres]

            # f_rs per unit D: G of the footprint's mean SGGX matrix (g_bar), and of each
            # residual texel's own tangent (g_k). The residual corrects mean(D) g_bar
            # towards mean(D g), which differ where D and the tangent correlate (grazing
            # highlights: 10-17% low without it).
            dirs = spongecake.SpecularDirections.of(wi, wo)  # once for every texel

            def g_of(sigma_i, sigma_o):
                return spongecake.eval_specular_at(1.0, sigma_i, sigma_o, dirs, thickness)

            g_bar = g_of(sggx.mean_sigma(st.moments, wi, roughness), sggx.mean_sigma(st.moments, wo, roughness))
            # The base (mean D over the footprint times a visibility) and the visibility
            # w_bar of the residual's control variate, where it is not each texel's v_bar.
            w_bar = None
            if fibre.use_visibility:
                # Alg. 4's visibility: the mean v_c of the residual texels' clusters.
                texel_mean = sum(vbar_p) * (1.0 / n)
                if fd.per_cluster:
                    base = mi.Float(0.0)
                    for c in range(fd.clusters):
                        base += st.cvis_i[c] * cvis_o[c] * fd.d_integral(st.q, bins, weights, c)
                    base *= st.inv_area
                elif fd.d_cluster_tile is not None:
                    # Each cluster's visibility weighted by its share of the footprint's D:
                    # its share of the footprint times its mean D over the tile. Exact for
                    # footprints of whole tiles; Alg. 4's texel_mean (the fallback) is off
                    # by -Cov(D, v) at every size (docs/performance-log.md L3).
                    m_c = fd.cluster_d_means(bins, weights)
                    num = mi.Float(0.0)
                    den = mi.Float(0.0)
                    for c in range(fd.clusters):
                        w_c = st.fractions[c] * m_c[c]
                        num += w_c * st.cvis_i[c] * cvis_o[c]
                        den += w_c
                    w_bar_d = dr.select(den > 0.0, num / dr.select(den > 0.0, den, 1.0), texel_mean)
                    base = d_yarn * w_bar_d
                    if self.CONSISTENT_VISIBILITY_CV:
                        # Below a tile the residual's control variate takes the base's own
                        # visibility, so base + residual is unbiased at every size; each
                        # texel's cluster visibility left it 2-57% off there. Over whole
                        # tiles the base is exact for that one, whose residual varies far
                        # less (a 384^2 footprint's variance ratio 0.06 against 0.41)
                        # (bench/footprint_bias_scan.py, docs/performance-log.md L15).
                        whole_tiles = True
                        for x0, y0, x1, y1 in st.fp.boxes:  # empty parts aside
                            whole_tiles &= ((x1 - x0 >= fibre.tile.width.f) & (y1 - y0 >= fibre.tile.height.f)
                                            | (x1 <= x0))
                        w_bar = (whole_tiles, w_bar_d)
                else:
                    base = d_yarn * texel_mean
            else:
                base = d_yarn

        # Where the yarns' colours differ (denim's indigo warp and ecru weft), the colour
        # correlates with D and visibility: the footprint's mean colour times the mean of
        # the rest was biased (denim, direct sun). The residual then carries each texel's
        # own colour against the mean colour times its control variate, whose mean is the
        # base times the mean colour: unbiased again.
        coloured = fibre.tile.uniform_yarn_colour is None
        colors = [t_.color for t_ in texels] if coloured else None

        def texel_terms(t_, vbar, v, color):
            """One residual texel's (specular residual, diffuse residual / n, specular pdf),
            given its cluster visibility ``vbar``, its own ``v`` (with visibility) and its
            yarn colour (where colours vary: the residuals then per channel, six Floats)."""
            residual = yarn_v = pdf_spec = mi.Float(0.0)
            if fibre.use_visibility:
                if diffuse:
                    if coloured:
                        yarn_v = t_.yarn * (color * v - yarn_albedo * vbar) * (1.0 / n)
                    else:
                        yarn_v = t_.yarn * (v - vbar) * (1.0 / n)
            if specular:
                t = t_.tangent
                d_h = sggx.ndf(h, t, roughness, h2)  # D is even: also the density's D(h)
                d = d_h * t_.yarn
                # The same texel's D as the tables bin it (its tangent in the tables'
                # frame): the control variate that removes the bins' bias from the base.
                d_bin = fd.binned_ndf(centres, weights, _table_tangent(fr, t), roughness, centre_norms) * t_.yarn
                sigma_i = sggx.projected_area(wi, t, roughness, wi2)
                g = g_of(sigma_i, sggx.projected_area(wo, t, roughness, wo2))
                if fibre.use_visibility:
                    vbar_spec = vbar if w_bar is None else dr.select(w_bar[0], vbar, w_bar[1])
                    own, control = d * v * g, d_bin * vbar_spec * g_bar
                else:
                    own, control = d * g, d_bin * g_bar
                residual = color * own - yarn_albedo * control if coloured else own - control
                pdf_spec = samplers.specular_pdf_from(half, wo, fold, d_h, sggx.ndf(half.folded, t, roughness, folded2),
                                                      sigma_i)
            if coloured:
                return (*_channels(residual), *_channels(yarn_v), pdf_spec)
            return residual, yarn_v, pdf_spec

        sums = self._texel_sums(texels, (vbar_p, v_p, colors), texel_terms, 7 if coloured else 3,
                                unrolled or not self.LOOP_TEXELS)
        if coloured:
            residual, yarn_v, pdf_spec = mi.Color3f(*sums[:3]), mi.Color3f(*sums[3:6]), sums[6]
        else:
            residual, yarn_v, pdf_spec = sums
        value, under_fuzz = fibre.sheen_and_fuzz(fr, wo, enabled)
        reflection = mi.Color3f(0.0)
        transmission = mi.Color3f(0.0)
        # The mean colour multiplies the whole estimate, or only the base and the control
        # variates where the residual carries each texel's own.
        tint = 1.0 if coloured else yarn_albedo
        if specular:
            # An unbiased control-variate estimate: it can dip below zero for the
            # residual texels (V(p) = 0 under a bright base); clamping it biased
            # grazing highlights by up to +90% (docs/performance-log.md L3), so we do not.
            spec = base * g_bar
            spec = (yarn_albedo * spec if coloured else spec) + residual * (1.0 / n)
            if enabled[SPECULAR_REFLECTION]:
                reflection += k.specular_albedo * tint * spec
            if enabled[SPECULAR_TRANSMISSION]:
                transmission += k.specular_transmittance * tint * spec
        if diffuse:
            if fibre.use_visibility:
                # Eq. 14 through the cluster histogram, plus the same residual texels.
                cluster_visible = mi.Float(0.0)
                for c in range(fd.clusters):
                    cluster_visible += st.cvis_i[c] * cvis_o[c] * st.fractions[c]
                yarn_visible = yarn_v + (yarn_albedo * cluster_visible if coloured else cluster_visible)
            else:
                yarn_visible, tint = st.yarn_mean, yarn_albedo
            cosine = dr.abs(cos_o) * dr.inv_pi * yarn_visible
            if enabled[DIFFUSE_REFLECTION]:
                reflection += k.diffuse_albedo * tint * cosine
            if enabled[DIFFUSE_TRANSMISSION]:
                transmission += k.diffuse_transmittance * tint * cosine
        value += under_fuzz * dr.select(up, reflection, transmission)

        pdf = self._mixture_pdf(fr, st, wo, enabled, fold, pdf_spec * (1.0 / n))
        return dr.select(valid, value, 0.0), dr.select(valid, pdf, 0.0)

    def eval_pdf_covered(self, fr: ViewFrame, st: FootprintState, wo, enabled, unrolled=False):
        """(:meth:`eval`, :meth:`pdf`) at ``wo`` (mirrored frame) for a probe covering few
        texels (:meth:`covered_texels`): the BSDF the mean of the fibre-level BSDF over the
        probe's boxes, summed over every texel under them weighted by its area there (the
        mean that the SAT means and residual texels estimate, without their noise); the
        density the mixture's, as :meth:`eval_pdf`'s. Each texel's lobes as the fibre
        level's (:meth:`.FibreBSDF.eval_pdf`), its own colour included; the sheen and the
        fuzz over them once. A symbolic loop over the texels in JIT variants."""
        fibre = self.fibre
        fd = fibre.footprint_data
        roughness, thickness = fibre.params.roughness, fibre.params.thickness
        wi = fr.wi
        cos_o = wo.z
        up = cos_o > 0.0
        valid = spongecake.directions_valid(wi, wo)
        specular = enabled[SPECULAR_REFLECTION] or enabled[SPECULAR_TRANSMISSION]
        cosine = dr.abs(cos_o) * dr.inv_pi
        grids = st.fp.covered_grids()
        counts = [g.count for g in grids]
        total = sum(counts[1:], counts[0])
        inv_area = dr.rcp(dr.maximum(st.fp.probe_texels(), 1e-30))
        if specular:
            h, h2, _, _ = self._half_vectors(wi, wo)
            dirs = spongecake.SpecularDirections.of(wi, wo)
            wi2, wo2 = dr.dot(wi, wi), dr.dot(wo, wo)
        if fibre.use_visibility:
            bins_i = fd.visibility_bins(fr.wi)
            wo_up, back_o = fibre.outgoing_side(fr.flip, wo)
            bins_o = fd.visibility_bins(wo_up)

        def texel_lobes(k):
            """The ``k``-th covered texel's yarn lobes times its yarn, visibility and share."""
            grid, local, start = grids[0], k, counts[0]
            x, y, share = grid.texel(local)
            for g, c in zip(grids[1:], counts[1:]):
                later = k >= start
                gx, gy, g_share = g.texel(k - start)
                x, y, share = dr.select(later, gx, x), dr.select(later, gy, y), dr.select(later, g_share, share)
                start = start + c
            pt = fibre.read_visibility(fibre.texel(fr, x + 0.5, y + 0.5))
            weight = share * inv_area * pt.yarn
            if fibre.use_visibility:
                # V(p, i) V(p, o) as FibreBSDF.visibility, with the directions' bins read once.
                weight *= fd.visibility_in_bins(pt.vis, bins_i, fr.flip) * fd.visibility_in_bins(pt.vis, bins_o,
                                                                                               back_o)
            spec = None
            if specular:
                t = pt.tangent
                spec = spongecake.eval_specular_at(sggx.ndf(h, t, roughness, h2),
                                                   sggx.projected_area(wi, t, roughness, wi2),
                                                   sggx.projected_area(wo, t, roughness, wo2), dirs, thickness)
            return weight * fibre.yarn_lobes(pt.k, spec, cosine, up, enabled)

        if unrolled or not dr.is_jit_v(mi.Float):
            # One copy per texel up to the most any lane covers (which this reads back);
            # the BSDF's shading takes the SAT means where gradients flow instead
            # (:meth:`.ClothShading._footprint_branch`), so this is for direct callers.
            yarn_lobes = mi.Color3f(0.0)
            for k in range(int(dr.max(total)[0]) if dr.is_jit_v(mi.Float) else int(total)):
                yarn_lobes += dr.select(k < total, texel_lobes(mi.Float(k)), 0.0)
        else:
            def body(k, sums):
                return k + 1.0, sums + texel_lobes(k)

            lanes = dr.width((total, wo))
            _, yarn_lobes = dr.while_loop(state=(dr.zeros(mi.Float, lanes), dr.zeros(mi.Color3f, lanes)),
                                          cond=lambda k, sums: k < total, body=body, labels=("k", "sums"),
                                          label="cloth_covered_texels")
        value, under_fuzz = fibre.sheen_and_fuzz(fr, wo, enabled)
        value += under_fuzz * yarn_lobes
        return dr.select(valid, value, 0.0), self.pdf(fr, st, wo, enabled, unrolled)

    @staticmethod
    def _half_vectors(wi, wo):
        """(h folded up, |h|^2, the specular density's half vectors, |folded|^2) at (wi, wo):
        what eval_pdf's specular terms and :meth:`pdf` share, built one way for both."""
        h = dr.normalize(wi + wo)
        h = dr.select(h.z < 0.0, -h, h)  # D is even
        half = SpecularHalfVectors.of(wi, wo)
        return h, dr.squared_norm(h), half, dr.squared_norm(half.folded)

    @staticmethod
    def _with_defensive(st: FootprintState, wo, pdf):
        """A density of the footprint's lobes mixed with the defensive cosine (each side's
        share); validity not masked."""
        eps_c, eps_lower = st.eps_c, st.eps_lower
        eps_side = dr.select(wo.z > 0.0, eps_c - eps_lower, eps_lower)
        return (1.0 - eps_c) * pdf + eps_side * dr.abs(wo.z) * dr.inv_pi

    def _mixture_pdf(self, fr: ViewFrame, st: FootprintState, wo, enabled, fold, specular_mean):
        """The footprint mixture's density at ``wo`` given its specular lobe's
        (``specular_mean``: over the texels that may lend their tangent), with the
        defensive cosine; validity not masked."""
        pdf = self.fibre.samplers.pdf(self.fibre.params.roughness, fr.wi, wo, st.probs, None, enabled, fold,
                                      specular_mean=specular_mean)
        return self._with_defensive(st, wo, pdf)

    def pdf(self, fr: ViewFrame, st: FootprintState, wo, enabled, unrolled=False):
        """The density of :meth:`sample` at ``wo`` (mirrored frame) alone: :meth:`eval_pdf`'s
        without the BSDF's value, the specular lobe's over every residual texel (its
        tangent's visible flakes) and nothing read from the tables; ``unrolled`` as there."""
        fibre = self.fibre
        roughness = fibre.params.roughness
        wi = fr.wi
        valid = spongecake.directions_valid(wi, wo)
        fold = fibre.samplers.fold_share(fr.k, enabled)
        specular_mean = None
        texels = st.texels
        if enabled[SPECULAR_REFLECTION] or enabled[SPECULAR_TRANSMISSION]:
            h, h2, half, folded2 = self._half_vectors(wi, wo)
            wi2 = dr.dot(wi, wi)

            def texel_pdf(t_):
                t = t_.tangent
                return (fibre.samplers.specular_pdf_from(half, wo, fold, sggx.ndf(h, t, roughness, h2),
                                                         sggx.ndf(half.folded, t, roughness, folded2),
                                                         sggx.projected_area(wi, t, roughness, wi2)),)

            specular_mean = (self._texel_sums(texels, (), texel_pdf, 1, unrolled or not self.LOOP_TEXELS)[0]
                             * (1.0 / len(texels)))
        return dr.select(valid, self._mixture_pdf(fr, st, wo, enabled, fold, specular_mean), 0.0)

    @staticmethod
    def _texel_sums(texels: list[Texel], extras, terms, count: int, unrolled):
        """The sums over the residual texels of ``terms(texel, *its extras)`` (a tuple of
        ``count`` Floats; ``extras``: lists of a value per texel, or None each). In JIT
        variants a symbolic loop, so the traced code holds one copy of the per-texel work
        instead of one per texel (4x4 on shiny cloth; 3x3 in performance log L40); ``unrolled``
        (where gradients flow) one copy each. Both add in texel order."""
        n = len(texels)
        if unrolled or n < 2 or not dr.is_jit_v(mi.Float):
            sums = None
            for j, t_ in enumerate(texels):
                terms_t = terms(t_, *(None if e is None else e[j] for e in extras))
                sums = terms_t if sums is None else tuple(a + b for a, b in zip(sums, terms_t))
            return sums
        first = texels[0]
        lanes = dr.width((first.tangent, first.yarn, [e for e in extras if e is not None]))

        def texel_at(i):
            # Only what the terms read: the tangent and coverage, and the extras.
            tangent = pick([t_.tangent for t_ in texels], i)
            yarn = pick([t_.yarn for t_ in texels], i)
            texel = dataclasses.replace(first, tangent=tangent, yarn=yarn, vis=None, v_i=None)
            return (texel, *(None if e is None else pick(e, i) for e in extras))

        def body(i, sums):
            return i + 1, tuple(a + b for a, b in zip(sums, terms(*texel_at(i))))

        state = (dr.zeros(mi.UInt32, lanes), tuple(dr.zeros(mi.Float, lanes) for _ in range(count)))
        _, sums = dr.while_loop(state=state, cond=lambda i, sums: i < n, body=body, labels=("i", "sums"),
                                label="cloth_residual_texels")
        return sums

    def sample(self, fr: ViewFrame, st: FootprintState, enabled, sample1, sample2, active, at_texel=None):
        """A direction from the footprint mixture:
        (wo mirrored, ok, component, gap_ok, gap_pdf, gap_value, the texel that lent its
        tangent: where the sample is weighed at it, ``at_texel`` (default:
        :meth:`sample_at_texel`), uniform over the probe whichever component is sampled
        and read whole for :meth:`texel_eval_pdf`)."""
        texels, fp_probs, eps_c = st.texels, st.probs, st.eps_c
        # Split sample1: defensive cosine | the footprint's lobes; within the specular
        # share, which of the residual texels lends its tangent.
        pick_def_cos = sample1 < eps_c
        u = (sample1 - eps_c) / (1.0 - eps_c)
        if at_texel is None:
            at_texel = self.sample_at_texel()
        if at_texel:
            # sample1's place within the slot it falls in (a side of the defensive cosine,
            # or a lobe): uniform, and independent of the slot, so the texel it picks is
            # uniform over the probe whichever component is sampled.
            eps_lower = st.eps_lower
            lower = sample1 < eps_lower
            place = dr.select(lower, sample1 * dr.rcp(dr.maximum(eps_lower, 1e-30)),
                              (sample1 - eps_lower) * dr.rcp(dr.maximum(eps_c - eps_lower, 1e-30)))
            start = mi.Float(0.0)
            for lobe in (SHEEN, SPECULAR_REFLECTION, DIFFUSE_REFLECTION, DIFFUSE_TRANSMISSION, GAP):
                share = fp_probs[lobe]
                inside = logical_not(pick_def_cos) & (u >= start) & (share > 0.0)
                place = dr.select(inside, (u - start) / dr.select(share > 0.0, share, 1.0), place)
                start = start + share
        else:
            place = (u - fp_probs[SHEEN]) / dr.select(fp_probs[SPECULAR_REFLECTION] > 0.0,
                                                      fp_probs[SPECULAR_REFLECTION], 1.0)
        quad = mi.UInt32(dr.clip(dr.floor(place * len(texels)), 0, len(texels) - 1))
        if at_texel:
            # The texel read again whole (its colour and visibility bits too): a few
            # reads instead of picking every field among the residual texels.
            ix = pick([t_.ix for t_ in texels], quad)
            iy = pick([t_.iy for t_ in texels], quad)
            chosen = self.fibre.read_visibility(self.fibre.texel(fr, mi.Float(ix) + 0.5, mi.Float(iy) + 0.5))
        else:
            tangent = texels[0].tangent
            for q in range(1, len(texels)):
                tangent = dr.select(quad == q, texels[q].tangent, tangent)
            chosen = dataclasses.replace(texels[0], tangent=tangent)

        wo, ok, component, gap_ok = self.fibre.sample(chosen, fp_probs, enabled, u, sample2, active, len(texels))
        wo_cos = mi.warp.square_to_cosine_hemisphere(sample2)
        # The defensive cosine side: the lower or upper part of its sample1 slice.
        lower = sample1 < st.eps_lower
        wo_cos.z = dr.select(lower, -wo_cos.z, wo_cos.z)
        wo = dr.select(pick_def_cos, wo_cos, wo)
        viewer_ok = active & (fr.wi.z > spongecake.COS_EPSILON)
        ok = dr.select(pick_def_cos, viewer_ok, ok)
        component = dr.select(pick_def_cos, dr.select(lower, DIFFUSE_TRANSMISSION, DIFFUSE_REFLECTION),
                              component)
        gap_ok &= logical_not(pick_def_cos)
        gap_pdf = (1.0 - eps_c) * fp_probs[GAP]
        gap_value = self.fibre.gap_value(fr, st.yarn_mean)
        return wo, ok, component, gap_ok, gap_pdf, gap_value, chosen

    def texel_eval_pdf(self, fr: ViewFrame, st: FootprintState, pt: Texel, wo, enabled):
        """(f_k, p_k): the fibre-level BSDF of texel ``pt`` (what :meth:`sample` chose) at
        ``wo``, and the density of the footprint mixture given that texel (its specular
        lobe on the texel's tangent, with the defensive cosine)."""
        value, pdf = self.fibre.eval_pdf(pt, wo, enabled, st.probs)
        return value, dr.select(spongecake.directions_valid(fr.wi, wo), self._with_defensive(st, wo, pdf), 0.0)
