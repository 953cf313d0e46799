"""Flat arrays in Dr.Jit memory and per-lane reads from them, in every variant (JIT
arrays in llvm/cuda, plain containers in scalar variants): the lookup tables of the BSDF
(summed-area tables, visibility, calibration) and of its samplers (alias tables)."""
from __future__ import annotations

import drjit as dr
import mitsuba as mi
import numpy as np


def _aligned(values, dtype) -> np.ndarray:
    """A flat copy of ``values`` in a 64-byte aligned NumPy buffer.

    Dr.Jit maps NumPy memory without copying and marks the kernel's loads with the
    alignment it finds: a table that is not 64-byte aligned gets no packet reads (each
    :func:`gather_block` packet silently becomes four scalar gathers, 1.5-2x the render
    time of a footprint shading, measured), and per-lane inputs aligned differently
    trace a different kernel (a fresh compilation and a kernel-cache miss)."""
    values = np.asarray(values)
    nbytes = values.size * np.dtype(dtype).itemsize
    buffer = np.empty(nbytes + 64, dtype=np.uint8)
    start = -buffer.ctypes.data % 64
    aligned = buffer[start:start + nbytes].view(dtype)
    # One pass from a strided or wider view (a table moved to channel-minor order):
    # ravel-then-copy read 100 MiB tables twice.
    np.copyto(aligned.reshape(values.shape), values, casting="unsafe")
    return aligned


def flat_array(values: np.ndarray):
    """A flat float32 Dr.Jit array of ``values`` that ``dr.gather`` reads, in every variant
    (a 64-byte aligned JIT array in llvm/cuda, a dynamic array in scalar variants)."""
    aligned = _aligned(values, np.float32)
    return mi.Float(aligned) if dr.is_jit_v(mi.Float) else mi.TensorXf(aligned).array


def lane_values(values) -> "mi.Float":
    """Per-lane float32 inputs from NumPy (JIT variants), 64-byte aligned (see
    :func:`_aligned`)."""
    return mi.Float(_aligned(values, np.float32))


def gather(source, index, active=True):
    """``source[index]`` per lane (0 where not ``active``), in JIT and scalar variants."""
    if dr.is_jit_v(mi.Float):
        return dr.gather(mi.Float, source, index, active)
    return source[int(index)] if active else 0.0


def flat_word_array(values: np.ndarray):
    """A flat uint32 array of ``values`` for :func:`gather_word`."""
    aligned = _aligned(values, np.uint32)
    return mi.UInt32(aligned) if dr.is_jit_v(mi.Float) else aligned


def gather_word(source, index, active=True):
    """``source[index]`` of a :func:`flat_word_array` per lane (0 where not ``active``)."""
    if dr.is_jit_v(mi.Float):
        return dr.gather(mi.UInt32, source, index, active)
    return int(source[int(index)]) if active else 0


def _packets(vector4, one, source, start, n: int, active):
    """[source[start + j] for j < n] per lane: ``vector4`` packets of four neighbours (one
    vector load each instead of four gathers) in JIT variants when n is a multiple of 4
    (``start`` one too), else ``one`` read per element."""
    if dr.is_jit_v(mi.Float) and n % 4 == 0:
        out = []
        first = start // 4
        for j in range(n // 4):
            v = dr.gather(vector4, source, first + j, active)
            out += [v.x, v.y, v.z, v.w]
        return out
    return [one(source, start + j, active) for j in range(n)]


def gather_words(source, start, n: int, active=True):
    """[source[start + j] for j < n] of a :func:`flat_word_array` per lane, in packets of
    four words like :func:`gather_block`."""
    return _packets(mi.Vector4u, gather_word, source, start, n, active)


def gather_block(source, start, n: int, active=True):
    """[source[start + j] for j < n] per lane, ``start`` a multiple of 4 when n is: read as
    packets of four neighbours (one vector load each instead of four gathers)."""
    return _packets(mi.Vector4f, gather, source, start, n, active)


def opaque(dtype, value):
    """``value`` as a one-lane evaluated (opaque) JIT array of ``dtype`` (``mi.Float`` or
    ``mi.UInt32``), a plain Python number in scalar variants. For a constant of one BSDF
    that differs between BSDFs (a tile's size): traced code reads it instead of holding
    it as a literal, so that BSDFs that differ only in such constants trace identical
    code (one callable in a render's kernel, shared calibration kernels; as
    :meth:`.bsdf.cloth.ClothBSDF._parameter` does for float parameters)."""
    if dr.is_jit_v(mi.Float):
        return dr.opaque(dtype, value)
    return float(value) if dtype is mi.Float else int(value)


class Extent:
    """A size in texels (a tile's width or height) for traced code: ``n`` the Python int
    (array shapes, host-side arithmetic), and :func:`opaque` copies of it as a float
    (``f``), its reciprocal (``rcp``: ``x * rcp`` is what ``x / n`` traced with a Python
    int, which Dr.Jit turns into a product by the rounded reciprocal), ``f - 1``
    (``last_f``) and as unsigned ints (``u``, ``last_u = n - 1``, ``u1 = n + 1``)."""

    __slots__ = ("n", "f", "rcp", "last_f", "u", "last_u", "u1")

    def __init__(self, n: int):
        self.n = n = int(n)
        self.f = opaque(mi.Float, float(n))
        self.rcp = opaque(mi.Float, 1.0 / n)
        self.last_f = opaque(mi.Float, float(n - 1))
        self.u = opaque(mi.UInt32, n)
        self.last_u = opaque(mi.UInt32, n - 1)
        self.u1 = opaque(mi.UInt32, n + 1)
