"""Alias tables (Walker 1977, Vose 1991): O(1) sampling of discrete distributions.

Sampling a tabulated lobe by inverting its CDF costs a binary search per sample, a chain
of dependent gathers (12 for a 64 x 64 table): the fibre-level BSDF's kernel time grew by
58% with its sheen and diffuse tables. An alias table picks a cell with one read: cell j
with probability N p_j / N, else its alias, and what is left of the uniform number places
the sample inside the cell.

Each cell is one 32-bit word, its threshold in 16 bits and its alias in the other 16: one
read picks a cell. The tables live in memory shared by every lane of a kernel, and their
reads are cache misses more often than not (the sheen sampler's reads were a fifth of a
fibre-level BSDF call): one word instead of a float and a word halves what a sample reads.
"""
from __future__ import annotations

import drjit as dr
import mitsuba as mi
import numpy as np

from ..jit_arrays import flat_word_array, gather_word

#: The largest float32 below 1.
ONE_MINUS_EPSILON = float(np.nextafter(np.float32(1.0), np.float32(0.0)))
#: Thresholds are stored as k / 65535 (k < 2^16, 1 included); cells are at most 2^16.
THRESHOLD_STEPS = 65535
_THRESHOLD_UNIT = np.float32(1.0 / THRESHOLD_STEPS)
MAX_CELLS = 1 << 16


def build_alias(weights: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(probabilities, thresholds, aliases) of each row of ``weights`` (R, N), rows
    normalised to sum 1: cell j is kept when N u - j < threshold[j], else alias[j]."""
    w = np.asarray(weights, dtype=np.float64)
    if w.ndim != 2 or not np.all(np.isfinite(w)) or np.any(w < 0.0):
        raise ValueError(f"build_alias: expected a finite non-negative (rows, cells) array, got shape {w.shape}")
    totals = w.sum(axis=1, keepdims=True)
    if np.any(totals <= 0.0):
        raise ValueError("build_alias: a row has no weight")
    prob = w / totals
    rows, n = prob.shape
    threshold = np.ones((rows, n))
    alias = np.tile(np.arange(n), (rows, 1))
    for r in range(rows):
        scaled = (prob[r] * n).tolist()
        small = [j for j, x in enumerate(scaled) if x < 1.0]
        large = [j for j, x in enumerate(scaled) if x >= 1.0]
        t, a = threshold[r], alias[r]
        while small and large:
            s, g = small.pop(), large.pop()
            t[s] = scaled[s]
            a[s] = g
            scaled[g] -= 1.0 - scaled[s]
            (small if scaled[g] < 1.0 else large).append(g)
        # What is left holds 1 up to rounding: kept with certainty (threshold 1).
    return prob, threshold, alias


def realised_probabilities(threshold: np.ndarray, alias: np.ndarray) -> np.ndarray:
    """The probability of each cell that (threshold, alias) rows actually give."""
    rows, n = threshold.shape
    prob = np.array(threshold, dtype=np.float64)
    for r in range(rows):
        np.add.at(prob[r], alias[r], 1.0 - threshold[r])
    return prob / n


def quantised_thresholds(threshold: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(steps k, the float32 thresholds k * (1 / 65535) that sampling computes from them)."""
    steps = np.rint(np.clip(threshold, 0.0, 1.0) * THRESHOLD_STEPS).astype(np.uint32)
    return steps, steps.astype(np.float32) * _THRESHOLD_UNIT


class AliasTable:
    """``rows`` discrete distributions over ``cells`` (at most 2^16) cells each, in Dr.Jit
    memory, one 32-bit word per cell: threshold step (low 16 bits), alias (high 16 bits).

    ``probabilities`` are the ones sampling realises with the thresholds as stored
    (quantised to 1/65535), so densities built from them match the samples exactly; the
    quantisation moves a cell's probability by at most 1/65535 of a cell's share."""

    def __init__(self, weights: np.ndarray):
        _, threshold, alias = build_alias(weights)
        self.rows, self.cells = threshold.shape
        if self.cells > MAX_CELLS:
            raise ValueError(f"AliasTable: at most {MAX_CELLS} cells per row (16-bit aliases), got {self.cells}")
        steps, threshold = quantised_thresholds(threshold)
        self.probabilities = realised_probabilities(threshold.astype(np.float64), alias)
        self._words = flat_word_array(steps | (alias.astype(np.uint32) << 16))

    def sample(self, row, u):
        """(cell, v): a cell of distribution ``row`` for a uniform ``u`` in [0, 1), and a
        fresh uniform ``v`` in [0, 1) from what is left of ``u`` (coarser by a factor
        ``cells``), for placing the sample inside the cell."""
        x = u * self.cells
        j = mi.UInt32(dr.clip(dr.floor(x), 0, self.cells - 1))
        frac = x - mi.Float(j)
        word = mi.UInt32(gather_word(self._words, row * self.cells + j))
        t = mi.Float(word & 0xFFFF) * float(_THRESHOLD_UNIT)
        keep = frac < t
        cell = dr.select(keep, j, word >> 16)
        v = dr.select(keep, frac / dr.maximum(t, 1e-12), (frac - t) / dr.maximum(1.0 - t, 1e-12))
        return cell, dr.clip(v, 0.0, ONE_MINUS_EPSILON)
