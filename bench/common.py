"""What the measuring scripts in bench/ share: Mitsuba set-up for the package in src/, and
NAME=VALUE settings (cloth parameters, class attributes of the cloth BSDF)."""
from __future__ import annotations

import sys


def setup_mitsuba():
    """The default variant and the ``cloth`` plugin, from this checkout's src/."""
    sys.path.insert(0, "src")
    import mitsuba as mi

    import mscloth
    mi.set_variant(mscloth.default_variant())
    mscloth.register()
    return mi


def parse_value(text: str):
    """'true' / 'false', an int or a float."""
    lowered = text.lower()
    if lowered in ("true", "false"):
        return lowered == "true"
    try:
        return int(text)
    except ValueError:
        return float(text)


def parse_settings(items) -> dict:
    """['NAME=VALUE', ...] -> {NAME: value}."""
    out = {}
    for item in items:
        key, value = item.split("=", 1)
        out[key] = parse_value(value)
    return out


def set_class_attributes(attrs: dict) -> dict:
    """Set class attributes of the ``cloth`` BSDF (an experiment); returns the old values."""
    from mscloth.bsdf.registry import cloth_class

    cls = cloth_class()
    saved = {k: getattr(cls, k) for k in attrs}
    for k, v in attrs.items():
        setattr(cls, k, v)
    return saved
