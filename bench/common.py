"""What the measuring scripts in bench/ share: Mitsuba set-up for the package in src/, and
NAME=VALUE settings (cloth parameters, class attributes of the cloth BSDF or of its footprint
estimator)."""
from __future__ import annotations

import sys


def emit(text: str, out: str | None) -> None:
    """Print a result table and, with ``out``, append it to that Markdown file (make bench
    collects the scripts' tables in bench/RESULTS.md this way)."""
    print(text)
    if out:
        with open(out, "a") as f:
            f.write(text + "\n\n")


def setup_mitsuba():
    """The default variant and the ``cloth`` plugin, from this checkout's src/."""
    sys.path.insert(0, "src")
    import mitsuba as mi

    import mscloth
    mscloth.setup_mitsuba()
    return mi


def parse_value(text: str):
    """'true' / 'false', 'none', an int, a float, or a Python tuple or list literal (the
    estimator's rules by roughness: '()' empties one)."""
    lowered = text.lower()
    if lowered in ("true", "false"):
        return lowered == "true"
    if lowered == "none":
        return None
    if text.strip()[:1] in ("(", "["):
        import ast

        return ast.literal_eval(text)
    try:
        return int(text)
    except ValueError:
        pass
    try:
        return float(text)
    except ValueError:
        return text


def parse_settings(items) -> dict:
    """['NAME=VALUE', ...] -> {NAME: value}."""
    out = {}
    for item in items:
        key, value = item.split("=", 1)
        out[key] = parse_value(value)
    return out


def attribute_owner(name: str):
    """The class whose attribute ``name`` an experiment sets: the footprint estimator's
    (its tuning constants, e.g. MAX_PROBES, RESIDUAL_GRID, and ``shading_hash``) if it has
    one, else the lobe samplers' (FOLD_FLAKES), else the shading's (LOOP_DIRECTIONS), else
    the uploaded tables' (CHANNEL_MAJOR), else the ``clothpath`` module's
    (DEFAULT_UV_FILTER), else the sky albedo table's module (SHAPE_STEPS), else the
    ``cloth`` BSDF class of the active variant."""
    from mscloth.bsdf.cloth_shading import ClothShading
    from mscloth.bsdf.footprint_data import FootprintData
    from mscloth.bsdf.footprint_estimator import FootprintEstimator
    from mscloth.bsdf.lobe_mixture import LobeSamplers
    from mscloth.bsdf import sky_albedo
    from mscloth.bsdf.registry import cloth_class
    from mscloth.integrators import clothpath

    for owner in (FootprintEstimator, LobeSamplers, ClothShading, FootprintData, clothpath, sky_albedo):
        if hasattr(owner, name):
            return owner
    return cloth_class()


def set_class_attributes(attrs: dict) -> dict:
    """Set class attributes of the ``cloth`` BSDF or its footprint estimator (an
    experiment, see :func:`attribute_owner`); returns the old values."""
    saved = {k: getattr(attribute_owner(k), k) for k in attrs}
    for k, v in attrs.items():
        setattr(attribute_owner(k), k, v)
    return saved
