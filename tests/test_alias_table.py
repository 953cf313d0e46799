"""Alias tables (scattering/alias_table.py): the cells they pick and the uniform they leave."""
import mitsuba as mi
import numpy as np
import pytest

if mi.variant() is None:  # normally done by conftest.py
    mi.set_variant("llvm_ad_rgb")

from mscloth.scattering.alias_table import AliasTable, build_alias, realised_probabilities  # noqa: E402


def test_thresholds_and_aliases_realise_the_weights():
    rng = np.random.default_rng(1)
    w = rng.random((5, 37)) ** 3
    w[2, :30] = 0.0  # empty cells and one dominant cell
    w[3] = 0.0
    w[3, 7] = 1.0
    prob, threshold, alias = build_alias(w)
    np.testing.assert_allclose(prob, w / w.sum(axis=1, keepdims=True))
    np.testing.assert_allclose(realised_probabilities(threshold, alias), prob, atol=1e-15)
    assert np.all((threshold >= 0) & (threshold <= 1))


def test_sampled_cells_follow_the_probabilities_and_leave_a_uniform():
    """2^20 draws of two rows: cell counts within 5 binomial standard deviations of
    N p (a wrong threshold or alias moves whole cells' mass: far more); the leftover
    uniform v has the mean 1/2 and variance 1/12 of U[0, 1) within 5 standard errors."""
    rng = np.random.default_rng(2)
    w = np.stack([rng.random(16) + 0.01, np.r_[np.zeros(8), np.arange(1.0, 9.0)]])
    table = AliasTable(w)
    n = 1 << 20
    for row in range(2):
        cell, v = table.sample(mi.UInt32(row), mi.Float(rng.random(n)))
        cell, v = np.asarray(cell), np.asarray(v)
        p = table.probabilities[row]
        counts = np.bincount(cell, minlength=16)
        sd = np.sqrt(n * p * (1 - p)) + 1e-9
        assert np.all(np.abs(counts - n * p) <= 5 * sd + 1e-9), (counts, n * p)
        assert np.all(counts[p == 0] == 0)
        assert np.all((v >= 0) & (v < 1))
        assert abs(v.mean() - 0.5) < 5 * np.sqrt(1 / 12 / n)
        assert abs(v.var() - 1 / 12) < 5 * np.sqrt(1 / 180 / n)


def test_bad_weights_are_refused():
    with pytest.raises(ValueError, match="no weight"):
        build_alias(np.zeros((1, 4)))
    with pytest.raises(ValueError, match="non-negative"):
        build_alias(np.array([[1.0, -1.0]]))
    with pytest.raises(ValueError, match="non-negative"):
        build_alias(np.ones(4))


def test_thresholds_are_stored_in_16_bits_and_cells_are_limited():
    """A cell's realised probability differs from its weight's share by the threshold's
    16-bit rounding at most (half a step of 1/65535 of a cell's share, per cell it touches),
    and rows of more than 2^16 cells (16-bit aliases) are refused."""
    rng = np.random.default_rng(4)
    w = rng.random((3, 500)) ** 4
    table = AliasTable(w)
    exact = w / w.sum(axis=1, keepdims=True)
    # Each cell's probability gathers its own threshold and those of the cells aliasing it.
    _, _, alias = build_alias(w)
    touching = 1 + np.stack([np.bincount(a, minlength=500) for a in alias])
    bound = touching * 0.5 / 65535 / 500 + 1e-12
    assert np.all(np.abs(table.probabilities - exact) <= bound)
    assert np.abs(table.probabilities - exact).max() > 0.0  # rounded, not stored exactly
    with pytest.raises(ValueError, match="at most 65536 cells"):
        AliasTable(np.ones((1, 65537)))
