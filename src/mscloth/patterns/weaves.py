"""Named weave drawdowns.

A drawdown is a 2-D bool array of shape (weft picks, warp ends): ``drawdown[i, j]`` is True
where warp end j passes over weft pick i (warp up), False where the weft is on top. One array
is one repeat of the weave; it tiles periodically in both directions.
"""
from __future__ import annotations

from typing import Any

import numpy as np

from ..errors import PatternError


def plain() -> np.ndarray:
    """Plain (tabby) weave: every thread alternates over one, under one."""
    return np.array([[True, False], [False, True]], dtype=bool)


def validate_drawdown(arr: Any) -> np.ndarray:
    """Return ``arr`` as a new 2-D bool drawdown, or raise PatternError saying what is wrong.

    Accepted: any non-empty 2-D array-like of bools or of the numbers 0 and 1. Other values
    (2, 0.5, strings) are refused rather than truth-tested, since they usually mean a draft
    was parsed wrongly.
    """
    try:
        raw = np.asarray(arr)
    except (TypeError, ValueError) as exc:  # ragged nested lists
        raise PatternError(f"drawdown: expected a 2-D array of bools, got unreadable input "
                           f"({exc})") from None
    if raw.ndim != 2:
        raise PatternError(f"drawdown: expected a 2-D array (weft picks, warp ends), got "
                           f"{raw.ndim} dimension(s) with shape {raw.shape}")
    if raw.size == 0:
        raise PatternError(f"drawdown: expected a non-empty array, got shape {raw.shape}")
    if raw.dtype == bool:
        return raw.copy()
    if raw.dtype.kind not in "iuf":
        raise PatternError(f"drawdown: expected bools or 0/1 values, got dtype {raw.dtype}")
    if not np.all((raw == 0) | (raw == 1)):
        raise PatternError("drawdown: expected only bools or the values 0 and 1")
    return raw == 1


__all__ = ["plain", "validate_drawdown"]
