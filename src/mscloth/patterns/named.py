"""Patterns by name: ``plain``, ``twill-2-1-S``, ``satin-8-3``, ``basket-2``, ``jersey``,
``rib-2-2``, ``garter``, ``seed``... and WIF files by path.

A name is a weave or knit followed by its integer arguments, joined by ``-``; missing
arguments take the constructor's defaults. ``weft-faced`` satins are ``sateen-N-STEP``.
"""
from __future__ import annotations

import numpy as np

from ..errors import PatternError
from . import weaves
from .draft import Draft


def _knit(function_name: str):
    def make(*args):
        from . import knit  # knits are optional at import time of this module

        return getattr(knit, function_name)(*args)
    return make


#: name -> (constructor, number of integer arguments it takes at most, help)
NAMED = {
    "plain": (weaves.plain, 0, "plain"),
    "twill": (weaves.twill, 2, "twill-OVER-UNDER[-S|Z], e.g. twill-2-1-S"),
    "satin": (lambda n=5, step=2: weaves.satin(n, step, warp_faced=True), 2, "satin-N-STEP, e.g. satin-8-3"),
    "sateen": (lambda n=5, step=2: weaves.satin(n, step, warp_faced=False), 2, "sateen-N-STEP"),
    "basket": (weaves.basket, 1, "basket-N"),
    "jersey": (_knit("jersey"), 0, "jersey (stockinette)"),
    "rib": (_knit("rib"), 2, "rib-K-P, e.g. rib-1-1, rib-2-2"),
    "garter": (_knit("garter"), 0, "garter"),
    "seed": (_knit("seed"), 0, "seed (moss)"),
}


def pattern_names() -> str:
    return ", ".join(help_text for _, _, help_text in NAMED.values())


def is_wif_path(spec) -> bool:
    return str(spec).lower().endswith(".wif")


def named_pattern(spec: str):
    """The Draft (weaves) or KnitPattern (knits) a name stands for, or a WIF file's Draft."""
    if is_wif_path(spec):
        from .wif import read_wif

        return read_wif(spec)
    parts = str(spec).strip().split("-")
    name, raw = parts[0].lower(), parts[1:]
    if name not in NAMED:
        raise PatternError(f"unknown pattern {spec!r}: expected one of {pattern_names()}, "
                           "a .wif file or a maps directory")
    make, max_args, help_text = NAMED[name]
    direction = None
    if name == "twill" and raw and raw[-1].upper() in ("S", "Z"):
        direction = raw.pop().upper()
    try:
        args = [int(a) for a in raw]
    except ValueError:
        raise PatternError(f"pattern {spec!r}: arguments must be integers ({help_text})") from None
    if len(args) > max_args:
        raise PatternError(f"pattern {spec!r}: too many arguments ({help_text})")
    if direction is not None:
        while len(args) < 2:
            args.append(2)
        args.append(direction)
    result = make(*args)
    if isinstance(result, np.ndarray):  # a weave's drawdown
        return Draft(result, name=str(spec))
    return result
