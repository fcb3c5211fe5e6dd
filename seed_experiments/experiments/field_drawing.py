"""Drawing the FTC field (walls and wall images) under a trajectory plot, in the field's units."""

from __future__ import annotations

import matplotlib

matplotlib.use("Agg")
from matplotlib.axes import Axes  # noqa: E402
from matplotlib.patches import Rectangle  # noqa: E402

from sim_robot.world.field import Field  # noqa: E402


def draw_field(ax: Axes, field: Field, label_images: bool = True) -> None:
    """Walls as a grey square, images as thick green segments."""
    h = field.half_size
    ax.add_patch(Rectangle((-h, -h), 2 * h, 2 * h, fill=False, lw=1.5, color="0.35"))
    _, _, ends = field.image_arrays()
    for i, e in enumerate(ends):
        ax.plot(e[:, 0], e[:, 1], color="tab:green", lw=6, solid_capstyle="butt",
                label="wall images" if (label_images and i == 0) else None)
    ax.set_aspect("equal")
