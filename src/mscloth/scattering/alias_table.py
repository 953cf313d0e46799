"""Alias tables (Walker 1977, Vose 1991): O(1) sampling of discrete distributions.

Sampling a tabulated lobe by inverting its CDF costs a binary search per sample, a chain
of dependent gathers (12 for a 64 x 64 table): the fibre-level BSDF's kernel time grew by
58% with its sheen and diffuse tables. An alias table picks a cell with one read: cell j
with probability N p_j / N, else its alias, and what is left of the uniform number places
the sample inside the cell.
"""
from __future__ import annotations

import drjit as dr
import mitsuba as mi
import numpy as np

from ..jit_arrays import flat_array, flat_word_array, gather, gather_word

#: The largest float32 below 1.
ONE_MINUS_EPSILON = float(np.nextafter(np.float32(1.0), np.float32(0.0)))


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


class AliasTable:
    """``rows`` discrete distributions over ``cells`` cells each, in Dr.Jit memory.

    ``probabilities`` are the ones sampling realises with the thresholds as stored
    (float32), so densities built from them match the samples exactly."""

    def __init__(self, weights: np.ndarray):
        _, threshold, alias = build_alias(weights)
        self.rows, self.cells = threshold.shape
        threshold = threshold.astype(np.float32)
        self.probabilities = realised_probabilities(threshold.astype(np.float64), alias)
        self._threshold = flat_array(threshold)
        self._alias = flat_word_array(alias)

    def sample(self, row, u):
        """(cell, v): a cell of distribution ``row`` for a uniform ``u`` in [0, 1), and a
        fresh uniform ``v`` in [0, 1) from what is left of ``u`` (coarser by a factor
        ``cells``), for placing the sample inside the cell."""
        x = u * self.cells
        j = mi.UInt32(dr.clip(dr.floor(x), 0, self.cells - 1))
        frac = x - mi.Float(j)
        index = row * self.cells + j
        t = gather(self._threshold, index)
        keep = frac < t
        cell = dr.select(keep, j, mi.UInt32(gather_word(self._alias, index)))
        v = dr.select(keep, frac / dr.maximum(t, 1e-12), (frac - t) / dr.maximum(1.0 - t, 1e-12))
        return cell, dr.clip(v, 0.0, ONE_MINUS_EPSILON)
