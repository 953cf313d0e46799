"""Registering Python plugins with Mitsuba once per variant.

Plugin classes bind to the Mitsuba variant active when they are defined, so each plugin
has a factory that defines its class; we call it once per variant and remember the class.
"""
from __future__ import annotations

from typing import Callable

import mitsuba as mi

from .errors import ClothError

_classes: dict[tuple[str, str], type] = {}


def plugin_class(name: str, register: Callable, make_class: Callable[[], type]) -> type:
    """The class of plugin ``name`` for the active variant, defining and registering it
    (``register`` is e.g. ``mi.register_bsdf``) the first time; later calls are no-ops."""
    variant = mi.variant()
    if variant is None:
        raise ClothError(f"registering '{name}': no Mitsuba variant is set; call "
                         "mi.set_variant(mscloth.default_variant()) first")
    key = (variant, name)
    if key not in _classes:
        cls = make_class()
        register(name, lambda props: cls(props))
        _classes[key] = cls
    return _classes[key]


def registered_class(name: str) -> type | None:
    """The class of plugin ``name`` for the active variant, or None if it was never
    registered (then no scene of this variant holds one)."""
    return _classes.get((mi.variant(), name))
