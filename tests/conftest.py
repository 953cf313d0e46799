"""Test session setup: pick the Mitsuba variant before any test module imports plugins.

``import mscloth`` first: it points DRJIT_LIBLLVM_PATH at a usable libLLVM before
Dr.Jit's LLVM backend starts.
"""
import atexit
import os
import shutil
import tempfile

# Multi-scale tables go to a fresh cache per test session: tests never touch the user's
# ~/.cache/mscloth, and every run exercises the table builds.
os.environ["MSCLOTH_CACHE"] = tempfile.mkdtemp(prefix="mscloth-test-cache-")
atexit.register(shutil.rmtree, os.environ["MSCLOTH_CACHE"], True)

import mscloth  # noqa: E402,F401  (sets DRJIT_LIBLLVM_PATH)
import mitsuba as mi  # noqa: E402

mi.set_variant("llvm_ad_rgb")

import gc

import pytest


@pytest.fixture(autouse=True)
def _collect_garbage():
    """Free unreachable plugin instances between tests.

    Dr.Jit traces a virtual call by calling into every registered BSDF instance; if the
    garbage collector frees an unreachable Python-defined instance (kept alive only by a
    reference cycle, e.g. a traceback) in the middle of such a trace, the trace calls a
    freed object. Collecting between tests keeps the registry free of such instances.
    """
    yield
    gc.collect()
