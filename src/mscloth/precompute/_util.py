"""Small helpers of the precomputation: progress lines, per-direction worker threads, pitch."""
from __future__ import annotations

import os
import sys
import threading
import time
from concurrent.futures import ThreadPoolExecutor

import numpy as np


#: Held while one progress line is written. Mitsuba constructs a scene's plugins on parallel
#: threads, so the tables of several cloths are built at once; ``print`` writes the text and
#: its newline separately, and two builds' lines ran into one another.
_LINE_LOCK = threading.Lock()


def write_line(stream, text: str) -> None:
    """Write ``text`` and its newline to ``stream`` in one call, under :data:`_LINE_LOCK`."""
    with _LINE_LOCK:
        stream.write(text + "\n")
        stream.flush()


class Progress:
    """Progress lines on stderr: ``mscloth precompute [<label>]: <what> <done>/<total> <unit>``.

    ``label`` names whose tables these are (a cloth's id and pattern); every line carries it,
    and each is written whole (:func:`write_line`), so parallel builds can be told apart.
    At most one line every ``interval`` seconds (plus the last one), so logs stay short.
    ``enabled=False`` prints nothing.
    """

    def __init__(self, enabled: bool = True, interval: float = 1.0, stream=None, label: str = ""):
        self.enabled = bool(enabled)
        self.interval = interval
        self.stream = stream
        self.prefix = f"mscloth precompute [{label}]: " if label else "mscloth precompute: "
        self._last = 0.0

    def __call__(self, what: str, done: int, total: int, unit: str = "") -> None:
        if not self.enabled:
            return
        now = time.perf_counter()
        if done < total and done > 1 and now - self._last < self.interval:
            return
        self._last = now
        self._write(f"{what} {done}/{total}{' ' + unit if unit else ''}")

    def note(self, text: str) -> None:
        if self.enabled:
            self._write(text)

    def _write(self, text: str) -> None:
        # sys.stderr looked up per line: tests and callers may redirect it after construction.
        write_line(self.stream if self.stream is not None else sys.stderr, self.prefix + text)


def default_workers() -> int:
    """Threads for per-direction work (NumPy releases the GIL inside its loops)."""
    try:
        n = len(os.sched_getaffinity(0))
    except (AttributeError, OSError):
        n = os.cpu_count() or 1
    return max(1, min(8, n))


def map_ordered(fn, items, workers: int | None = None, on_done=None) -> list:
    """[fn(x) for x in items], on ``workers`` threads; ``on_done(n_done, n_total)`` after each."""
    items = list(items)
    workers = default_workers() if workers is None else max(1, int(workers))
    total = len(items)
    if workers == 1 or total <= 1:
        out = []
        for i, x in enumerate(items):
            out.append(fn(x))
            if on_done is not None:
                on_done(i + 1, total)
        return out
    results = [None] * total
    with ThreadPoolExecutor(max_workers=workers) as pool:
        futures = {pool.submit(fn, x): i for i, x in enumerate(items)}
        done = 0
        from concurrent.futures import as_completed
        for fut in as_completed(futures):
            results[futures[fut]] = fut.result()
            done += 1
            if on_done is not None:
                on_done(done, total)
    return results


def texel_pitch(shape, meta: dict | None = None) -> tuple[float, float]:
    """(px, py): texel size along x (columns) and y (rows) in tile-width units.

    ``meta['tile_size_mm']`` = (width, height) gives the tile's aspect; without it the tile is
    taken as physically square.
    """
    H, W = shape
    aspect = 1.0
    if meta:
        size = meta.get("tile_size_mm")
        try:
            if size is not None and float(size[0]) > 0 and float(size[1]) > 0:
                aspect = float(size[1]) / float(size[0])
        except (TypeError, ValueError, IndexError):
            aspect = 1.0
    return 1.0 / W, aspect / H


def as_pitch(pitch, shape) -> tuple[float, float]:
    if pitch is None:
        return texel_pitch(shape, None)
    px, py = (float(p) for p in pitch)
    if not (np.isfinite(px) and np.isfinite(py) and px > 0 and py > 0):
        raise ValueError(f"pitch must be two positive numbers, got {pitch!r}")
    return px, py
