"""mscloth's Mitsuba integrators: ``clothpath`` (``path`` plus pixel footprints for BSDFs).

Plugin classes bind to the Mitsuba variant active when they are defined, so the class is
built by a factory once per variant, like the ``cloth`` BSDF (:mod:`mscloth.bsdf.registry`)::

    mi.set_variant("llvm_ad_rgb")
    from mscloth.integrators import register_integrators
    register_integrators()                      # idempotent per variant
    scene = mi.load_dict({..., "integrator": {"type": "clothpath", "max_depth": 8}})
"""
from __future__ import annotations

import mitsuba as mi

from ..plugin_registry import plugin_class


def clothpath_class():
    """The ``clothpath`` class for the active variant (registering it the first time)."""
    from .clothpath import make_clothpath_class

    return plugin_class("clothpath", mi.register_integrator, make_clothpath_class)


def register_integrators() -> None:
    """Register ``clothpath`` for the active variant; a second call is a no-op."""
    clothpath_class()


__all__ = ["clothpath_class", "register_integrators"]
