"""Registering the ``cloth`` BSDF with Mitsuba, once per variant."""
from __future__ import annotations

import mitsuba as mi

from ..plugin_registry import plugin_class


def cloth_class():
    """The ``cloth`` class for the active variant (registering it the first time)."""
    from .cloth import make_cloth_class

    return plugin_class("cloth", mi.register_bsdf, make_cloth_class)


def register_plugins() -> None:
    """Register ``cloth`` for the active variant; a second call is a no-op."""
    cloth_class()
