"""A weave draft: the drawdown plus what a weaver records about each thread."""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from ..errors import PatternError
from .weaves import validate_drawdown

#: Thread spacing and yarn thickness of drafts that do not say (millimetres).
DEFAULT_SPACING_MM = 0.5
DEFAULT_THICKNESS_MM = 0.4


def _per_thread(name: str, value, count: int, default, width: int | None = None) -> np.ndarray:
    """Broadcast ``value`` (scalar / one triple / one entry per thread) to ``count`` threads."""
    shape = (count,) if width is None else (count, width)
    if value is None:
        value = default
    arr = np.asarray(value, dtype=np.float64)
    if width is not None and arr.shape == (width,):
        arr = np.broadcast_to(arr, shape)
    elif arr.ndim == 0 and width is None:
        arr = np.full(shape, float(arr))
    if arr.shape != shape:
        raise PatternError(f"Draft.{name}: expected {'one value' if width is None else f'one {width}-vector'} "
                           f"or one per thread (shape {shape}), got shape {arr.shape}")
    if not np.all(np.isfinite(arr)):
        raise PatternError(f"Draft.{name}: expected finite values")
    return np.array(arr, dtype=np.float64)


@dataclass(eq=False)
class Draft:
    """One repeat of a woven fabric.

    Attributes:
        drawdown: bool array (weft picks, warp ends), True where the warp thread is on top.
        warp_colors, weft_colors: (n, 3) sRGB colours in [0, 1] as a weaving program shows
            them (the map generator converts them to linear albedo).
        warp_spacing, weft_spacing: (n,) distance between neighbouring thread centres, mm.
        warp_thickness, weft_thickness: (n,) yarn diameter, mm.
        name: a label (pattern name or file name).
    """

    drawdown: np.ndarray
    warp_colors: np.ndarray | None = None
    weft_colors: np.ndarray | None = None
    warp_spacing: np.ndarray | None = None
    weft_spacing: np.ndarray | None = None
    warp_thickness: np.ndarray | None = None
    weft_thickness: np.ndarray | None = None
    name: str = ""
    meta: dict = field(default_factory=dict)

    def __post_init__(self):
        self.drawdown = validate_drawdown(self.drawdown)
        n_weft, n_warp = self.drawdown.shape
        self.warp_colors = _per_thread("warp_colors", self.warp_colors, n_warp, (1.0, 1.0, 1.0), 3)
        self.weft_colors = _per_thread("weft_colors", self.weft_colors, n_weft, (1.0, 1.0, 1.0), 3)
        self.warp_spacing = _per_thread("warp_spacing", self.warp_spacing, n_warp, DEFAULT_SPACING_MM)
        self.weft_spacing = _per_thread("weft_spacing", self.weft_spacing, n_weft, DEFAULT_SPACING_MM)
        self.warp_thickness = _per_thread("warp_thickness", self.warp_thickness, n_warp, DEFAULT_THICKNESS_MM)
        self.weft_thickness = _per_thread("weft_thickness", self.weft_thickness, n_weft, DEFAULT_THICKNESS_MM)
        for name in ("warp_colors", "weft_colors"):
            arr = getattr(self, name)
            if np.any(arr < 0.0) or np.any(arr > 1.0):
                raise PatternError(f"Draft.{name}: expected sRGB values in [0, 1], got [{arr.min():g}, {arr.max():g}]")
        for name in ("warp_spacing", "weft_spacing", "warp_thickness", "weft_thickness"):
            arr = getattr(self, name)
            if np.any(arr <= 0.0):
                raise PatternError(f"Draft.{name}: expected positive millimetres, got min {arr.min():g}")

    @property
    def n_warp(self) -> int:
        return self.drawdown.shape[1]

    @property
    def n_weft(self) -> int:
        return self.drawdown.shape[0]

    @property
    def size_mm(self) -> tuple[float, float]:
        """(width along the weft = sum of warp spacings, height = sum of weft spacings)."""
        return float(self.warp_spacing.sum()), float(self.weft_spacing.sum())

    def __repr__(self) -> str:
        w, h = self.size_mm
        return f"Draft({self.name or 'unnamed'!r}, {self.n_weft} picks x {self.n_warp} ends, {w:.2f} x {h:.2f} mm)"
