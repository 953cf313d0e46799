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

from ..errors import ClothError

_registered: dict[str, type] = {}


def register_integrators() -> None:
    """Register ``clothpath`` for the active variant; a second call is a no-op."""
    variant = mi.variant()
    if variant is None:
        raise ClothError("register_integrators(): no Mitsuba variant is set; call "
                         "mi.set_variant(mscloth.default_variant()) first")
    if variant in _registered:
        return
    from .clothpath import make_clothpath_class

    cls = make_clothpath_class()
    mi.register_integrator("clothpath", lambda props: cls(props))
    _registered[variant] = cls


def clothpath_class():
    """The ``clothpath`` class registered for the active variant (registering if needed)."""
    register_integrators()
    return _registered[mi.variant()]


__all__ = ["clothpath_class", "register_integrators"]
