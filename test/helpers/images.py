"""Checks on a written PNG that fail for a real reason: it does not decode, has another size than
the figure it should be, or shows no plotted data (only white, black and grey: empty axes)."""

from __future__ import annotations

from pathlib import Path

import numpy as np

# A pixel is "coloured" when its channels differ by this much: matplotlib's data colours (tab10:
# C0 blue has 0.59) do, its axes, text, grid and background (black, greys, white) do not.
CHROMA = 0.2
# ... and a figure with data has at least this fraction of such pixels (a 1.5 pt line across an
# 880 px axes already covers ~0.2 %; empty axes have 0).
MIN_COLOURED = 0.001


def read_png(path: Path) -> np.ndarray:
    """The image as (height, width, channels) floats in 0..1; fails if it is no PNG."""
    import matplotlib.image

    data = Path(path).read_bytes()
    assert data[:8] == b"\x89PNG\r\n\x1a\n", f"{path} is not a PNG"
    return matplotlib.image.imread(path, format="png")


def coloured_fraction(img: np.ndarray) -> float:
    rgb = img[..., :3]
    return float(np.mean(rgb.max(axis=-1) - rgb.min(axis=-1) > CHROMA))


def assert_plot_png(path: Path, width: int, height: int | None = None,
                    min_coloured: float = MIN_COLOURED) -> np.ndarray:
    """``path`` decodes as a ``width`` x ``height`` image (figsize x dpi; ``height`` None: any)
    with plotted data on it. Returns the image."""
    img = read_png(path)
    h, w = img.shape[:2]
    assert w == width and (height is None or h == height), f"{path}: {w}x{h}, want {width}x{height}"
    frac = coloured_fraction(img)
    assert frac >= min_coloured, f"{path}: {frac:.2%} coloured pixels (< {min_coloured:.2%}): nothing plotted"
    return img
