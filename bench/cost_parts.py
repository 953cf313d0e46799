"""What a multi-scale sample's time is made of, for the parts that no tuning constant
switches off: experiment switches that swap code in (installed here, before any scene
loads), timed as ``bench/sample_cost.py`` times variants (same arguments; set a switch
per variant with ``--attr NAME=True``):

* ``IGNORE_ESTIMATOR``: the cloth BSDF shades every vertex at fibre level exactly as brute
  force does (no shading hash, no footprint, no sky albedo read): what is left is the
  integrator's own multi-scale work (pixel centring, normal derivatives, cones).
* ``NO_FOOTPRINT_CODE``: the hash, the footprint and the sky albedo read as usual, the
  fibre-level branch shades, and the footprint branch is not traced at all: against an all
  fibre-level variant (``--attr POINT_TEXELS=1e9 ...``, the footprint code traced but
  never run), whether the footprint code's mere presence in the kernel slows the rest.
* ``SPLIT_CALLS``: vertices without a footprint (after a camera ray's first hit) call a
  second BSDF callable that holds no footprint code; the others the usual one.
* ``HUGE_PAGES``: tables of ``HUGE_FROM`` bytes or more uploaded from memory advised for
  transparent huge pages (Linux ``madvise``), so that their random reads miss the TLB less.
* ``SKY_READ_ZERO``: the sky albedo table's read returns a constant (the control
  variate's arithmetic and branch kept): the read's own price.

Timing only: ``SKY_READ_ZERO`` and ``NO_FOOTPRINT_CODE`` change the image.

    .venv/bin/python bench/cost_parts.py satin --marginal --rounds 5 \\
        --variant "fibre level as brute force: --attr IGNORE_ESTIMATOR=True" \\
        --variant "no footprint code: --attr NO_FOOTPRINT_CODE=True"
"""
from __future__ import annotations

import mmap
import sys

import numpy as np

import sample_cost
from common import setup_mitsuba

#: Tables from this size (bytes) go to huge pages under ``HUGE_PAGES``.
HUGE_FROM = 1 << 20

SWITCHES = ("IGNORE_ESTIMATOR", "NO_FOOTPRINT_CODE", "SPLIT_CALLS", "HUGE_PAGES", "SKY_READ_ZERO")


def install() -> None:
    """The switches, as class attributes of ``ClothShading`` (False), and the code they swap."""
    import drjit as dr
    import mitsuba as mi

    from mscloth import jit_arrays
    from mscloth.bsdf import cloth_shading, sky_albedo
    from mscloth.integrators import bsdf_contract as contract

    shading = cloth_shading.ClothShading
    for name in SWITCHES:
        setattr(shading, name, False)
    lean = [False]  # tracing the second callable of SPLIT_CALLS
    shade, aligned, probe, call = (shading.shade, jit_arrays._aligned, sky_albedo.SkyAlbedoTable.probe_albedo,
                                   contract.call)

    def fibre_level(self, si, fr, enabled, wos, samples, active, fp, hashed, sky_albedo_wanted):
        xi = None if hashed is None else hashed[0]
        values, pdfs, record = self._point_branch(si, fr, enabled, wos, samples, active, fp, xi)
        values = [dr.select(active, v, 0.0) for v in values]
        pdfs = [dr.select(active, p, 0.0) for p in pdfs]
        sample = self._bsdf_sample(cloth_shading.SampleRecord(*record)) if record else ()
        out = (values, pdfs, sample)
        if sky_albedo_wanted is False:
            return out
        if hashed is None:  # (brute force's shading reads no table)
            return out + ((mi.Color3f(0.0), mi.Float(0.0)),)
        # As the shading reads it: in a branch that packets of later vertices skip.
        want = mi.Bool(active) & sky_albedo_wanted
        albedo = cloth_shading.branch(want, (si, wos, samples),
                                      true_fn=lambda: self.probe_albedo(fr, fp, hashed, want),
                                      false_fn=lambda: (mi.Color3f(0.0), mi.Float(0.0)), label="cost_parts_sky")
        return out + (albedo,)

    def switched_shade(self, enabled, si, wos, samples, active, pixel_offset=None, pixel_filter="box", mis=True,
                       exact_wos=None, sky_albedo=False):
        if self.estimator is not None and (shading.IGNORE_ESTIMATOR or lean[0] or shading.NO_FOOTPRINT_CODE):
            fr = self.fibre.frame(si, active, pixel_offset, pixel_filter)
            mirrored = [fr.mirror(wo) for wo in wos]
            fp = hashed = None
            if shading.NO_FOOTPRINT_CODE and not (shading.IGNORE_ESTIMATOR or lean[0]):
                hashed, fp = self._hashed_footprint(si, fr, self._exact_wos(si, fr, mirrored, exact_wos))
            return fibre_level(self, si, fr, enabled, mirrored, samples, active, fp, hashed, sky_albedo)
        return shade(self, enabled, si, wos, samples, active, pixel_offset, pixel_filter, mis, exact_wos, sky_albedo)

    def merge(mask, a, b):
        if isinstance(a, (list, tuple)):
            return type(a)(merge(mask, x, y) for x, y in zip(a, b))
        if isinstance(a, mi.BSDFSample3f):
            out = mi.BSDFSample3f()
            for name in ("wo", "pdf", "eta", "sampled_type", "sampled_component"):
                setattr(out, name, dr.select(mask, getattr(a, name), getattr(b, name)))
            return out
        return dr.select(mask, a, b)

    def switched_call(bsdf, func, *args, active=True, default=None):
        shades = getattr(func, "func", None) is contract.eval_pdf_sample_n or \
            getattr(func, "__name__", "") == "shade_with_sky"
        if not (shading.SPLIT_CALLS and shades and dr.is_jit_v(mi.Float)):
            return call(bsdf, func, *args, active=active, default=default)
        si = next(a for a in args if isinstance(a, mi.SurfaceInteraction3f))
        has = (si.duv_dx.x != 0.0) | (si.duv_dx.y != 0.0) | (si.duv_dy.x != 0.0) | (si.duv_dy.y != 0.0)
        full = call(bsdf, func, *args, active=active & has, default=default)
        lean[0] = True
        try:
            rest = call(bsdf, func, *args, active=active & ~has, default=default)
        finally:
            lean[0] = False
        return merge(has, full, rest)

    def switched_aligned(values, dtype):
        values = np.asarray(values)
        nbytes = values.size * np.dtype(dtype).itemsize
        if not shading.HUGE_PAGES or nbytes < HUGE_FROM:
            return aligned(values, dtype)
        memory = mmap.mmap(-1, nbytes + (2 << 20))
        memory.madvise(mmap.MADV_HUGEPAGE)  # before the first write: faults take huge pages
        buffer = np.frombuffer(memory, dtype=np.uint8)
        start = -buffer.ctypes.data % 64
        out = buffer[start:start + nbytes].view(dtype)
        np.copyto(out.reshape(values.shape), values, casting="unsafe")
        return out

    def switched_probe(self, *args):
        return mi.Color3f(0.5) if shading.SKY_READ_ZERO else probe(self, *args)

    shading.shade = switched_shade
    contract.call = switched_call
    jit_arrays._aligned = switched_aligned
    sky_albedo.SkyAlbedoTable.probe_albedo = switched_probe


def main(argv=None) -> int:
    setup_mitsuba()
    install()
    return sample_cost.main(argv)


if __name__ == "__main__":
    sys.exit(main())
