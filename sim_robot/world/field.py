"""The FTC field: a square with its origin at the centre and navigation images on the walls.

Field frame (REP-103/105 ``map``): x and y in the floor plane, z up, yaw CCW. The field
is 144 in (3.6576 m) square, so the walls are at ±72 in. Each image is a segment of
width ``width`` on a wall, centred at ``(x, y)`` and facing into the field along
``facing_yaw`` (the direction of the image's normal).

Presets (all lengths given in inches and multiplied by ``length_per_inch``: 1.0 for
the paper's inch units, 0.0254 for metres):

* ``seed000``: seed 000's test layout, "images at the top and bottom of the border"
  (fig. 7). The paper gives no coordinates; we put two images on each of the
  y = +72 in (top) and y = -72 in (bottom) walls, at x = ±36 in (one and a half tiles
  from the centre, like FTC's own layouts).
* ``freight_frenzy``: the 2021-22 FTC Freight Frenzy targets, at the positions of the
  FTC SDK's navigation sample (``halfField`` = 72 in, ``halfTile`` = 12 in,
  ``oneAndHalfTile`` = 36 in): Blue Storage (-72, 36), Blue Alliance Wall (12, 72),
  Red Storage (-72, -36), Red Alliance Wall (12, -72); FTC's field x/y axes are used
  directly (right-handed, z up).

Image width: 10 in for both presets (the printed targets are about letter size; the
paper does not say). The width only matters for the "image fully in view" test.
"""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass

import numpy as np

from ekf_localization.core.units import METRES_PER_INCH

FIELD_SIZE_IN = 144.0
IMAGE_WIDTH_IN = 10.0
PRESETS = ("seed000", "freight_frenzy")


@dataclass(frozen=True)
class FieldImage:
    """A wall image: centre (x, y), outward normal ``facing_yaw`` (rad), ``width`` (length unit)."""

    x: float
    y: float
    facing_yaw: float
    width: float
    name: str = ""

    def __post_init__(self) -> None:
        if not all(math.isfinite(v) for v in (self.x, self.y, self.facing_yaw)):
            raise ValueError(f"image {self.name!r}: x, y and facing_yaw must be finite")
        if not (math.isfinite(self.width) and self.width > 0.0):
            raise ValueError(f"image {self.name!r}: width must be positive, got {self.width!r}")


@dataclass(frozen=True)
class Field:
    """A square field of side ``size`` centred on the origin, with wall images."""

    size: float
    images: tuple[FieldImage, ...]

    def __post_init__(self) -> None:
        if not (math.isfinite(self.size) and self.size > 0.0):
            raise ValueError(f"field size must be positive, got {self.size!r}")

    @property
    def half_size(self) -> float:
        return 0.5 * self.size

    def image_arrays(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Image centres (M, 2), unit normals (M, 2) and the two end points (M, 2, 2); read-only."""
        return self._image_arrays

    @functools.cached_property
    def _image_arrays(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        # computed once: the camera tests them at every capture
        if not self.images:
            c, n, ends = np.zeros((0, 2)), np.zeros((0, 2)), np.zeros((0, 2, 2))
        else:
            c = np.array([[im.x, im.y] for im in self.images])
            yaw = np.array([im.facing_yaw for im in self.images])
            n = np.column_stack([np.cos(yaw), np.sin(yaw)])
            t = np.column_stack([-n[:, 1], n[:, 0]])  # along the wall
            half_w = 0.5 * np.array([im.width for im in self.images])[:, None]
            ends = np.stack([c - half_w * t, c + half_w * t], axis=1)
        for a in (c, n, ends):
            a.setflags(write=False)
        return c, n, ends

    @classmethod
    def preset(cls, name: str, length_per_inch: float = METRES_PER_INCH,
               image_width: float | None = None) -> Field:
        """A preset layout in the length unit given by ``length_per_inch`` (see module doc)."""
        k = float(length_per_inch)
        w = IMAGE_WIDTH_IN * k if image_width is None else float(image_width)
        h = 0.5 * FIELD_SIZE_IN * k
        if name == "seed000":
            images = (
                FieldImage(-36.0 * k, h, -0.5 * math.pi, w, "top left"),
                FieldImage(36.0 * k, h, -0.5 * math.pi, w, "top right"),
                FieldImage(-36.0 * k, -h, 0.5 * math.pi, w, "bottom left"),
                FieldImage(36.0 * k, -h, 0.5 * math.pi, w, "bottom right"),
            )
        elif name == "freight_frenzy":
            images = (
                FieldImage(-h, 36.0 * k, 0.0, w, "Blue Storage"),
                FieldImage(12.0 * k, h, -0.5 * math.pi, w, "Blue Alliance Wall"),
                FieldImage(-h, -36.0 * k, 0.0, w, "Red Storage"),
                FieldImage(12.0 * k, -h, 0.5 * math.pi, w, "Red Alliance Wall"),
            )
        else:
            raise ValueError(f"field preset must be one of {PRESETS}, got {name!r}")
        return cls(FIELD_SIZE_IN * k, images)
