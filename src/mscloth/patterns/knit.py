"""Weft-knitted stitch patterns: which stitches are knit and which purl, and yarn colours.

A `KnitPattern` holds one repeat of a knitted fabric as a grid of stitches, shape
(courses, wales): course i is row i (one yarn per course in weft knitting), wale j is column j.
``stitches[i, j]`` is 1 for a knit stitch (the two legs of the loop, a "V", are seen from the
face) and 0 for a purl stitch (the loop head and sinker arcs, a horizontal "bump", are seen
from the face). The grid tiles periodically in both directions.

Colours are sRGB in [0, 1], as a knitting chart or a colour picker gives them; the map
generator (`mscloth.maps.knit.knit_maps`) converts them to linear albedo.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field
from numbers import Integral
from typing import Any

import numpy as np

from ..errors import PatternError
from .weaves import binary_grid

KNIT = 1
PURL = 0


def validate_stitches(arr: Any) -> np.ndarray:
    """Return ``arr`` as a new 2-D int8 stitch grid of 0/1, or raise PatternError."""
    grid = binary_grid(arr, "KnitPattern.stitches", "courses, wales",
                       "the values 0 (purl) and 1 (knit), or bools")
    return grid.astype(np.int8)


def _colors(name: str, value: Any, count: int, what: str) -> np.ndarray | None:
    """None, or ``value`` as a (count, 3) float64 sRGB array in [0, 1] (one triple broadcast)."""
    if value is None:
        return None
    try:
        arr = np.asarray(value, dtype=np.float64)
    except (TypeError, ValueError):
        raise PatternError(f"KnitPattern.{name}: expected an RGB triple or a ({count}, 3) array "
                           f"(one sRGB colour per {what}), got {value!r}") from None
    if arr.shape == (3,):
        arr = np.broadcast_to(arr, (count, 3))
    if arr.shape != (count, 3):
        raise PatternError(f"KnitPattern.{name}: expected an RGB triple or a ({count}, 3) array "
                           f"(one sRGB colour per {what}), got shape {arr.shape}")
    if not np.all(np.isfinite(arr)) or arr.min() < 0.0 or arr.max() > 1.0:
        raise PatternError(f"KnitPattern.{name}: expected sRGB values in [0, 1], got range "
                           f"[{np.nanmin(arr):g}, {np.nanmax(arr):g}]")
    return np.array(arr, dtype=np.float64)


@dataclass(eq=False)
class KnitPattern:
    """One repeat of a weft-knitted fabric (see the module docstring).

    Attributes:
        stitches: int8 array (n_courses, n_wales), 1 = knit, 0 = purl (bools and 0/1 accepted).
        course_colors: (n_courses, 3) sRGB in [0, 1], one colour per course (row), or None.
        wale_colors: (n_wales, 3) sRGB in [0, 1], one colour per wale (column), or None.
            If both are given, ``course_colors`` wins: in weft knitting a course is one yarn,
            so a stitch takes the colour of its course's yarn. Neither given: white.
            One RGB triple is accepted for either and broadcast.
        name: a label.
        meta: free-form, JSON-serialisable extras.
    """

    stitches: np.ndarray
    course_colors: np.ndarray | None = None
    wale_colors: np.ndarray | None = None
    name: str = ""
    meta: dict = field(default_factory=dict)

    def __post_init__(self) -> None:
        self.stitches = validate_stitches(self.stitches)
        n_courses, n_wales = self.stitches.shape
        self.course_colors = _colors("course_colors", self.course_colors, n_courses, "course")
        self.wale_colors = _colors("wale_colors", self.wale_colors, n_wales, "wale")
        if not isinstance(self.name, str):
            raise PatternError(f"KnitPattern.name: expected a str, got "
                               f"{type(self.name).__name__}")
        if not isinstance(self.meta, dict):
            raise PatternError(f"KnitPattern.meta: expected a dict, got "
                               f"{type(self.meta).__name__}")

    @property
    def n_courses(self) -> int:
        """Rows of the repeat (one yarn each)."""
        return int(self.stitches.shape[0])

    @property
    def n_wales(self) -> int:
        """Columns of the repeat."""
        return int(self.stitches.shape[1])

    def stitch_colors(self) -> np.ndarray:
        """(n_courses, n_wales, 3) sRGB colour of every stitch (course colours win; white)."""
        shape = (self.n_courses, self.n_wales, 3)
        if self.course_colors is not None:
            return np.array(np.broadcast_to(self.course_colors[:, None, :], shape))
        if self.wale_colors is not None:
            return np.array(np.broadcast_to(self.wale_colors[None, :, :], shape))
        return np.ones(shape)

    def tiled(self, courses: int = 1, wales: int = 1) -> "KnitPattern":
        """This pattern repeated ``courses`` times down and ``wales`` times across.

        Useful to make a tile physically square: with ``loop_aspect`` a (course height /
        wale width) the tile is n_courses * a / n_wales wide-units tall, e.g. ``jersey()
        .tiled(5, 4)`` is square at a = 0.8.
        """
        for label, n in (("courses", courses), ("wales", wales)):
            if isinstance(n, bool) or not isinstance(n, Integral) or n < 1:
                raise PatternError(f"KnitPattern.tiled: {label} must be an int >= 1, "
                                   f"got {n!r}")
        return KnitPattern(
            stitches=np.tile(self.stitches, (courses, wales)),
            course_colors=None if self.course_colors is None
            else np.tile(self.course_colors, (courses, 1)),
            wale_colors=None if self.wale_colors is None
            else np.tile(self.wale_colors, (wales, 1)),
            name=self.name, meta=dict(self.meta))


def _count(label: str, value: Any, lo: int) -> int:
    if isinstance(value, bool) or not isinstance(value, Integral) or value < lo:
        raise PatternError(f"{label} must be an int >= {lo}, got {value!r}")
    return int(value)


def _named(stitches: np.ndarray, course_colors: Any, wale_colors: Any, name: str
           ) -> KnitPattern:
    """A named pattern; colour lists longer than the repeat tile the stitches to fit.

    ``jersey(course_colors=[red, red, blue])`` is a 3-course striped jersey: the stitch
    repeat is extended to the least common multiple of its size and the colour count.
    """
    reps = [1, 1]
    for axis, colors in ((0, course_colors), (1, wale_colors)):
        if colors is None:
            continue
        arr = np.asarray(colors, dtype=object)
        if arr.ndim == 2 and arr.shape[0] >= 1:
            n = stitches.shape[axis]
            reps[axis] = math.lcm(n, arr.shape[0]) // n
    stitches = np.tile(stitches, reps)
    course_colors = _cycle(course_colors, stitches.shape[0])
    wale_colors = _cycle(wale_colors, stitches.shape[1])
    return KnitPattern(stitches, course_colors, wale_colors, name=name)


def _cycle(colors: Any, count: int) -> Any:
    """Repeat a (k, 3) colour list to ``count`` rows when k divides count; else unchanged."""
    if colors is None:
        return None
    arr = np.asarray(colors, dtype=object)
    if arr.ndim == 2 and arr.shape[0] >= 1 and count % arr.shape[0] == 0:
        return np.tile(np.asarray(colors), (count // arr.shape[0], 1))
    return colors


def jersey(course_colors: Any = None, wale_colors: Any = None) -> KnitPattern:
    """Single jersey (stockinette): every stitch knit; face shows columns of V's. 1x1 repeat.

    Every named constructor takes ``course_colors`` / ``wale_colors`` (sRGB); a list of k
    colours extends the repeat to a multiple of k courses / wales (stripes).
    """
    return _named(np.ones((1, 1), np.int8), course_colors, wale_colors, "jersey")


def reverse_jersey(course_colors: Any = None, wale_colors: Any = None) -> KnitPattern:
    """The back of jersey: every stitch purl (rows of bumps). 1x1 repeat."""
    return _named(np.zeros((1, 1), np.int8), course_colors, wale_colors, "reverse_jersey")


def rib(k: int = 1, p: int = 1, course_colors: Any = None,
        wale_colors: Any = None) -> KnitPattern:
    """k x p rib: per course, k knit wales then p purl wales; repeat (1, k + p).

    ``rib(2, 2).stitches`` is ``[[1, 1, 0, 0]]``.
    """
    k = _count("rib: k (knit wales)", k, 1)
    p = _count("rib: p (purl wales)", p, 1)
    row = np.array([KNIT] * k + [PURL] * p, np.int8)[None, :]
    return _named(row, course_colors, wale_colors, f"rib{k}x{p}")


def garter(course_colors: Any = None, wale_colors: Any = None) -> KnitPattern:
    """Garter stitch: courses alternate all knit / all purl; repeat (2, 1)."""
    return _named(np.array([[KNIT], [PURL]], np.int8), course_colors, wale_colors, "garter")


def seed(course_colors: Any = None, wale_colors: Any = None) -> KnitPattern:
    """Seed (moss) stitch: knit and purl alternate along courses and wales; repeat (2, 2)."""
    return _named(np.array([[KNIT, PURL], [PURL, KNIT]], np.int8), course_colors,
                  wale_colors, "seed")


KNIT_PATTERNS = {"jersey": jersey, "reverse_jersey": reverse_jersey, "rib": rib,
                 "garter": garter, "seed": seed}

__all__ = ["KnitPattern", "KNIT", "PURL", "validate_stitches", "jersey", "reverse_jersey",
           "rib", "garter", "seed", "KNIT_PATTERNS"]
