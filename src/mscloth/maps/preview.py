"""PNG previews of `ClothMaps`, one per map plus a labelled contact sheet.

Image row r is texel row r, so +v points down the image and +u to the right.
"""
from __future__ import annotations

import os
from pathlib import Path

import numpy as np
from PIL import Image, ImageDraw, ImageFont

from ..atomic import atomic_write
from ..errors import MapsError
from .cloth_maps import ClothMaps

PREVIEW_NAMES = ("tangent", "normal", "height", "gap", "yarn_id", "albedo")
CONTACT_SHEET = "contact_sheet.png"
PANEL_MAX = 256      # contact-sheet panel size limit (pixels), keeps the sheet small
LABEL_HEIGHT = 16
_GOLDEN = 0.6180339887498949


def _to_u8(x: np.ndarray) -> np.ndarray:
    return np.round(np.clip(x, 0.0, 1.0) * 255.0).astype(np.uint8)


def _srgb_encode(linear: np.ndarray) -> np.ndarray:
    x = np.clip(linear, 0.0, 1.0)
    return np.where(x <= 0.0031308, 12.92 * x, 1.055 * np.power(x, 1.0 / 2.4) - 0.055)


def _hsv_to_rgb(h: np.ndarray, s: float, v: float) -> np.ndarray:
    """Vectorised HSV -> RGB for hue arrays in [0, 1)."""
    k = np.stack([(5.0 + h * 6.0) % 6.0, (3.0 + h * 6.0) % 6.0, (1.0 + h * 6.0) % 6.0], -1)
    return v - v * s * np.clip(np.minimum(k, 4.0 - k), 0.0, 1.0)


def _yarn_colours(yarn_id: np.ndarray) -> np.ndarray:
    """Distinct colours per id (golden-ratio hue steps, so neighbouring ids differ); gaps black."""
    hue = (np.maximum(yarn_id, 0) * _GOLDEN) % 1.0
    # Alternate the value too, so ids whose hues come close still differ in brightness.
    rgb = np.where((yarn_id % 2 == 0)[..., None], _hsv_to_rgb(hue, 0.75, 1.0),
                   _hsv_to_rgb(hue, 0.9, 0.7))
    return np.where((yarn_id < 0)[..., None], 0.0, rgb)


def preview_images(maps: ClothMaps) -> dict[str, Image.Image]:
    """The six preview images of ``maps`` keyed by map name (RGB or greyscale)."""
    h = maps.height.astype(np.float64)
    span = float(h.max() - h.min())
    h01 = (h - h.min()) / span if span > 0 else np.full_like(h, 0.5)
    return {
        "tangent": Image.fromarray(_to_u8(maps.tangent * 0.5 + 0.5), "RGB"),
        "normal": Image.fromarray(_to_u8(maps.normal * 0.5 + 0.5), "RGB"),
        "height": Image.fromarray(_to_u8(h01), "L"),
        "gap": Image.fromarray(_to_u8(maps.gap), "L"),
        "yarn_id": Image.fromarray(_to_u8(_yarn_colours(maps.yarn_id)), "RGB"),
        "albedo": Image.fromarray(_to_u8(_srgb_encode(maps.albedo)), "RGB"),
    }


def contact_sheet(images: dict[str, Image.Image]) -> Image.Image:
    """All images side by side, each scaled to fit PANEL_MAX, with its name underneath."""
    first = next(iter(images.values()))
    scale = min(1.0, PANEL_MAX / max(first.size))
    pw, ph = max(1, round(first.width * scale)), max(1, round(first.height * scale))
    gap = 4
    sheet = Image.new("RGB", (len(images) * (pw + gap) + gap, ph + LABEL_HEIGHT + 2 * gap),
                      (32, 32, 32))
    draw = ImageDraw.Draw(sheet)
    font = ImageFont.load_default()
    for k, (name, img) in enumerate(images.items()):
        x = gap + k * (pw + gap)
        # NEAREST keeps ids/gaps crisp when upscaling; BOX averages when shrinking.
        resample = Image.Resampling.NEAREST if scale >= 1.0 else Image.Resampling.BOX
        sheet.paste(img.convert("RGB").resize((pw, ph), resample), (x, gap))
        draw.text((x + 2, gap + ph + 2), name, fill=(230, 230, 230), font=font)
    return sheet


def write_previews(maps: ClothMaps, directory: str | os.PathLike, *,
                   overwrite: bool = False) -> list[Path]:
    """Write ``<map>.png`` for the six maps and ``contact_sheet.png`` into ``directory``.

    Refuses (MapsError) if any of the seven files exists, unless ``overwrite`` is true;
    nothing is written in that case. Each file is written atomically. Returns the paths.
    """
    directory = Path(directory)
    names = [f"{n}.png" for n in PREVIEW_NAMES] + [CONTACT_SHEET]
    paths = [directory / n for n in names]
    if not overwrite:
        existing = [str(p) for p in paths if p.exists()]
        if existing:
            raise MapsError(f"refusing to overwrite existing {', '.join(existing)}; "
                            "pass overwrite=True to replace")
    images = preview_images(maps)
    images_out = list(images.values()) + [contact_sheet(images)]
    try:
        directory.mkdir(parents=True, exist_ok=True)
        for path, img in zip(paths, images_out):
            atomic_write(path, lambda f, img=img: img.save(f, format="PNG"))
    except OSError as exc:
        raise MapsError(f"cannot write previews to {directory}: {exc}") from None
    return paths


__all__ = ["write_previews", "preview_images", "contact_sheet", "PREVIEW_NAMES"]
