"""Image errors of ``mscloth compare`` and of its error budget: relative MSE, FLIP, and the
estimators of noise per sample and squared bias.

Per region, relMSE = mean over the region's pixels and the RGB channels of
(img - ref)^2 / (ref^2 + 1e-2); FLIP (NVIDIA's ``flip_evaluator``, LDR mode) on both
images clipped to [0, 1] and sRGB-encoded (exactly what the PNGs show), the FLIP error map
averaged over the region. The reference's own noise is estimated from its two
independent halves, Var(mean) ~ (A - B)^2 / 4, and reported as ``relmse_reference`` (the
floor under every measured relMSE).

Estimators of the error budget (per pixel, then averaged over a region's pixels and the RGB
channels, with the same relMSE normalisation (img - ref)^2 / (ref^2 + eps)):

* per-sample noise from k renders of n spp each: n * sample variance over the k renders;
* squared bias from halves A, B of n spp each and a reference of variance r (of its mean):
  ((A + B) / 2 - ref)^2 - (A - B)^2 / 4 - r, unbiased because E[(A - B)^2 / 4] is the
  variance of (A + B) / 2.
"""
from __future__ import annotations

import numpy as np

RELMSE_EPS = 1e-2


def relmse_map(img: np.ndarray, ref: np.ndarray, eps: float = RELMSE_EPS) -> np.ndarray:
    """Per-pixel relative squared error, mean over channels: mean_c (img-ref)^2 / (ref^2 + eps)."""
    img = np.asarray(img, dtype=np.float64)
    ref = np.asarray(ref, dtype=np.float64)
    if img.shape != ref.shape:
        raise ValueError(f"image shape {img.shape} differs from the reference's {ref.shape}")
    err = (img - ref) ** 2 / (ref ** 2 + eps)
    return err.mean(axis=-1) if err.ndim == 3 else err


def relmse(img: np.ndarray, ref: np.ndarray, mask: np.ndarray | None = None, eps: float = RELMSE_EPS) -> float:
    """mean((img - ref)^2 / (ref^2 + eps)) over the pixels in ``mask`` (all if None) and channels."""
    per_pixel = relmse_map(img, ref, eps)
    if mask is not None:
        mask = np.asarray(mask, dtype=bool)
        if not mask.any():
            raise ValueError("empty region mask")
        per_pixel = per_pixel[mask]
    return float(per_pixel.mean())


def to_srgb8(img: np.ndarray) -> np.ndarray:
    """Linear RGB -> sRGB in [0, 1] (clipped), the transform of the PNGs."""
    x = np.clip(np.asarray(img, dtype=np.float64), 0.0, 1.0)
    return np.where(x <= 0.0031308, 12.92 * x, 1.055 * np.power(x, 1 / 2.4) - 0.055)


def flip_map(img: np.ndarray, ref: np.ndarray) -> np.ndarray:
    """FLIP error map (H, W) of ``img`` against ``ref``: LDR-FLIP of the sRGB-encoded, clipped images."""
    import flip_evaluator

    error, _, _ = flip_evaluator.evaluate(to_srgb8(ref).astype(np.float32), to_srgb8(img).astype(np.float32),
                                          "LDR", applyMagma=False, computeMeanError=False)
    return np.asarray(error, dtype=np.float64).reshape(ref.shape[:2])


def per_sample_noise(images, spp: int, ref, eps: float = RELMSE_EPS) -> np.ndarray:
    """Per-pixel relative variance of one sample: ``spp`` times the sample variance over the
    independent ``images`` (k >= 2 renders of ``spp`` samples each, shape (k, H, W, C)),
    over ref^2 + eps, mean over channels."""
    images = np.asarray(images, dtype=np.float64)
    if images.ndim != 4 or images.shape[0] < 2:
        raise ValueError(f"per_sample_noise: expected (k >= 2, H, W, C) images, got shape {images.shape}")
    var = images.var(axis=0, ddof=1) * spp
    return (var / (np.asarray(ref, np.float64) ** 2 + eps)).mean(axis=-1)


def squared_bias(half_a, half_b, ref, ref_var, eps: float = RELMSE_EPS) -> np.ndarray:
    """Per-pixel unbiased estimate of the relative squared bias of the method that rendered
    the independent halves ``half_a``, ``half_b`` (same spp) against ``ref`` whose mean has
    variance ``ref_var``; mean over channels. Single pixels can be negative (it is an
    estimate); region means are what it is for."""
    a = np.asarray(half_a, np.float64)
    b = np.asarray(half_b, np.float64)
    ref = np.asarray(ref, np.float64)
    estimate = (0.5 * (a + b) - ref) ** 2 - 0.25 * (a - b) ** 2 - np.asarray(ref_var, np.float64)
    return (estimate / (ref ** 2 + eps)).mean(axis=-1)
