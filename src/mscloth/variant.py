"""Choosing the Mitsuba variant, in one place.

Dr.Jit's LLVM backend needs libLLVM >= 15, and 15/16 crash on ``fminimum`` in
Mitsuba 3.9 (see docs/decisions.md), so we look for 17 or newer, 19 preferred,
and point ``DRJIT_LIBLLVM_PATH`` at it before the backend first starts.
"""
from __future__ import annotations

import glob
import os
import re
import warnings

#: Oldest libLLVM major version that renders correctly with drjit 1.5.
MIN_LLVM_MAJOR = 17
PREFERRED_LLVM_MAJOR = 19

_LLVM_GLOBS = (
    "/usr/lib/*/libLLVM.so.*",
    "/usr/lib/*/libLLVM-*.so*",
    "/usr/lib/llvm-*/lib/libLLVM.so*",
    "/usr/lib/llvm-*/lib/libLLVM-*.so*",
    "/usr/local/lib/libLLVM*.so*",
    "/opt/homebrew/opt/llvm/lib/libLLVM.dylib",
)


def _llvm_major(path: str) -> int | None:
    name = os.path.basename(path)
    m = re.search(r"libLLVM[-.](?:so\.)?(\d+)", name) or re.search(r"llvm-(\d+)", path)
    return int(m.group(1)) if m else None


def find_libllvm() -> str | None:
    """Path of the best usable libLLVM on this machine, or None.

    An explicit ``DRJIT_LIBLLVM_PATH`` wins if it exists. Otherwise the newest
    library whose major version is >= MIN_LLVM_MAJOR, preferring 19.
    """
    env = os.environ.get("DRJIT_LIBLLVM_PATH")
    if env and os.path.exists(env):
        return env
    found = {}
    for pattern in _LLVM_GLOBS:
        for path in glob.glob(pattern):
            major = _llvm_major(path)
            if major is not None and major >= MIN_LLVM_MAJOR and os.path.isfile(path):
                found.setdefault(major, path)
    if not found:
        return None
    if PREFERRED_LLVM_MAJOR in found:
        return found[PREFERRED_LLVM_MAJOR]
    return found[max(found)]


def configure_llvm() -> str | None:
    """Point Dr.Jit at a usable libLLVM (sets DRJIT_LIBLLVM_PATH); returns its path."""
    path = find_libllvm()
    if path is not None:
        os.environ["DRJIT_LIBLLVM_PATH"] = path
    return path


def _backend_works(backend_name: str) -> bool:
    import drjit as dr

    try:
        return bool(dr.has_backend(getattr(dr.JitBackend, backend_name)))
    except Exception:  # a broken driver must not stop us from falling back
        return False


def variant_unavailable(variant: str) -> str | None:
    """Why ``variant`` cannot run on this machine (one line), or None if it can.

    ``mi.set_variant`` of a JIT variant whose backend does not start raises an ImportError
    about uninitialised thread state; this says which backend is missing instead.
    """
    if variant.startswith("cuda_") and not _backend_works("CUDA"):
        return "no CUDA device works on this machine (Dr.Jit's CUDA backend did not start)"
    if variant.startswith("llvm_"):
        path = configure_llvm()
        if path is None:
            return (f"no libLLVM >= {MIN_LLVM_MAJOR} found (apt-get install libllvm19, "
                    "or set DRJIT_LIBLLVM_PATH)")
        if not _backend_works("LLVM"):
            return f"Dr.Jit's LLVM backend did not start with {path}"
    return None


def default_variant() -> str:
    """The variant mscloth renders with on this machine.

    ``cuda_ad_rgb`` when a CUDA device works, else ``llvm_ad_rgb`` when a usable
    libLLVM is found, else ``scalar_rgb`` (with a warning: it is ~500x slower).
    """
    import mitsuba as mi

    available = set(mi.variants())
    if "cuda_ad_rgb" in available and _backend_works("CUDA"):
        return "cuda_ad_rgb"
    if "llvm_ad_rgb" in available and configure_llvm() is not None and _backend_works("LLVM"):
        return "llvm_ad_rgb"
    warnings.warn(
        "mscloth: no CUDA device and no libLLVM >= %d found; falling back to the slow "
        "'scalar_rgb' variant. Install Debian's libllvm19 (apt-get install libllvm19) "
        "or set DRJIT_LIBLLVM_PATH." % MIN_LLVM_MAJOR,
        RuntimeWarning,
        stacklevel=2,
    )
    return "scalar_rgb"


def set_default_variant() -> str:
    """Set (and return) :func:`default_variant` unless a variant is already active."""
    import mitsuba as mi

    current = mi.variant()
    if current is None:
        current = default_variant()
        mi.set_variant(current)
    return current
