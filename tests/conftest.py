"""Test session setup: pick the Mitsuba variant before any test module imports plugins.

``import mscloth`` first: it points DRJIT_LIBLLVM_PATH at a usable libLLVM before
Dr.Jit's LLVM backend starts.
"""
import mscloth  # noqa: F401  (sets DRJIT_LIBLLVM_PATH)
import mitsuba as mi

mi.set_variant("llvm_ad_rgb")
