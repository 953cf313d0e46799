"""Registering mscloth's plugins with Mitsuba, once per variant."""
from __future__ import annotations

import mitsuba as mi

from ..errors import ClothError

_registered: dict[str, type] = {}


def register_plugins() -> None:
    """Register ``cloth`` for the active variant; a second call is a no-op."""
    variant = mi.variant()
    if variant is None:
        raise ClothError("mscloth.register(): no Mitsuba variant is set; call "
                         "mi.set_variant(mscloth.default_variant()) first")
    if variant in _registered:
        return
    from .cloth import make_cloth_class

    cls = make_cloth_class()
    mi.register_bsdf("cloth", lambda props: cls(props))
    _registered[variant] = cls


def cloth_class():
    """The ``cloth`` class registered for the active variant (registering if needed)."""
    register_plugins()
    return _registered[mi.variant()]
