"""Named weave drawdowns.

A drawdown is a 2-D bool array of shape (weft picks, warp ends): ``drawdown[i, j]`` is True
where warp end j passes over weft pick i (warp up), False where the weft is on top. One array
is one repeat of the weave; it tiles periodically in both directions.
"""
from __future__ import annotations

import math
from typing import Any

import numpy as np

from ..errors import PatternError


def plain() -> np.ndarray:
    """Plain (tabby) weave: every thread alternates over one, under one."""
    return np.array([[True, False], [False, True]], dtype=bool)


def twill(over: int = 2, under: int = 2, direction: str = "Z") -> np.ndarray:
    """Twill: each warp end floats over ``over`` picks and under ``under``, shifted by one
    pick per end, so the floats line up in diagonals. ``direction`` "Z" (right-hand: the
    diagonal rises to the right, in increasing u and v) or "S" (left-hand)."""
    over, under = _count("twill over", over, 1), _count("twill under", under, 1)
    if direction not in ("Z", "S"):
        raise PatternError(f"twill direction must be 'Z' or 'S', got {direction!r}")
    n = over + under
    step = -1 if direction == "Z" else 1
    i, j = np.indices((n, n))
    return (i + step * j) % n < over


def satin(n: int = 5, step: int = 2, warp_faced: bool = True) -> np.ndarray:
    """Satin (warp-faced) or sateen: each end interlaces once in ``n`` picks, the
    interlacing moving ``step`` picks per end. ``step`` must be coprime with ``n`` and in
    [2, n - 2], otherwise interlacings touch and it is a twill, not a satin."""
    n = _count("satin n", n, 5)
    step = _count("satin step", step, 1)
    if not 2 <= step <= n - 2 or math.gcd(n, step) != 1:
        valid = [s for s in range(2, n - 1) if math.gcd(n, s) == 1]
        raise PatternError(f"satin step must be coprime with n={n} and in [2, {n - 2}] "
                           f"(valid: {valid}), got {step}")
    i, j = np.indices((n, n))
    interlacing = (i - step * j) % n == 0
    return ~interlacing if warp_faced else interlacing


def basket(n: int = 2) -> np.ndarray:
    """Basket weave: plain weave with groups of ``n`` ends and ``n`` picks."""
    n = _count("basket n", n, 1)
    i, j = np.indices((2 * n, 2 * n))
    return (i // n + j // n) % 2 == 0


def _count(name: str, value: Any, minimum: int) -> int:
    if isinstance(value, bool) or not isinstance(value, (int, np.integer)) or not minimum <= value <= 64:
        raise PatternError(f"{name} must be an integer in [{minimum}, 64], got {value!r}")
    return int(value)


def binary_grid(arr: Any, field: str, axes: str, values: str) -> np.ndarray:
    """``arr`` as a new non-empty 2-D bool grid, or a PatternError naming ``field``.

    Accepted: bools or the numbers 0 and 1. Other values (2, 0.5, strings) are refused
    rather than truth-tested, since they usually mean a draft was parsed wrongly. ``axes``
    names the two dimensions and ``values`` what 0 and 1 mean, for the messages.
    """
    try:
        raw = np.asarray(arr)
    except (TypeError, ValueError) as exc:  # ragged nested lists
        raise PatternError(f"{field}: expected a 2-D array of {values}, got unreadable input "
                           f"({exc})") from None
    if raw.ndim != 2:
        raise PatternError(f"{field}: expected a 2-D array ({axes}), got "
                           f"{raw.ndim} dimension(s) with shape {raw.shape}")
    if raw.size == 0:
        raise PatternError(f"{field}: expected a non-empty array, got shape {raw.shape}")
    if raw.dtype == bool:
        return raw.copy()
    if raw.dtype.kind not in "iuf":
        raise PatternError(f"{field}: expected {values}, got dtype {raw.dtype}")
    if not np.all((raw == 0) | (raw == 1)):
        raise PatternError(f"{field}: expected only {values}")
    return raw == 1


def validate_drawdown(arr: Any) -> np.ndarray:
    """Return ``arr`` as a new 2-D bool drawdown, or raise PatternError saying what is wrong."""
    return binary_grid(arr, "drawdown", "weft picks, warp ends", "bools or the values 0 and 1")


__all__ = ["plain", "twill", "satin", "basket", "binary_grid", "validate_drawdown"]
