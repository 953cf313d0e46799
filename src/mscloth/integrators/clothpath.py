"""The ``clothpath`` integrator: Mitsuba's ``path`` plus a pixel footprint for every BSDF call.

Plugin classes bind to the Mitsuba variant active when they are defined, so
:func:`make_clothpath_class` builds one class per variant (see :mod:`mscloth.integrators`).
"""
from __future__ import annotations

import functools

from dataclasses import dataclass

import drjit as dr
import mitsuba as mi
import numpy as np

from ..errors import ParameterError
from ..lanes import logical_not
from ..pixel_filter import quadratic_bspline_quantile
from . import bsdf_contract as contract
from . import footprint as fp
from . import gap_shadows
from . import sky_share_pilot

DOCSTRING = r"""
Path tracer with pixel footprints (``clothpath``)
-------------------------------------------------

Mitsuba's ``path`` integrator (3.9.1: emitter sampling, BSDF sampling, power-heuristic MIS,
the same Russian roulette rule; with ``emitter_sampling=one`` the same order of random
numbers), which in addition hands
every BSDF call the pixel footprint of its shading point in ``si.duv_dx`` / ``si.duv_dy``
(Mitsuba's ``path`` drops ray differentials, so BSDFs see zeros there). On scenes whose BSDFs
ignore ``duv_dx`` / ``duv_dy`` it renders the same image as ``path`` (``emitter_sampling=one``)
or converges to it (``all``, the default, which has less noise where several emitters light
the scene).

* first hit: the camera's ray differentials, rescaled to the whole pixel (Mitsuba scales
  them by 1/sqrt(spp)), intersected with the tangent plane; BSDFs that shade whole
  footprints (``footprint_shading``: multi-scale ``cloth``) get the uv of the pixel centre
  (perspective and orthographic cameras), so a pixel is its footprint's average, and the
  camera sample's offset in its pixel (``pixel_offset`` of ``eval_pdf_sample_n``): the part
  of the footprint that the sample stands for. So do hits behind straight crossings of
  cloth gaps, which are still on the camera ray's line (seen through the pixel; shaded at
  the sample's own uv with a footprint centred there, a pixel averaged them over twice
  its width);
* later hits: a ray cone whose width grows with distance and whose spread grows at each
  non-delta bounce by 2/sqrt(pi pdf) (see :mod:`mscloth.integrators.footprint`);
* after a non-delta bounce (``scattered_footprints`` false, the default): a zero footprint,
  so BSDFs shade the hit point. The path's own random hit point then samples the cone's
  footprint, with the same expectation as shading it whole; the cone's filtering matters
  along mirror, glass and gap chains (delta bounces), which keep it. Shadow rays cross
  cloth with the footprint of their vertex: the ray cone continued from the first hit and
  along delta chains, a point after a rough bounce.

Footprint convention: the footprint of a shading point is the UV parallelogram centred on
``si.uv`` spanned by ``si.duv_dx`` and ``si.duv_dy`` (its bounding rectangle has half-widths
1/2 (|du/dx| + |du/dy|) and 1/2 (|dv/dx| + |dv/dy|)).

.. list-table::
   :header-rows: 1

   * - Parameter
     - Type
     - Default
     - Meaning
   * - max_depth
     - integer
     - -1
     - Longest path depth (-1: infinite; 1: only directly visible emitters; 2: direct
       illumination only, ...), as in ``path``.
   * - rr_depth
     - integer
     - 5
     - Depth at which Russian roulette starts, > 0.
   * - hide_emitters
     - boolean
     - false
     - Hide directly visible emitters.
   * - emitter_sampling
     - string
     - ``all``
     - ``all``: sample every emitter once at each vertex (MIS with BSDF sampling per
       emitter), so a sun and a sky never compete for one sample, except a uniform
       environment (``constant``), which BSDF sampling alone reaches with less noise;
       ``one``: pick one emitter per vertex as Mitsuba's ``path`` does (same image with
       the same seed).
   * - scattered_footprints
     - boolean
     - false
     - Hand BSDFs ray-cone footprints after non-delta bounces too. Off, a hit after a
       rough bounce is shaded at its point (footprint zero): it costs a multi-scale
       ``cloth`` a fibre-level evaluation instead of a footprint one (``sphere`` scene:
       about half the render time) at the same per-pixel noise, since such a path's light
       is already spread over the cone by the bounce (``docs/decisions.md``).
   * - uv_filter
     - string
     - ``box``
     - The filter over the first hit's uv and those behind gap crossings (textures and
       cloth; geometry stays box filtered by the film's ``box``). ``box``: each pixel is
       the average over its own footprint, which beats with weaves of about a pixel's
       period into moiré (rings, fringes), in brute force as in multi-scale shading.
       ``tent``: a pixel is the footprint average under box ⊗ tent, a quadratic B-spline
       as soft as Mitsuba's default ``gaussian`` (its response at 1.3 cycles per pixel,
       where the box keeps 20%, is under 1%): each camera sample shades the point at the
       B-spline's quantile of its place in the pixel, and a footprint-shading BSDF moves
       its probe by a tent offset of up to a pixel in the pixel's uv frame. Two more
       sampler dimensions per vertex (used at the first hit where a sample's place in its
       pixel is not known).
   * - emitter_samples
     - integer
     - 1
     - Emitter samples per vertex (per emitter with ``all``; delta emitters such as a sun
       take one, since more would repeat it). MIS weighs them against the one BSDF sample
       with their count (Veach's multi-sample power heuristic). More samples cut the
       lighting noise of an environment at the cost of shadow rays and BSDF evaluations,
       which footprint BSDFs share per shading point; the texture noise of a fibre-level
       BSDF needs pixel samples instead.
   * - sky_share
     - float
     - auto: a pilot's, from 2^19 samples per pass, else 0
     - The share c of a uniform environment's light (``constant``, left to BSDF
       sampling by ``emitter_sampling`` ``all``) that camera rays' first hits on BSDFs
       that know their sample weight's expectation (multi-scale ``cloth``: a table of
       each texel's albedo, built on the first render that uses it, a few seconds per
       cloth) take whole: c L A(wi), Monte Carlo carrying only what the sampled
       directions bring beyond c L. 0: off; 1 suits open cloth under the sky, less cloth
       whose directions see other surfaces (docs/performance-log.md L60). Not given:
       the share that leaves the least noise in the scene, measured by a pilot render
       (8192 pixels of the frame, three times at the render's sample count, on small
       tables; the full ones are built only for a share), or 0 where it would cut the
       variance by less than the table's reads cost
       (:mod:`mscloth.integrators.sky_share_pilot`; stored in the table cache, so a
       scene rendered again runs none); off for renders of fewer samples per pass
       (pixels x spp), which the table's build would outlast.
   * - gap_shadows
     - boolean
     - true
     - Shadow rays cross cloth through its gaps, as through a null interface
       (:mod:`mscloth.integrators.gap_shadows`): the only way the light of a delta
       emitter (a sun, a point light) reaches what lies behind cloth, and for other
       emitters MIS-weighted against BSDF paths through the gaps, whose gap crossings
       leave the MIS state of the vertex before them as it was. Off, cloth blocks shadow
       rays like any surface: faster where many shadow rays meet cloth (the demo scene: a
       crossing every other sample; ``make bench`` measures it), but the sunlight through
       the weave, on the floor under a sheet or inside a cloth-covered object, is lost,
       and area lights and skies behind cloth are reached by BSDF sampling alone (the same
       image, with fireflies under sheer cloth).

AOVs ``footprint_u`` and ``footprint_v``: the footprint half-widths in UV at the first hit
(0 where the camera ray escapes), e.g. ``footprint_u`` = 1/(2N) for a UV square seen
head-on across N pixels; ``footprint_texels_u``, ``footprint_texels_v``: the footprint's full
widths in texels of the BSDF's pattern tile (BSDFs with ``footprint_texels``, i.e. ``cloth``;
0 elsewhere).
"""


_UINT32_MAX = 0xFFFFFFFF
#: Values of ``uv_filter``, and its default.
UV_FILTERS = ("box", "tent")
DEFAULT_UV_FILTER = "box"
#: AOVs of ``footprint_aovs``: UV half-widths, and full widths in texels of the BSDF's tile.
AOV_NAMES = ("footprint_u", "footprint_v", "footprint_texels_u", "footprint_texels_v")


def _read_properties(props):
    max_depth = props.get("max_depth", -1)
    if not isinstance(max_depth, int) or (max_depth < 0 and max_depth != -1):
        raise ParameterError('clothpath: "max_depth" must be -1 (infinite) or an integer >= 0, '
                             f"got {max_depth!r}")
    rr_depth = props.get("rr_depth", 5)
    if not isinstance(rr_depth, int) or rr_depth <= 0:
        raise ParameterError(f'clothpath: "rr_depth" must be an integer > 0, got {rr_depth!r}')
    emitter_sampling = props.get("emitter_sampling", "all")
    if emitter_sampling not in ("all", "one"):
        raise ParameterError('clothpath: "emitter_sampling" must be "all" or "one", '
                             f"got {emitter_sampling!r}")
    uv_filter = props.get("uv_filter", DEFAULT_UV_FILTER)
    if uv_filter not in UV_FILTERS:
        raise ParameterError(f'clothpath: "uv_filter" must be "box" or "tent", got {uv_filter!r}')
    emitter_samples = props.get("emitter_samples", 1)
    if not isinstance(emitter_samples, int) or not 1 <= emitter_samples <= 256:
        raise ParameterError('clothpath: "emitter_samples" must be an integer in [1, 256], '
                             f"got {emitter_samples!r}")
    return ((_UINT32_MAX if max_depth == -1 else max_depth), rr_depth, emitter_sampling,
            emitter_samples, uv_filter)


def _read_flag(props, name):
    value = props.get(name, _FLAGS[name])
    if not isinstance(value, bool):
        raise ParameterError(f'clothpath: "{name}" must be a boolean, got {value!r}')
    return value


#: Boolean properties and their defaults (``footprint_aovs`` off: an RGB image from
#: mi.render, as with Mitsuba's ``path``).
_FLAGS = {"footprint_aovs": False, "scattered_footprints": False, "gap_shadows": True}


@dataclass
class PathState:
    """The state of one path between two iterations of ``clothpath``'s loop (with the
    sampler, the loop's state). A dataclass is a Dr.Jit PyTree: ``dr.while_loop`` carries
    its fields, in JIT variants as symbolic loop variables, in scalar ones as Python values."""

    #: The ray to trace next, without its time and wavelengths, which the loop leaves as
    #: they are: such state makes Dr.Jit trace the whole body twice to drop it
    #: (:meth:`ray`; performance log L51).
    ray_o: mi.Point3f
    ray_d: mi.Vector3f
    ray_maxt: mi.Float
    pi: mi.PreliminaryIntersection3f  #: its intersection, found at the end of the last iteration
    throughput: mi.Spectrum
    result: mi.Spectrum
    eta: mi.Float                  #: product of the relative IORs crossed (Russian roulette)
    depth: mi.UInt32
    valid_ray: mi.Bool             #: the path saw something (else the pixel's alpha is 0)
    prev_si: mi.Interaction3f      #: the last scattering vertex before any gap crossings (MIS)
    prev_bsdf_pdf: mi.Float        #: its BSDF sample's pdf
    prev_bsdf_delta: mi.Bool       #: its BSDF sample was a delta lobe
    active: mi.Bool
    cone_width: mi.Float           #: ray-cone width at the previous vertex
    cone_spread: mi.Float          #: ray-cone spread angle
    aovs: tuple                    #: the ``AOV_NAMES`` values (recorded at the first hit)
    sky_term: tuple                #: the pilot's (:mod:`.sky_share_pilot`): the control variate's term at c = 1
    delta_chain: mi.Bool           #: only delta bounces so far (the footprint is kept)
    gap_run: mi.UInt32             #: gap crossings since prev_si

    def ray(self, camera_ray: mi.Ray3f) -> mi.Ray3f:
        """The ray to trace next, with the time and wavelengths of the path's camera ray."""
        return mi.Ray3f(self.ray_o, self.ray_d, self.ray_maxt, camera_ray.time, camera_ray.wavelengths)

    def set_ray(self, ray: mi.Ray3f):
        self.ray_o, self.ray_d, self.ray_maxt = ray.o, ray.d, ray.maxt


def mis_weight(pdf_a, pdf_b):
    """Power heuristic (exponent 2), 0 where undefined (a NaN or infinite density
    included), detached as in Mitsuba's ``path``."""
    a2 = pdf_a * pdf_a
    total = a2 + pdf_b * pdf_b
    defined = (total > 0) & dr.isfinite(total)  # False for NaN
    # (no 0/0 evaluated: scalar variants would raise)
    w = dr.select(defined, a2 / dr.select(defined, total, 1.0), 0.0)  # in [0, 1]
    return dr.detach(w)


def opaque_environment(scene):
    """The scene's environment emitter as an opaque one-lane pointer, or None. Mitsuba writes
    the environment an escaped ray hits (``si.emitter(scene)``) into the kernel as a literal:
    its index among the emitters in the order the parallel loader constructed them, which
    changes from run to run, and with it the kernel's hash, so a warm render missed Dr.Jit's
    kernel cache about one time in six (performance log L36)."""
    if scene.environment() is None:
        return None
    env = mi.EmitterPtr(scene.environment())
    dr.make_opaque(env)
    return env


def _is_uniform(emitter):
    """A ``constant`` environment: the same radiance from every direction."""
    return emitter is not None and emitter.class_name() == "ConstantBackgroundEmitter"


#: A first hit's emitter directions are "exact" (``eval_pdf_sample_n``'s ``exact_wos``)
#: where the delta emitters' irradiance there exceeds this many times pi times the
#: environment's radiance above the surface: their light, which has no sampling noise of
#: its own, is then most of the pixel's, and a footprint BSDF's own noise in it most of
#: the pixel's noise (docs/performance-log.md L56).
EXACT_EMITTER_RATIO = 4.0

#: Experiment (``bench/sky_control_variate.py``); 0 by default (then nothing of it is
#: traced): render only what a control variate for a uniform sky would leave to Monte
#: Carlo. With the share c, the sky's light at a camera ray's first hit is c L_env A(wi)
#: (A: the BSDF's non-delta directional albedo) plus what its directions bring minus c
#: L_env each; with this set, the first hit's non-delta sampled rays that escape bring
#: (1 - c) L_env and those that reach a surface subtract c L_env times their weight, so
#: the image is the true one minus c L_env A(wi) and its noise what the control variate
#: would leave with A exact (docs/performance-log.md L59). Only with ``emitter_sampling``
#: ``all`` (the sky left to BSDF sampling).
SKY_CONTROL_VARIATE_SHARE = 0.0
#: ... and with K > 0, the whole estimator: c L_env times A's estimate, the mean weight of
#: K non-delta samples of the first hit's BSDF in the state of its sampled direction (the
#: same call, emitter directions included: a footprint's same probe and branch), is added
#: there. Unbiased; its noise falls towards what a table of A would leave as K grows (each
#: sample costs one more BSDF sample, so it measures, it does not pay).
SKY_ALBEDO_SAMPLES = 0

#: ``sky_share``: the share c of a uniform sky's light at a camera ray's first hit that a
#: control variate takes whole: c L_env A(wi), A the mean albedo of what the BSDF samples its
#: direction from (``sky_albedo`` of :mod:`.bsdf_contract`: multi-scale ``cloth``'s table),
#: with c L_env times the weight of every sampled direction taken off, so that Monte Carlo
#: carries only what those directions bring beyond c L_env (docs/performance-log.md L59-L61).
#: Only where the sky is left to BSDF sampling (``emitter_sampling`` ``all``) and at first
#: hits whose BSDF gives A. Its default (auto) for large renders: with this None, the share a
#: pilot render measures for the scene (:mod:`.sky_share_pilot`); a number (experiments):
#: that share in every scene.
SKY_TABLE_SHARE = None
#: ... for renders of at least this many samples per pass (pixels x spp of the whole frame,
#: a crop counting as its frame: 320 x 180 at 16 spp and more): a table's build (about 7 s
#: per cloth) outlasts smaller ones (the test suite took 17 min instead of 6 with 2^17).
SKY_TABLE_LANES = 1 << 19


#: Why ``clothpath`` refuses gradients (performance log L18, L70).
NOT_DIFFERENTIABLE = (
    "clothpath: renders are not differentiable: its BSDF samples are drawn with lobe and texel choices "
    "that follow the cloth's parameters, which a gradient through the path cannot see (and Dr.Jit fails "
    "to compile some of them); differentiate the scene with Mitsuba's 'prb' integrator (cloth is then "
    "shaded at points), or render a clothpath image under dr.suspend_grad()")


def gradients_requested(scene) -> bool:
    """Whether a parameter of a BSDF that ``clothpath`` shades through its own calls
    (``eval_pdf_sample_n``: ``cloth``) carries a gradient here (not under
    ``dr.suspend_grad``)."""
    if not dr.is_diff_v(mi.Float):
        return False
    for bsdf in contract.distinct_bsdfs(scene, contract.shades_n_directions):
        params = mi.traverse(bsdf)
        if any(dr.grad_enabled(params[key]) for key in params.keys()):
            return True
    return False


def frame_lanes(scene, lanes: int) -> float:
    """Samples per pass of the whole frame whose crop (``scene``'s first sensor's film) a
    pass of ``lanes`` samples renders: a crop of a frame decides as the frame does (``make
    bench`` times its regions as crops of the frames whose noise it measures)."""
    sensors = scene.sensors()
    if not sensors:
        return float(lanes)
    film = sensors[0].film()
    (w, h), (cw, ch) = film.size(), film.crop_size()
    return lanes * (w * h) / max(cw * ch, 1)


def sky_albedo_bsdfs(scene, max_mib: float | None = None) -> list:
    """The distinct BSDFs of ``scene``'s shapes that give their sampled direction's
    expected weight (``sky_albedo``), their tables of ``max_mib`` (default: full) made
    ready and read (:func:`.bsdf_contract.prepare_sky_albedo`)."""
    return contract.distinct_bsdfs(scene, lambda bsdf: contract.prepare_sky_albedo(bsdf, max_mib))


def uniform_radiance(env) -> tuple:
    """The RGB radiance of the uniform environment emitter ``env``."""
    probe = dr.zeros(mi.SurfaceInteraction3f, 1)
    probe.wi = mi.Vector3f(0.0, 0.0, -1.0)
    return tuple(float(v) for v in np.array(env.eval(probe)).ravel()[:3])


def environment_radiance(env, n: int = 256) -> float:
    """The mean luminance of environment emitter ``env`` over the sphere (``n`` spiral
    directions; 0 without one): a scene's sky for :func:`exact_emitter_directions`."""
    if env is None:
        return 0.0
    i = np.arange(n) + 0.5
    z = 1.0 - 2.0 * i / n
    r = np.sqrt(np.maximum(1.0 - z * z, 0.0))
    phi = i * 2.399963229728653  # the golden angle
    directions = np.stack([r * np.cos(phi), r * np.sin(phi), z])
    with dr.suspend_grad():
        if dr.is_jit_v(mi.Float):
            si = dr.zeros(mi.SurfaceInteraction3f, n)
            si.wi = -mi.Vector3f(*(mi.Float(d) for d in directions))
            return float(np.mean(np.array(mi.luminance(env.eval(si)))))
        total = 0.0
        for d in directions.T:
            si = dr.zeros(mi.SurfaceInteraction3f)
            si.wi = -mi.Vector3f(*(float(v) for v in d))
            total += float(mi.luminance(env.eval(si)))
        return total / n


def exact_emitters_possible(emitters, sky: float) -> bool:
    """Whether :func:`exact_emitter_directions` can hold anywhere: a delta emitter other than
    a directional one (whose irradiance grows without bound near it), or directional ones
    whose irradiance together (at normal incidence, unshadowed) exceeds
    EXACT_EMITTER_RATIO x pi x ``sky``. Where not, the BSDFs get no ``exact_wos`` and
    trace no branch for it."""
    irradiance = 0.0
    for e in emitters:
        if not mi.has_flag(e.flags(), mi.EmitterFlags.Delta):
            continue
        if e.class_name() != "DirectionalEmitter":
            return True
        with dr.suspend_grad():
            it = dr.zeros(mi.Interaction3f) if not dr.is_jit_v(mi.Float) else dr.zeros(mi.Interaction3f, 1)
            _, weight = e.sample_direction(it, mi.Point2f(0.5, 0.5))
            lum = mi.luminance(weight)
            irradiance += float(lum if not dr.is_jit_v(mi.Float) else np.array(lum)[0])
    return irradiance > EXACT_EMITTER_RATIO * np.pi * sky


def exact_emitter_directions(em_samples, sky: float, active):
    """Per lane: whether the delta emitters' samples among ``em_samples`` ((ds, weight,
    active, local direction) each) bring more than EXACT_EMITTER_RATIO x pi x ``sky``
    (the environment's mean luminance, :func:`environment_radiance`): an irradiance
    against the one a uniform sky of that radiance would give."""
    irradiance = mi.Float(0.0)
    for ds, weight, em_active, wo in em_samples:
        if ds is not None:
            irradiance += dr.select(em_active & ds.delta, mi.luminance(weight) * dr.abs(wo.z), 0.0)
    return active & (irradiance > EXACT_EMITTER_RATIO * dr.pi * sky)


def sample_density_needed(emitters, scattered_footprints: bool) -> bool:
    """Whether a BSDF sample's density is read beyond its sign: for MIS where a path may
    hit an emitter that is also sampled (a non-delta one among ``emitters``, those the
    integrator samples), or for the ray cone's spread after a rough bounce
    (``scattered_footprints``). Otherwise ``eval_pdf_sample_n`` is called with ``mis``
    False, and a BSDF may skip computing the mixture's density (``cloth``'s footprints
    whose sample is weighed at a texel: docs/decisions.md)."""
    return bool(scattered_footprints) or any(not mi.has_flag(e.flags(), mi.EmitterFlags.Delta) for e in emitters)


def canonical_emitter_order(emitters) -> list:
    """``emitters`` in an order that depends on the scene alone: by id (the shape's, for an
    area light), then kind and bounds. Mitsuba lists a scene's emitters in the order its
    parallel loader finished them, which varies from load to load; with ``all`` each
    emitter draws its own sample numbers, so that order would change the image a fixed
    seed gives."""
    def key(emitter):
        shape = emitter.get_shape()
        bbox = emitter.bbox()
        # (rounded: transforms read back from XML differ in their last bits)
        bounds = tuple(round(float(v), 6) for v in (*bbox.min, *bbox.max)) if bbox.valid() else ()
        return ((shape.id() if shape is not None else emitter.id()), emitter.class_name(), bounds)
    return sorted(emitters, key=key)


def any_or_true(mask) -> bool:
    """``dr::any_or<true>`` of Mitsuba's C++: JIT variants run a masked branch on all lanes;
    scalar variants skip it where their one lane is off (there it may call methods of a None
    emitter or BSDF, or spend a ray on a sample that counts for nothing)."""
    return dr.is_jit_v(mi.Float) or bool(mask)



def spec_fma(a, b, c):
    """a * b + c: a Mueller-matrix product in polarized variants, a fused multiply-add else."""
    if mi.is_polarized:
        return a * b + c
    return dr.fma(a, b, c)


def make_clothpath_class():
    """Define the ``clothpath`` integrator class for the active Mitsuba variant."""

    class ClothPathIntegrator(mi.SamplingIntegrator):
        __doc__ = DOCSTRING

        def __init__(self, props):
            mi.SamplingIntegrator.__init__(self, props)
            (self.max_depth, self.rr_depth, self.emitter_sampling,
             self.emitter_samples, self.uv_filter) = _read_properties(props)
            self.footprint_aovs = _read_flag(props, "footprint_aovs")
            self.scattered_footprints = _read_flag(props, "scattered_footprints")
            self.gap_shadows = _read_flag(props, "gap_shadows")
            # None: auto, for renders of SKY_TABLE_LANES samples per pass or more the pilot's share.
            self.sky_share = props.get("sky_share", None)
            if isinstance(self.sky_share, int) and not isinstance(self.sky_share, bool):
                self.sky_share = float(self.sky_share)
            if self.sky_share is not None and (not isinstance(self.sky_share, float)
                                               or not 0.0 <= self.sky_share <= 1.0):
                raise ParameterError(f'clothpath: "sky_share" must be a number in [0, 1], got {self.sky_share!r}')

        def aov_names(self):
            return list(AOV_NAMES) if self.footprint_aovs else []

        def to_string(self):
            depth = -1 if self.max_depth == _UINT32_MAX else self.max_depth
            return (f"ClothPathIntegrator[max_depth = {depth}, rr_depth = {self.rr_depth}, "
                    f"hide_emitters = {self.hide_emitters}, "
                    f"emitter_sampling = {self.emitter_sampling}, "
                    f"emitter_samples = {self.emitter_samples}, "
                    f"uv_filter = {self.uv_filter}, "
                    f"scattered_footprints = {self.scattered_footprints}, "
                    f"gap_shadows = {self.gap_shadows}, "
                    f"sky_share = {'auto' if self.sky_share is None else self.sky_share}]")

        def render(self, scene, sensor=0, seed=0, spp=0, develop=True, evaluate=True):
            if gradients_requested(scene):
                raise ParameterError(NOT_DIFFERENTIABLE)
            # sky_share auto's pilot runs here, before the render traces: run from within
            # ``sample`` its kernels would evaluate the camera rays traced so far, and the
            # render's kernel would differ (and miss Dr.Jit's cache) with the share stored.
            sensor_obj = scene.sensors()[sensor] if isinstance(sensor, int) else sensor
            # (The count the render's sampler takes: ``sample`` sees that one.)
            count = sky_share_pilot.render_sample_count(sensor_obj, spp if spp else sensor_obj.sampler().sample_count())
            crop = sensor_obj.film().crop_size()
            if self.sky_share is None and SKY_TABLE_SHARE is None and dr.is_jit_v(mi.Float) \
                    and frame_lanes(scene, int(crop[0]) * int(crop[1]) * count) >= SKY_TABLE_LANES:
                self.pilot_sky_share(scene, count)
            return mi.SamplingIntegrator.render(self, scene, sensor, seed, spp, develop, evaluate)

        def render_forward(self, scene, params, sensor=0, seed=0, spp=0):
            raise ParameterError(NOT_DIFFERENTIABLE)

        def render_backward(self, scene, params, grad_in, sensor=0, seed=0, spp=0):
            raise ParameterError(NOT_DIFFERENTIABLE)

        def sample(self, scene, sampler, ray, medium=None, active=True):
            if self.max_depth == 0:
                zero = mi.Float(0.0)
                return mi.Spectrum(0.0), mi.Bool(False), [zero for _ in self.aov_names()]

            # Whole-pixel differentials and the camera's ray cone.
            ray_d = fp.undo_differential_scaling(ray, sampler.sample_count())
            has_diff = bool(ray.has_differentials)
            if has_diff:
                width0, spread0 = fp.camera_cone(ray_d.o, ray_d.d, ray_d.o_x, ray_d.d_x,
                                                 ray_d.o_y, ray_d.d_y)
            else:
                width0, spread0 = mi.Float(0.0), mi.Float(0.0)
            share = self.sky_share
            if share is None:  # auto
                share = 0.0
                if frame_lanes(scene, dr.width(ray_d.o)) >= SKY_TABLE_LANES:
                    share = SKY_TABLE_SHARE
                    if share is None:
                        share = self.pilot_sky_share(scene, sampler.sample_count()).share
                    elif not self.sky_table_possible(scene):
                        share = 0.0
            return self._trace(scene, sampler, ray_d, has_diff, mi.Float(width0),
                               mi.Float(spread0), mi.Bool(active), share)[:3]

        def sky_table_possible(self, scene, max_mib: float | None = None) -> bool:
            """Whether the sky's control variate can run in ``scene``: a uniform sky left to
            BSDF sampling (``emitter_sampling`` ``all``), emitters not hidden, an RGB JIT
            variant, and a BSDF that gives A (:func:`sky_albedo_bsdfs`, whose tables of
            ``max_mib`` this builds, or makes the ones read). Not with the K-sample
            experiment, which would take the share twice."""
            return bool(not SKY_CONTROL_VARIATE_SHARE and self.emitter_sampling == "all"
                        and _is_uniform(scene.environment()) and dr.is_jit_v(mi.Float) and mi.is_rgb
                        and not mi.is_polarized and not self.hide_emitters and sky_albedo_bsdfs(scene, max_mib))

        def pilot_sky_share(self, scene, spp: int) -> sky_share_pilot.SkySharePilot:
            """``sky_share`` auto's share for ``scene`` rendered at ``spp`` samples per pixel:
            :meth:`decide_sky_share`, kept per scene
            description and spp (:func:`.sky_share_pilot.scene_key`) in this process and on
            disk: a scene rendered again measures nothing; a change its description does not
            show keeps the share, which moves the noise, not the mean."""
            key = sky_share_pilot.scene_key(scene, spp)
            pilot = sky_share_pilot.kept_share(key)
            if pilot is None:
                # (A crop's pilot renders pixels of the whole frame: it is the frame's. "No
                # table here" is not stored.)
                pilot = self.decide_sky_share(scene, spp)
                pilot = sky_share_pilot.keep_share(key, pilot, store=pilot.pixels > 0)
            return pilot

        def decide_sky_share(self, scene, spp: int) -> sky_share_pilot.SkySharePilot:
            """The pilot (:meth:`measure_sky_share`) on the small tables; where it takes no
            share by a cut within ``PILOT_MARGIN`` of ``MIN_VARIANCE_CUT``, again on the
            full tables (small ones read a cut up to 0.02 lower: the drape's 0.113
            against 0.130)."""
            pilot = self.measure_sky_share(scene, spp)
            if pilot.share == 0.0 and pilot.pixels and \
                    pilot.variance_cut >= sky_share_pilot.MIN_VARIANCE_CUT - sky_share_pilot.PILOT_MARGIN:
                pilot = self.measure_sky_share(scene, spp, None)
            return pilot

        def measure_sky_share(self, scene, spp: int,
                              max_mib: float | None = sky_share_pilot.PILOT_MAX_MIB) -> sky_share_pilot.SkySharePilot:
            """The pilot (:mod:`.sky_share_pilot`): PILOT_PIXELS pixels of ``scene``'s first
            sensor rendered three times at ``spp`` with the control variate's term recorded
            at c = 1 instead of added, A read from tables of ``max_mib`` (None: the full
            ones); share 0 where no table can be read."""
            if not self.sky_table_possible(scene, max_mib):
                return sky_share_pilot.SkySharePilot(0.0, 0.0, 0.0, 0)
            x, y = sky_share_pilot.pilot_pixels(scene.sensors()[0])
            F, T = zip(*(self.sky_terms(scene, x, y, spp, sky_share_pilot.PILOT_SEED + k, max_mib) for k in range(3)))
            pilot = sky_share_pilot.choose_share(F[:2], T[:2], F[2])
            mi.Log(mi.LogLevel.Info, f"clothpath: sky_share auto = {pilot.share:.2f} (pilot: optimal "
                   f"{pilot.optimal:.2f}, relative variance cut {pilot.variance_cut:.0%})")
            return pilot

        def sky_terms(self, scene, x, y, spp: int, seed: int, max_mib: float | None = None):
            """(F, T): per pixel (``x``, ``y``) of ``scene``'s first sensor, rendered at
            ``spp`` with its sampler seeded by ``seed`` (:func:`.sky_share_pilot.camera_rays`),
            the mean luminance without the sky's control variate and the mean of its term
            at c = 1 with tables of ``max_mib`` (default: the full ones), recorded instead of
            added (float64 arrays). The pilot's renders, and ``bench/sky_table_bias.py``'s:
            T's mean is L_env times the table's error."""
            rays, sampler = sky_share_pilot.camera_rays(scene.sensors()[0], x, y, spp, seed)
            width0, spread0 = fp.camera_cone(rays.o, rays.d, rays.o_x, rays.d_x, rays.o_y, rays.d_y)
            with dr.suspend_grad():
                result, valid, _, term = self._trace(scene, sampler, rays, True, mi.Float(width0),
                                                     mi.Float(spread0), mi.Bool(True), 0.0, record_sky=True,
                                                     table_mib=max_mib)
                f, t = mi.luminance(dr.select(valid, result, 0.0)), mi.luminance(term)
                dr.eval(f, t)
            return tuple(np.array(a, dtype=np.float64).reshape(len(x), spp).mean(axis=1) for a in (f, t))

        @staticmethod
        def _visible(scene, si, ds, em_weight, active, gaps, cone_width, cone_spread, max_crossings):
            """(ds, weight, active, local direction) of an emitter sample after its shadow
            ray: opaque occluders block it; with ``gaps``, emitters are seen through the
            gaps of cloth (see :mod:`.gap_shadows`): delta emitters across up to
            ``MAX_CROSSINGS`` layers, others across ``max_crossings``, the most that a
            BSDF-sampled path from here can cross before it reaches its ``max_depth``
            (both strategies must reach a path for their MIS weights to add up to 1)."""
            active = active & (ds.pdf != 0.0)
            if any_or_true(active):  # (scalar: no shadow ray for a failed sample)
                if gaps:
                    # A cheap any-hit test first; only occluded samples trace through.
                    occluded = scene.ray_test(si.spawn_ray_to(ds.p), active)
                    limit = dr.select(ds.delta, mi.UInt32(gap_shadows.MAX_CROSSINGS), max_crossings)
                    crossing = active & occluded & (limit > 0)
                    through = gap_shadows.shadow_transmittance(scene, si, ds.p, cone_width, cone_spread,
                                                               crossing, limit)
                    em_weight = em_weight * dr.select(crossing, through, 1.0)
                    active &= dr.select(crossing, through > 0.0, logical_not(occluded))
                else:
                    active &= logical_not(scene.ray_test(si.spawn_ray_to(ds.p), active))
            return ds, em_weight, active, si.to_local(ds.d)

        def _trace(self, scene, sampler, ray_d, has_diff, width0, spread0, active, sky_share, record_sky=False,
                   table_mib=None):
            """(radiance, valid, AOVs, the control variate's term or None) of the paths of
            camera rays ``ray_d`` (whole-pixel differentials), the sky's control variate
            taking ``sky_share`` with tables of ``table_mib`` (default: full); ``record_sky``:
            not added but returned, at c = 1 (the pilot)."""
            jit = dr.is_jit_v(mi.Float)
            bsdf_ctx = mi.BSDFContext()
            max_depth = self.max_depth
            rr_depth = self.rr_depth
            hide_emitters = self.hide_emitters
            o_x, d_x, o_y, d_y = ray_d.o_x, ray_d.d_x, ray_d.o_y, ray_d.d_y  # loop-invariant
            footprint_aovs = self.footprint_aovs
            scattered_footprints = self.scattered_footprints
            emitters = canonical_emitter_order(scene.emitters())
            # `all`: a uniform environment is left to BSDF sampling (MIS weight 1 where a
            # ray escapes); sampling it uniformly over the sphere only adds noise.
            env_by_bsdf = self.emitter_sampling == "all" and _is_uniform(scene.environment())
            if env_by_bsdf:
                emitters = [e for e in emitters if not _is_uniform(e)]
            all_emitters = self.emitter_sampling == "all" and (len(emitters) > 1 or env_by_bsdf)
            # ``mis`` bound here, a Python bool: dr.dispatch would turn an argument into a mask.
            shade_n = functools.partial(contract.eval_pdf_sample_n,
                                        mis=sample_density_needed(emitters, scattered_footprints))
            n_em = self.emitter_samples
            env = opaque_environment(scene) if jit else None
            # Whether a delta emitter (a sun) may make a first hit's emitter directions
            # most of its light (exact_emitter_directions).
            any_delta = any(mi.has_flag(e.flags(), mi.EmitterFlags.Delta) for e in emitters)
            sky = environment_radiance(scene.environment()) if any_delta else 0.0
            exact_possible = any_delta and exact_emitters_possible(emitters, sky)
            uv_normals = fp.needs_uv_normal_derivatives(scene)
            gap_bsdfs = gap_shadows.gap_bsdfs(scene) if self.gap_shadows else []
            gaps = bool(gap_bsdfs)
            # Offsets of camera samples from their pixel centres (perspective and
            # orthographic cameras), for footprint-shading BSDFs.
            centring = fp.pixel_centring(scene, ray_d) if has_diff else None
            tent_filter = has_diff and self.uv_filter == "tent"

            sky_residual = None
            # (RGB only: the sky's radiance read as three numbers. Not with hide_emitters, whose
            # paths through a Null lobe that escape are dropped with the share added back.)
            if SKY_CONTROL_VARIATE_SHARE and env_by_bsdf and jit and mi.is_rgb and not mi.is_polarized \
                    and not hide_emitters:
                share = float(SKY_CONTROL_VARIATE_SHARE)
                sky_radiance = mi.Spectrum(*(share * v for v in uniform_radiance(scene.environment())))

                def sky_residual(s):
                    """The lanes whose ray left a camera ray's first hit in a non-delta direction."""
                    return (s.depth == 1) & logical_not(s.prev_bsdf_delta)

            sky_table_radiance = None
            # (Not with the experiment's residual, which would take the share twice.)
            if (sky_share or record_sky) and self.sky_table_possible(scene, table_mib):
                sky_table_radiance = mi.Spectrum(*((1.0 if record_sky else sky_share) * v
                                                   for v in uniform_radiance(scene.environment())))
            record_sky = record_sky and sky_table_radiance is not None

            def shade_with_sky(bsdf, at_first, *args):
                """``shade_n`` with (A, known) at the lanes ``at_first`` (a Float)."""
                return shade_n(bsdf, *args, sky_albedo=at_first)

            ray = mi.Ray3f(ray_d)
            pi = scene.ray_intersect_preliminary(ray, coherent=True, active=active)

            if hide_emitters:
                # Directly visible area emitters: skip all of them along the camera ray.
                if jit:
                    skip = pi.is_valid() & (pi.shape.emitter() != None) & active  # noqa: E711
                else:  # (scalar: a miss has no shape to ask)
                    skip = bool(active and pi.is_valid() and pi.shape.emitter() is not None)
                if any_or_true(skip):
                    si_skip = pi.compute_surface_interaction(ray, mi.RayFlags.Minimal, skip)
                    ray_skip = si_skip.spawn_ray(ray.d)
                    pi = dr.select(skip, self.skip_area_emitters(scene, ray_skip, True, skip), pi)

            # Where the sample's place in its pixel is not known, the tent filter's offset
            # of up to a pixel: two sampler dimensions, drawn once (used at the first hit).
            tent_jitter = mi.warp.square_to_tent(sampler.next_2d()) if tent_filter else None

            def body(sampler, s: PathState):
                s_ray = s.ray(ray)
                # dNSdUV (not in All): how far the normal turns across a footprint, which
                # decides whether its probes follow the sample's place (curved cloth).
                si = s.pi.compute_surface_interaction(s_ray, mi.RayFlags.All | mi.RayFlags.dNSdUV)
                # (scalar: a miss has no shape, and si.bsdf() would dereference it)
                bsdf = si.bsdf() if any_or_true(si.is_valid()) else None

                # ------------------------- Footprint -------------------------
                first = s.depth == 0
                # Still on the camera ray's line: only straight gap crossings before.
                on_line = (s.gap_run == s.depth) if gaps else first
                w_hit = fp.cone_width(s.cone_width, s.cone_spread, si.t)
                c_dx, c_dy = fp.cone_footprint(w_hit, s_ray.d, si.n, si.dp_du, si.dp_dv)
                if has_diff:
                    r_dx, r_dy = fp.differential_footprint(si.p, si.n, si.dp_du, si.dp_dv,
                                                           o_x, d_x, o_y, d_y)
                    si.duv_dx = dr.select(on_line, r_dx, c_dx)
                    si.duv_dy = dr.select(on_line, r_dy, c_dy)
                else:
                    si.duv_dx = c_dx
                    si.duv_dy = c_dy
                shadow_w, shadow_spread = w_hit, s.cone_spread
                if not scattered_footprints:
                    # Only camera rays and their delta chains carry a footprint; shadow rays
                    # from a vertex shaded at a point cross cloth at a point too.
                    si.duv_dx = dr.select(s.delta_chain, si.duv_dx, 0.0)
                    si.duv_dy = dr.select(s.delta_chain, si.duv_dy, 0.0)
                    shadow_w = dr.select(s.delta_chain, w_hit, 0.0)
                    shadow_spread = dr.select(s.delta_chain, s.cone_spread, 0.0)
                if uv_normals:
                    # Per UV, as si.duv_dx, si.duv_dy (meshes give them per barycentric
                    # unit), where a footprint is handed over.
                    shaded = ((si.duv_dx.x != 0.0) | (si.duv_dx.y != 0.0) | (si.duv_dy.x != 0.0)
                              | (si.duv_dy.y != 0.0))
                    si.dn_du, si.dn_dv = fp.uv_normal_derivatives(si, shaded & s.active)
                if footprint_aovs:
                    record = first & si.is_valid()
                    h_u, h_v = fp.half_widths(si.duv_dx, si.duv_dy)
                    t_u, t_v = contract.call(bsdf, contract.footprint_texels, si, record, active=record,
                                             default=(mi.Float(0.0), mi.Float(0.0)))
                    s.aovs = tuple(dr.select(record, new, old)
                                   for new, old in zip((h_u, h_v, t_u, t_v), s.aovs))

                # ---------------------- Direct emission ----------------------
                leaving_first = sky_residual(s) if sky_residual is not None else None
                # (scalar: a surface without emitter has none to evaluate)
                if any_or_true(si.emitter(scene) is not None):
                    ds = mi.DirectionSample3f(scene, si=si, ref=s.prev_si)
                    if env is not None:  # the environment by an opaque pointer (opaque_environment)
                        ds.emitter = dr.select(si.is_valid(), si.shape.emitter(), env)
                    em_pdf = mi.Float(0.0)
                    if any_or_true(logical_not(s.prev_bsdf_delta)):  # (scalar: none after a delta bounce)
                        if all_emitters:  # no emitter selection: the emitter's own pdf
                            em_pdf = ds.emitter.pdf_direction(s.prev_si, ds, logical_not(s.prev_bsdf_delta))
                        else:
                            em_pdf = scene.pdf_emitter_direction(s.prev_si, ds, logical_not(s.prev_bsdf_delta))
                        if gaps:
                            # prev_si is the vertex before the gap crossings (if any); past
                            # MAX_CROSSINGS of them its shadow rays do not reach the emitter.
                            em_pdf = dr.select(s.gap_run <= gap_shadows.MAX_CROSSINGS, em_pdf, 0.0)
                    if env_by_bsdf:
                        em_pdf = dr.select(si.is_valid(), em_pdf, 0.0)
                    # Only non-delta emitters can be hit, and each had n_em samples.
                    mis_bsdf = mis_weight(s.prev_bsdf_pdf, n_em * em_pdf)
                    emitted = ds.emitter.eval(si, s.prev_bsdf_pdf > 0.0)
                    if leaving_first is not None:
                        emitted = dr.select(leaving_first & logical_not(si.is_valid()), emitted - sky_radiance,
                                            emitted)
                    s.result = spec_fma(s.throughput, emitted * mis_bsdf, s.result)
                if leaving_first is not None:
                    s.result = dr.select(leaving_first & si.is_valid(), s.result - s.throughput * sky_radiance,
                                         s.result)

                # Continue tracing the path at this point?
                active_next = (s.depth + 1 < max_depth) & si.is_valid()
                if not any_or_true(active_next):
                    # Scalar variants stop here, as path.cpp does (a miss has no BSDF).
                    s.active = False
                    return sampler, s

                # ---------------------- Emitter sampling ---------------------
                active_em = active_next & mi.has_flag(bsdf.flags(), mi.BSDFFlags.Smooth)
                em_samples = []  # (ds, weight, active, local direction) per emitter sample
                # Cloth layers a shadow ray towards a non-delta emitter may cross: as many as a
                # BSDF path from here can cross through gaps (each crossing is a vertex of
                # the path) and still count the emitter it then hits (depth + 1 + k < max_depth).
                max_crossings = 0
                if gaps:
                    room = dr.select(s.depth + 2 <= max_depth, mi.UInt32(max_depth) - s.depth - 2, 0)
                    max_crossings = dr.minimum(room, gap_shadows.MAX_CROSSINGS)
                if any_or_true(active_em):  # (scalar: no sample where none counts)
                    if all_emitters:
                        for emitter in emitters:
                            delta = mi.has_flag(emitter.flags(), mi.EmitterFlags.Delta)
                            for _ in range(1 if delta else n_em):
                                ds, em_weight = emitter.sample_direction(si, sampler.next_2d(), active_em)
                                em_samples.append(self._visible(scene, si, ds, em_weight, active_em,
                                                                gaps, shadow_w, shadow_spread, max_crossings))
                    else:
                        for _ in range(n_em):
                            # Visibility as Mitsuba tests it, plus the gaps of cloth.
                            ds, em_weight = scene.sample_emitter_direction(si, sampler.next_2d(), False,
                                                                           active_em)
                            em_samples.append(self._visible(scene, si, ds, em_weight, active_em, gaps,
                                                            shadow_w, shadow_spread, max_crossings))
                if not em_samples:
                    em_samples.append((None, None, False, mi.Vector3f(0.0)))

                # ------ Evaluate BSDF * cos(theta) and sample a direction ------
                sample_1 = sampler.next_1d()
                sample_2 = sampler.next_2d()
                wos = [e[3] for e in em_samples]
                # At the first hit: footprint-aware BSDFs see the pixel centre's uv, the
                # sample's offset in its pixel and the pixel filter (which place their
                # probe and point); uv_filter tent moves the others' shading uv.
                si_shade = si_centred = si
                pixel_offset = mi.Point2f(-1.0, -1.0)
                if centring is not None:
                    ox, oy, centre_ok = centring(si.p, on_line & si.is_valid())
                    centre = fp.centred_uv(si.uv, si.duv_dx, si.duv_dy, ox, oy)
                if tent_filter:
                    shift_ok = on_line & si.is_valid()
                    jitter = tent_jitter
                    si_shade = mi.SurfaceInteraction3f(si)
                    si_shade.uv = dr.select(shift_ok, fp.centred_uv(si.uv, si.duv_dx, si.duv_dy, -jitter.x, -jitter.y),
                                            si.uv)
                    if centring is not None:
                        # Where it is: the point at the B-spline's quantile of that place,
                        # so that a stratified sampler stratifies the filter (an
                        # independent offset added to it multiplied the noise of sharp
                        # detail ~10x on satin-plane).
                        bx = quadratic_bspline_quantile(ox + 0.5)
                        by = quadratic_bspline_quantile(oy + 0.5)
                        si_shade.uv = dr.select(shift_ok & centre_ok,
                                                fp.centred_uv(centre, si.duv_dx, si.duv_dy, -bx, -by), si_shade.uv)
                # A Float (1: exact): dr.dispatch takes a Bool argument for the call's mask.
                exact_wos = None
                if exact_possible:
                    exact_wos = dr.select(exact_emitter_directions(em_samples, sky, on_line & active_next), 1.0, 0.0)
                if centring is not None:
                    si_centred = mi.SurfaceInteraction3f(si)
                    si_centred.uv = dr.select(centre_ok, centre, si_shade.uv)
                    pixel_offset = dr.select(centre_ok, mi.Point2f(ox, oy), pixel_offset)
                # Lanes whose path ends here skip the BSDF (as path.cpp masks it with
                # active_next): a footprint shading is costly, and its result unused.
                exact_arg = () if exact_wos is None else (exact_wos,)
                if sky_table_radiance is None:
                    bsdf_vals, bsdf_pdfs, bsdf_sample, bsdf_weight = contract.call(
                        bsdf, shade_n, bsdf_ctx, si_shade, si_centred, wos, sample_1, sample_2,
                        True, pixel_offset, self.uv_filter, *exact_arg, active=active_next)
                else:  # (A, known) too, at first hits (a Float: a Bool would be dr.dispatch's mask)
                    bsdf_vals, bsdf_pdfs, bsdf_sample, bsdf_weight, albedo, known = contract.call(
                        bsdf, shade_with_sky, dr.select(first, 1.0, 0.0), bsdf_ctx, si_shade, si_centred, wos,
                        sample_1, sample_2, True, pixel_offset, self.uv_filter, *exact_arg, active=active_next)

                if sky_table_radiance is not None:
                    # The sky's share c taken whole where the BSDF knows A: c L A(wi) added,
                    # c L times the sampled direction's weight taken off (delta ones too: a
                    # gap's straight ray sees the sky as the others do; its
                    # expectation is c L A: unbiased whatever the sample reaches).
                    at_first = first & active_next
                    sampled_weight = si.to_world_mueller(bsdf_weight, -bsdf_sample.wo, si.wi)
                    taken = albedo - dr.select(bsdf_sample.pdf > 0.0, sampled_weight, 0.0)
                    into = s.sky_term[0] if record_sky else s.result
                    into = dr.select(at_first & (known > 0.0),
                                     spec_fma(s.throughput, taken * sky_table_radiance, into), into)
                    if record_sky:
                        s.sky_term = (into,)
                    else:
                        s.result = into

                if sky_residual is not None and SKY_ALBEDO_SAMPLES:
                    at_first = first & active_next
                    albedo = mi.Spectrum(0.0)
                    for _ in range(SKY_ALBEDO_SAMPLES):
                        # The full context, delta samples dropped, as the residual drops them
                        # (a restricted context renormalises some BSDFs' weights: mask).
                        _, _, bs_k, weight_k = contract.call(
                            bsdf, shade_n, bsdf_ctx, si_shade, si_centred, wos, sampler.next_1d(), sampler.next_2d(),
                            True, pixel_offset, self.uv_filter, *exact_arg, active=at_first)
                        weight_k = si.to_world_mueller(weight_k, -bs_k.wo, si.wi)
                        kept = at_first & (bs_k.pdf > 0.0) & logical_not(mi.has_flag(bs_k.sampled_type,
                                                                                      mi.BSDFFlags.Delta))
                        albedo += dr.select(kept, weight_k, 0.0)
                    s.result = dr.select(at_first, spec_fma(s.throughput, albedo * sky_radiance / SKY_ALBEDO_SAMPLES,
                                                         s.result), s.result)

                # ---------------- Emitter sampling contribution ---------------
                for (ds, em_weight, em_active, wo), bsdf_val, bsdf_pdf in zip(em_samples, bsdf_vals, bsdf_pdfs):
                    if ds is not None and any_or_true(em_active):
                        bsdf_val = si.to_world_mueller(bsdf_val, -wo, si.wi)
                        # A delta sample is the only one of its emitter (``all``); with
                        # ``one`` it is one of n_em estimates like the others.
                        share = 1.0 / n_em if not all_emitters else dr.select(ds.delta, 1.0, 1.0 / n_em)
                        mis_em = dr.select(ds.delta, 1.0, mis_weight(n_em * ds.pdf, bsdf_pdf)) * share
                        s.result = dr.select(em_active,
                                             spec_fma(s.throughput, bsdf_val * em_weight * mis_em, s.result),
                                             s.result)

                # ----------------------- BSDF sampling ------------------------
                bsdf_weight = si.to_world_mueller(bsdf_weight, -bsdf_sample.wo, si.wi)
                s.set_ray(si.spawn_ray(si.to_world(bsdf_sample.wo)))

                # ------- Update loop variables based on current interaction -----
                s.throughput = s.throughput * bsdf_weight
                s.eta = s.eta * bsdf_sample.eta
                s.valid_ray = s.valid_ray | (s.active & si.is_valid() & logical_not(
                    mi.has_flag(bsdf_sample.sampled_type, mi.BSDFFlags.Null)))
                sampled_delta = mi.has_flag(bsdf_sample.sampled_type, mi.BSDFFlags.Delta)
                # A crossing through the gap of cloth is a null interface to MIS: shadow rays
                # from the vertex before it cross it too, so that vertex stays prev_si, with
                # its pdf, for the emitter the path may hit next.
                crossed = False
                if gaps:
                    crossed = (active_next & gap_shadows.is_gap_bsdf(bsdf, gap_bsdfs)
                               & mi.has_flag(bsdf_sample.sampled_type, mi.BSDFFlags.DeltaTransmission))
                s.prev_si = dr.select(crossed, s.prev_si, mi.Interaction3f(si))
                s.prev_bsdf_pdf = dr.select(crossed, s.prev_bsdf_pdf, bsdf_sample.pdf)
                s.prev_bsdf_delta = dr.select(crossed, s.prev_bsdf_delta, sampled_delta)
                s.gap_run = dr.select(crossed, s.gap_run + 1, mi.UInt32(0))
                s.delta_chain = s.delta_chain & sampled_delta

                # The cone leaves this vertex with its width here, spread by the lobe.
                s.cone_width = w_hit
                s.cone_spread = fp.bounce_spread(s.cone_spread, bsdf_sample.pdf, sampled_delta)

                # -------------------- Stopping criterion ---------------------
                s.depth = dr.select(si.is_valid(), s.depth + 1, s.depth)
                throughput_max = dr.max(mi.unpolarized_spectrum(s.throughput))
                rr_prob = dr.minimum(throughput_max * dr.square(s.eta), 0.95)
                rr_active = s.depth >= rr_depth
                rr_continue = sampler.next_1d() < rr_prob
                s.throughput = dr.select(rr_active, s.throughput * dr.rcp(dr.detach(rr_prob)),
                                         s.throughput)
                s.active = active_next & (logical_not(rr_active) | rr_continue) & (throughput_max != 0.0)

                s.pi = scene.ray_intersect_preliminary(s.ray(ray), coherent=False, active=s.active)
                return sampler, s

            state = PathState(
                ray_o=mi.Point3f(ray.o), ray_d=mi.Vector3f(ray.d), ray_maxt=mi.Float(ray.maxt), pi=pi,
                throughput=mi.Spectrum(1.0), result=mi.Spectrum(0.0), eta=mi.Float(1.0),
                depth=mi.UInt32(0),
                # If emitters are not hidden, the environment is visible.
                valid_ray=mi.Bool((not hide_emitters) and scene.environment() is not None),
                prev_si=dr.zeros(mi.Interaction3f), prev_bsdf_pdf=mi.Float(1.0),
                prev_bsdf_delta=mi.Bool(True), active=mi.Bool(active),
                cone_width=mi.Float(width0), cone_spread=mi.Float(spread0),
                # Only when recorded: a state variable the body leaves as it is (a literal)
                # made Dr.Jit trace the whole loop body twice (performance log L51).
                aovs=tuple(mi.Float(0.0) for _ in AOV_NAMES) if footprint_aovs else (),
                delta_chain=mi.Bool(True), gap_run=mi.UInt32(0),
                sky_term=(mi.Spectrum(0.0),) if record_sky else ())
            # A symbolic loop in JIT variants; in scalar ones, where ``active`` is a Python
            # bool, dr.while_loop runs the body as a Python while loop.
            # Without loop optimisation: it drops loop-invariant state (the sampler's seeds)
            # by tracing the whole body a second time, a third of a multi-scale render's
            # fixed cost for two fewer registers (performance log L51).
            with dr.scoped_set_flag(dr.JitFlag.OptimizeLoops, False):
                _, state = dr.while_loop((sampler, state), lambda sampler, s: s.active, body,
                                         label="clothpath")
            return (dr.select(state.valid_ray, state.result, 0.0), state.valid_ray,
                    list(state.aovs) if footprint_aovs else [], state.sky_term[0] if record_sky else None)

    ClothPathIntegrator.__name__ = "ClothPathIntegrator"
    ClothPathIntegrator.__qualname__ = "ClothPathIntegrator"
    return ClothPathIntegrator
