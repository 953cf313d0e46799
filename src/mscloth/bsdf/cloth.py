"""The ``cloth`` BSDF plugin: wires cloth maps and parameters into the lobes of
supplement Eq. 1, and Mitsuba's BSDF interface into the variant-agnostic units that shade:

* :mod:`.parameters`: what the plugin reads, what the tables are built from;
* :mod:`.fibre_bsdf`: the fibre-level BSDF at a texel (:class:`.FibreBSDF`), over the
  named state of :mod:`.shading_state` and the lobe mixture of :mod:`.lobe_mixture`;
* :mod:`.footprint_estimator`: the footprint (multi-scale) BSDF over it;
* :mod:`.cloth_shading`: one shading call, footprint or fibre level;
* :mod:`.lobe_calibration`: the lobe choice matched to the lobes' albedos.

The maths lives in :mod:`mscloth.scattering`. Plugin classes bind to the Mitsuba variant
active when they are defined, so :func:`make_cloth_class` builds one class per variant
(see :mod:`.registry`); the class holds only what binds to Mitsuba.
"""
from __future__ import annotations

import dataclasses
import itertools

import drjit as dr
import mitsuba as mi
import numpy as np

from ..errors import ParameterError
from .cloth_shading import ClothShading
from .fibre_bsdf import FibreBSDF, ShadingParameters, TileTables
from .footprint_data import FootprintData
from .footprint_estimator import FootprintEstimator
from . import calibration_cache
from .lobe_calibration import LobeCalibration, calibrate
from .lobe_mixture import LobeSamplers
from .lobes import component_flags, enabled_lobes
from .parameter_docs import DOCSTRING  # generated from the one parameter table
from .parameters import (ENERGY_PARAMETERS, EXPOSED, FLOAT_PARAMETERS, SPECTRUM_PARAMETERS, _check_float,
                         check_energy, check_spectrum, cloth_maps, constant_channels, exposure_flags,
                         read_parameters, uv_scales, with_flags_column)


#: The float parameters shading reads: the fields of :class:`.fibre_bsdf.ShadingParameters`.
SHADING_FLOATS = tuple(f.name for f in dataclasses.fields(ShadingParameters) if f.name != "textures")

#: Numbers cloths that have no id of their own, so that their progress lines differ.
_unnamed_cloths = itertools.count(1)


def cloth_label(plugin_id: str, pattern: str) -> str:
    """``"<id>, <pattern>"``: which cloth a progress line or warning is about.

    The id is the plugin's (``floor.bsdf`` for a cloth nested in shape ``floor`` when loaded
    through :func:`mscloth.loading.load_dict`, which names them); a cloth without one, or
    with Mitsuba's generic ``bsdf``, gets ``cloth <n>``. A pattern given as a path (a maps
    directory, a .wif file) is shown by its last component."""
    name = plugin_id if plugin_id and plugin_id != "bsdf" else f"cloth {next(_unnamed_cloths)}"
    shown = pattern.replace("\\", "/").rstrip("/").rsplit("/", 1)[-1] or pattern
    return f"{name}, {shown}"


def make_cloth_class():
    """Define the ``cloth`` BSDF class for the active Mitsuba variant."""

    class ClothBSDF(mi.BSDF):
        __doc__ = with_flags_column(DOCSTRING)

        def __init__(self, props):
            # Validate everything before the C++ base is constructed: a base that is
            # constructed (and registered for virtual calls) by an __init__ that then raises
            # leaves a dangling registry entry, and a later render crashes on it.
            p = read_parameters(props)
            maps = cloth_maps(p)
            mi.BSDF.__init__(self, props)
            self.pattern = p.fabric.name if not p.pattern_given else p.pattern
            self.label = cloth_label(props.id(), self.pattern)
            self.maps = maps
            # What the tables and the calibration were built from (parameters_changed
            # builds again when its roughness changes); everything else shading reads live.
            self.build = p.build
            self._pinned = {}
            self._maps_key = None  # a hash of the maps, for the calibration's cache key
            uv_scale, uv_scale_v = uv_scales(p, maps)
            # uv_scale_v follows uv_scale at the tile's aspect when it was not given.
            self._uv_aspect = None if (p.uv_scale_v and not p.uv_unit) else uv_scale_v / uv_scale
            given = dict(uv_scale=uv_scale, uv_scale_v=uv_scale_v)
            self.params = ShadingParameters(
                **{name: self._parameter(name, given[name] if name in given else getattr(p, name))
                   for name in SHADING_FLOATS},
                textures=p.textures)
            self.fibre = FibreBSDF(self.params, TileTables.from_maps(maps), p.build.visibility, p.build.parallax)
            self.multiscale = p.build.multiscale
            # Read by clothpath: footprints are shaded whole, so centre them on the pixel.
            self.footprint_shading = p.build.multiscale
            if p.footprint_slices != 1:
                mi.Log(mi.LogLevel.Warn, f"cloth [{self.label}]: footprint_slices is no longer used: footprints are "
                                         "shaded as the pixel's parallelogram (one probe per sample)")
            self.m_components = component_flags()
            flags = 0
            for f in self.m_components:
                flags |= f
            self.m_flags = flags
            self._build_tables()
            self.fibre.samplers = LobeSamplers.for_fuzz(self.params.sheen_roughness, p.sheen_roughness,
                                                        p.sheen_thickness)
            self._calibrate(uv_scale, uv_scale_v)
            # What a refused params.update() puts back (parameters_changed).
            self._accepted = self._saved_values(EXPOSED)

        # ------------------------------------------------------------------
        # What is built from parameters: tables, calibration
        # ------------------------------------------------------------------
        @property
        def estimator(self) -> FootprintEstimator | None:
            """The footprint (multi-scale) estimator, None at fibre level."""
            return self.shading.estimator

        @property
        def footprint_data(self) -> FootprintData | None:
            """The precomputed tables in Dr.Jit memory (None when none are needed)."""
            return self.fibre.footprint_data

        def _build_tables(self):
            """The multi-scale tables of ``self.build`` (cached: :func:`load_or_build`) in
            Dr.Jit memory, and the footprint estimator that reads them."""
            b = self.build
            self.fibre.footprint_data = None
            self.table_key = None
            self.direction_rank = b.direction_rank  # the rank built (see max_table_mib)
            if b.needs_tables:
                from ..precompute.tables import load_or_build

                key, why = b.table_key(*self.maps.resolution)
                self.direction_rank = key.d_rank
                # The rank note comes when the tables are built, not on every cached load.
                note = f"cloth [{self.label}]: {why}" if why and b.multiscale else ""
                tables = load_or_build(self.maps, key, label=self.label, build_warning=note)
                self.table_key = key
                self.fibre.footprint_data = FootprintData(tables, with_sats=b.multiscale, with_parallax=b.parallax)
            # The footprint BSDF; before calibration, which samples it.
            self.shading = ClothShading(self.fibre, FootprintEstimator(self.fibre, b.roughness) if b.multiscale else None)
            self._sky_tables = {}  # sky albedo tables by size (prepare_sky_albedo)

        def _calibrate(self, uv_scale, uv_scale_v):
            """Lobe selection matched to the lobes' albedos, and for footprints to the
            footprint mixture's weights, measured on the BSDF as it is now, at the uv scales
            given (JIT variants; scalar variants, for unit tests, keep the uncalibrated
            proxies). Stored in the cache (:mod:`.calibration_cache`) and read from it when
            the same BSDF is loaded again."""
            self.fibre.calibration = None
            if self.estimator is not None:
                self.estimator.calibration = None
            if not dr.is_jit_v(mi.Float):
                return
            key = self._calibration_key(uv_scale, uv_scale_v)
            stored = calibration_cache.load(key) if key else None
            if stored is not None:
                point = LobeCalibration(stored["point"])
                footprint = None
                if "footprint_ratios" in stored:
                    footprint = LobeCalibration(stored["footprint_ratios"], stored["footprint_factors"])
            else:
                texel_uv = None
                if self.multiscale:
                    tile = self.fibre.tile
                    texel_uv = (1.0 / (uv_scale * tile.tile_w), 1.0 / (uv_scale_v * tile.tile_h))
                with dr.suspend_grad():
                    point, footprint = calibrate(self, self.fibre.point_proxies, self.estimator, texel_uv)
                if key:
                    arrays = {"point": point.albedo_ratios}
                    if footprint is not None:
                        arrays.update(footprint_ratios=footprint.albedo_ratios, footprint_factors=footprint.factors)
                    calibration_cache.save(key, arrays)
            self.fibre.calibration = point
            if self.estimator is not None:
                self.estimator.calibration = footprint

        def _calibration_key(self, uv_scale, uv_scale_v) -> str | None:
            """The calibration's cache key, or None where spatially varying textures make
            it unknowable."""
            textures = {}
            for name, texture in self.params.textures.items():
                if texture.is_spatially_varying():
                    return None
                textures[name] = [float(c) for c in constant_channels(texture)]
            if self._maps_key is None:
                from ..precompute.tables import table_key
                self._maps_key = table_key(self.maps, {})
            tuning = {} if self.estimator is None else {
                name: getattr(self.estimator, name) for name in FootprintEstimator.TUNING}
            tuning["FOLD_FLAKES"] = LobeSamplers.FOLD_FLAKES  # the share factors measure the sampler
            inputs = {"variant": mi.variant(), "build": dataclasses.asdict(self.build),
                      "tables": None if self.table_key is None else self.table_key.as_params(),
                      "params": {name: self._value(name) for name in SHADING_FLOATS},
                      "textures": textures, "uv": [float(uv_scale), float(uv_scale_v)], "tuning": tuning}
            return calibration_cache.calibration_key(self._maps_key, inputs)

        def _parameter(self, name, value):
            """A float parameter as an evaluated (opaque) Float in JIT variants, as Mitsuba's
            own plugins hold theirs: two ``cloth`` BSDFs that differ only in parameter
            values then trace the same code, which Dr.Jit runs once for a packet of lanes
            that hit both (one callable instead of two; -4% render time in the demo scene).
            It also keeps Dr.Jit 1.5.0 from folding ``literal 0 * x`` by resizing the
            literal in place (a sheen_thickness of 0 once became as wide as the lanes it
            multiplied); the second reference guards that too."""
            value = mi.Float(value)
            self._pin(name, value)
            return value

        def _pin(self, name, value):
            """Make ``value`` (parameter ``name``'s Float, changed in place by
            ``params.update()``) opaque again, and hold its second reference."""
            if dr.is_jit_v(mi.Float):
                dr.make_opaque(value)
                self._pinned[name] = mi.Float(value)

        def _value(self, name) -> float:
            """Parameter ``name``'s value as a Python float: in JIT variants its float32's
            shortest decimal (0.45, not 0.4499999881), the value a scene would give, so
            that what is built from it (a table's cache key, a shared sheen table) is what a
            scene giving that value builds."""
            value = getattr(self.params, name)
            if not dr.is_jit_v(mi.Float):
                return float(value)
            return float(str(np.float32(dr.detach(value)[0])))

        # ------------------------------------------------------------------
        # mi.BSDF interface
        # ------------------------------------------------------------------
        def sample(self, ctx, si, sample1, sample2, active=True):
            return self.shading.shade(enabled_lobes(ctx), si, [], (sample1, sample2), active)[2]

        def eval_pdf(self, ctx, si, wo, active=True):
            values, pdfs, _ = self.shading.shade(enabled_lobes(ctx), si, [wo], None, active)
            return values[0], pdfs[0]

        def eval(self, ctx, si, wo, active=True):
            return self.eval_pdf(ctx, si, wo, active)[0]

        def pdf(self, ctx, si, wo, active=True):
            return self.eval_pdf(ctx, si, wo, active)[1]

        def eval_pdf_sample_n(self, ctx, si, wos, sample1, sample2, active=True, pixel_offset=None,
                              pixel_filter="box", mis=True, exact_wos=None, sky_albedo=False):
            """eval_pdf at every direction of ``wos`` and one sample, sharing one footprint
            state (SAT means, visibilities, the sampling mixture: all independent of the
            outgoing direction). Called by ``clothpath`` through ``dr.dispatch``, which
            passes the camera sample's ``pixel_offset`` at first hits, its
            ``pixel_filter``, ``mis`` False where no MIS reads the sample's density and
            ``exact_wos`` where the emitters' directions carry most of the light
            (:meth:`.ClothShading.shade`); ``sky_albedo`` True (or a mask of lanes): also
            the (A, known) of what it samples from, the sky albedo table's
            (:meth:`prepare_sky_albedo`; known 0 without one), two more values."""
            out = self.shading.shade(enabled_lobes(ctx), si, wos, (sample1, sample2), active, pixel_offset,
                                     pixel_filter, mis, exact_wos, sky_albedo)
            values, pdfs, (bs, weight) = out[:3]
            return (values, pdfs, bs, weight) + (() if sky_albedo is False else tuple(out[3]))

        def eval_pdf_sample(self, ctx, si, wo, sample1, sample2, active=True):
            values, pdfs, bs, weight = self.eval_pdf_sample_n(ctx, si, [wo], sample1, sample2, active)
            return values[0], pdfs[0], bs, weight

        def footprint_texels(self, si, active=True):
            """Full widths (u, v) in texels of this tile of the footprint in si.duv_dx/dy
            (the ``footprint_texels_*`` AOVs of clothpath)."""
            return self.shading.footprint_texels(si, active)

        def prepare_sky_albedo(self, max_mib: float | None = None) -> bool:
            """Make the sky albedo table (:mod:`.sky_albedo`) of ``max_mib`` (default
            ``MAX_MIB``; a pilot's is smaller) the one this cloth reads, built if it has
            none of that size, if this cloth can have one: multi-scale cloth whose textures
            are constant, without parallax (the table holds each texel's own A), in JIT
            variants. Whether it has one."""
            if not (self.multiscale and dr.is_jit_v(mi.Float) and not self.build.parallax
                    and self.footprint_data is not None) \
                    or any(t.is_spatially_varying() for t in self.params.textures.values()):
                return False
            from .sky_albedo import build_sky_albedo_table, cached_table, keep_table

            shading, tables = self.shading, self._sky_tables
            uv = (self._value("uv_scale"), self._value("uv_scale_v"))
            # What the calibration is built from is what the table is built from.
            key = self._calibration_key(*uv)
            table = tables.get(max_mib) or cached_table(key, max_mib)
            if table is None:
                ctx = mi.BSDFContext()

                def sample(uv, wi, sample1, sample2):
                    si = dr.zeros(mi.SurfaceInteraction3f, dr.width(uv))
                    si.uv = uv
                    si.wi = wi
                    with dr.suspend_grad():
                        bs, weight = self.sample(ctx, si, sample1, sample2)
                    kept = bs.pdf > 0.0
                    dr.eval(weight, kept)
                    return np.asarray(weight).reshape(3, -1), np.asarray(kept)

                from ..precompute._util import Progress

                h, w = self.maps.resolution
                fd = self.footprint_data
                # (A few seconds per cloth, on the first render that wants it: shown as the tables' builds are.)
                prog = Progress(label=self.label)
                table = keep_table(key, build_sky_albedo_table(
                    sample, h, w, uv, fd.dv, max_mib=max_mib,
                    progress=lambda done, total: prog("sky albedo table", done, total, "directions")), max_mib)
                mi.Log(mi.LogLevel.Info, f"cloth [{self.label}]: sky albedo table {table.nbytes / 2**20:.1f} "
                                         f"MiB in {table.seconds:.1f} s")
            tables[max_mib] = shading.sky_table = table
            return True

        def gap_transmission(self, si, active=True):
            """Fraction of light crossing the cloth straight along -si.wi through its gaps
            (clothpath's shadow rays; :meth:`.ClothShading.gap_transmission`)."""
            return self.shading.gap_transmission(si, active)

        # ------------------------------------------------------------------
        # Parameters: traverse, parameters_changed
        # ------------------------------------------------------------------
        def traverse(self, callback):
            # Flags from parameters.EXPOSED: differentiable where eval reads the value live.
            for name in EXPOSED:
                value = self.params.textures[name] if name in self.params.textures else getattr(self.params, name)
                callback.put(name, value, exposure_flags(name, self.multiscale))

        def parameters_changed(self, keys=[]):
            """After ``params.update()``: every changed float is checked and made opaque
            again; every changed albedo (a texture: its value, its data, a checkerboard's
            colours) is checked as the constructor checks it, in [0, 1] and within the
            energy bound; a changed fuzz rebuilds the samplers; a changed roughness rebuilds
            what was built from it (the tables where shading reads them, then the
            calibration), as a BSDF loaded with it would have. Other parameters are read
            live. No keys: all of them may have changed (Mitsuba's convention).

            A refused update raises ParameterError with the changed parameters back at
            their last accepted values: Mitsuba has written the new ones before calling
            this, and a caught error must not leave them to shade with."""
            changed = set(keys) if keys else set(EXPOSED)
            where = f"cloth [{self.label}]"
            try:
                build = self._checked_build(changed, where)
            except ParameterError as error:
                names = [name for name in EXPOSED if name in changed]
                self._restore(names)
                kept = "value of" if len(names) == 1 else "values of"
                raise ParameterError(f"{error}; kept the previous {kept} {', '.join(names)}") from None
            self.shading.sky_table = None  # built from every parameter: again on request
            self._sky_tables = {}
            for name in FLOAT_PARAMETERS:
                if name in changed and name in EXPOSED:
                    self._pin(name, getattr(self.params, name))
            if "uv_scale_v" in changed and keys:
                self._uv_aspect = None  # given now
            elif "uv_scale" in changed and self._uv_aspect is not None:
                # A v scale derived from uv_scale (and the tile's aspect) stays so, as when loaded.
                v = self._value("uv_scale") * self._uv_aspect
                if dr.is_jit_v(mi.Float):
                    mi.set_property(self.params.uv_scale_v, mi.Float(v))  # in place: params holds it
                else:
                    self.params.uv_scale_v = v
                self._pin("uv_scale_v", self.params.uv_scale_v)
                changed.add("uv_scale_v")
            if changed & {"sheen_roughness", "sheen_thickness"}:
                self.fibre.samplers = LobeSamplers.for_fuzz(self.params.sheen_roughness, self._value("sheen_roughness"),
                                                            self._value("sheen_thickness"))
            if build is not None:
                tables_change = self.build.tables_read_roughness
                self.build = build
                if tables_change:
                    self._build_tables()
                elif self.estimator is not None:
                    self.estimator.roughness = build.roughness
                self._calibrate(self._value("uv_scale"), self._value("uv_scale_v"))
            self._accepted.update(self._saved_values(name for name in EXPOSED if name in changed))

        def _checked_build(self, changed, where):
            """Check the ``changed`` parameters' values (ParameterError naming ``where``);
            the new BuildParameters if the roughness changed, else None. Changes nothing."""
            textures = self.params.textures
            bounds = {name: check_spectrum(name, textures[name], where) for name in SPECTRUM_PARAMETERS
                      if name in changed}
            if changed & set(ENERGY_PARAMETERS):
                check_energy({name: bounds[name] if name in bounds else check_spectrum(name, textures[name], where)
                              for name in ENERGY_PARAMETERS}, where)
            for name in FLOAT_PARAMETERS:
                if name in changed and name in EXPOSED:
                    _check_float(name, self._value(name), where)
            roughness = self._value("roughness")
            if "roughness" not in changed or np.float32(roughness) == np.float32(self.build.roughness):
                return None
            try:
                return self.build.with_roughness(roughness)
            except ParameterError as error:
                reason = str(error).removeprefix("cloth: ")
                raise ParameterError(f"{where}: roughness {roughness:g} does not fit the tables: {reason}; "
                                     "reload the scene with other direction_bins or direction_rank") from None

        def _saved_values(self, names) -> dict:
            """Copies of parameters ``names``' values as they are now (:meth:`_restore`): a
            float's Float, a texture's every traversed value (what ``params.update()``
            writes into it). Copies: what ``traverse`` hands out is changed in place."""
            saved = {}
            for name in names:
                if name in self.params.textures:
                    saved[name] = {key: type(value)(value)
                                   for key, value in mi.traverse(self.params.textures[name]).items()}
                else:
                    value = getattr(self.params, name)
                    saved[name] = type(value)(value)
            return saved

        def _restore(self, names):
            """Put parameters ``names`` back at their last accepted values (a refused update)."""
            for name in names:
                saved = self._accepted[name]
                if name in self.params.textures:
                    params = mi.traverse(self.params.textures[name])
                    for key, value in saved.items():
                        params[key] = value  # a no-op where unchanged
                    params.update()
                elif dr.is_jit_v(mi.Float):
                    mi.set_property(getattr(self.params, name), saved)  # in place: params holds it
                    self._pin(name, getattr(self.params, name))
                else:
                    setattr(self.params, name, saved)

        def to_string(self):
            h, w = self.maps.resolution
            p = self.params
            return (f"ClothBSDF[pattern={self.pattern!r} ({w}x{h} texels), uv_scale={p.uv_scale}, "
                    f"roughness={p.roughness}, thickness={p.thickness}, "
                    f"sheen_roughness={p.sheen_roughness}, sheen_thickness={p.sheen_thickness}]")

    ClothBSDF.__name__ = "ClothBSDF"
    return ClothBSDF
