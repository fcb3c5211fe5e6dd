"""The field's AprilTags: id, size and pose of each, read from a tag layout YAML.

The layout YAML (``config/tags/*.yaml``)::

    tag_family: tag36h11
    field: {length: 3.6576, width: 3.6576}   # m, optional: fixes off the field are rejected
    # field.origin: [x, y] (m), optional, default [0, 0]: the field's corner of least x and y
    # in the map frame ([0, 0] for WPILib's layouts, [-length/2, -width/2] for a map frame at
    # the field centre like the simulator's)
    tags:
      - id: 1
        size: 0.1016                # m, edge of the black square (where the corners are)
        position: [0.0, 1.2, 0.15]  # m, tag centre in the map frame
        orientation: [0.0, 0.0, 0.0, 1.0]   # quaternion (x, y, z, w), or `yaw: 0.0` (rad)

The tag frame is WPILib's: origin at the tag centre, +x out of the printed face (towards a
camera that sees it), +z up, +y = z × x (to the right of a camera facing the tag).

Corner order (the detector's, AprilRobotics'): as a camera facing the upright tag sees them,
bottom-left, bottom-right, top-right, top-left (counter-clockwise on the image).
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ekf_localization.core.angles import quaternion_to_matrix, rpy_to_matrix

TAG_FAMILY = "tag36h11"


def corners_in_tag(size: float) -> np.ndarray:
    """(4, 3) corners in the tag frame, detector order (bl, br, tr, tl as a camera sees them)."""
    h = 0.5 * size
    # The camera looks along -x; its right is +y and its up is +z.
    return np.array([[0.0, -h, -h], [0.0, h, -h], [0.0, h, h], [0.0, -h, h]])


@dataclass(frozen=True)
class Tag:
    """One tag: its id, edge length (m) and pose in the map frame (4x4 homogeneous transform map <- tag)."""

    tag_id: int
    size: float
    pose_in_map: np.ndarray

    def corners_map(self) -> np.ndarray:
        """(4, 3) corners in the map frame, detector order."""
        R, t = self.pose_in_map[:3, :3], self.pose_in_map[:3, 3]
        return corners_in_tag(self.size) @ R.T + t


@dataclass(frozen=True)
class TagLayout:
    """The tags of a field (by id) and, if known, the field's size (m)."""

    tags: dict[int, Tag]
    family: str = TAG_FAMILY
    field_length: float | None = None
    field_width: float | None = None
    field_origin: tuple[float, float] = (0.0, 0.0)

    def on_field(self, x: float, y: float, margin: float = 0.0) -> bool:
        """True when (x, y) lies on the field (grown by ``margin``), or the size is unknown."""
        if self.field_length is None or self.field_width is None:
            return True
        x, y = x - self.field_origin[0], y - self.field_origin[1]
        return (-margin <= x <= self.field_length + margin
                and -margin <= y <= self.field_width + margin)


def _number(value: object, where: str) -> float:
    if isinstance(value, bool) or not isinstance(value, int | float) or not math.isfinite(value):
        raise ValueError(f"{where}: expected a finite number, got {value!r}")
    return float(value)


def _vector(value: object, n: int, where: str) -> list[float]:
    if not isinstance(value, list | tuple) or len(value) != n:
        raise ValueError(f"{where}: expected a list of {n} numbers, got {value!r}")
    return [_number(v, f"{where}[{i}]") for i, v in enumerate(value)]


def _tag(entry: object, where: str) -> Tag:
    if not isinstance(entry, Mapping):
        raise ValueError(f"{where}: expected a mapping with id, size, position, orientation")
    unknown = set(entry) - {"id", "size", "position", "orientation", "yaw"}
    if unknown:
        raise ValueError(f"{where}: unknown key(s) {sorted(unknown)}")
    tag_id = entry.get("id")
    if isinstance(tag_id, bool) or not isinstance(tag_id, int) or tag_id < 0:
        raise ValueError(f"{where}.id: expected an integer >= 0, got {tag_id!r}")
    size = _number(entry.get("size"), f"{where}.size")
    if size <= 0.0:
        raise ValueError(f"{where}.size: must be > 0 (m), got {size}")
    position = _vector(entry.get("position"), 3, f"{where}.position")
    if ("orientation" in entry) == ("yaw" in entry):
        raise ValueError(f"{where}: give exactly one of orientation [x, y, z, w] or yaw")
    if "yaw" in entry:
        R = rpy_to_matrix(0.0, 0.0, _number(entry["yaw"], f"{where}.yaw"))
    else:
        q = _vector(entry["orientation"], 4, f"{where}.orientation")
        if not 0.5 < math.sqrt(sum(v * v for v in q)) < 2.0:
            raise ValueError(f"{where}.orientation: not a unit quaternion: {q}")
        R = quaternion_to_matrix(*q)
    T = np.eye(4)
    T[:3, :3], T[:3, 3] = R, position
    return Tag(tag_id, size, T)


def tag_layout_from_dict(data: object, source: str = "tag layout") -> TagLayout:
    """A :class:`TagLayout` from the parsed YAML; ValueError naming the bad key otherwise."""
    if not isinstance(data, Mapping):
        raise ValueError(f"{source}: expected a mapping with tag_family and tags")
    family = data.get("tag_family", TAG_FAMILY)
    if family != TAG_FAMILY:
        raise ValueError(f"{source}: tag_family {family!r} is not supported (only {TAG_FAMILY})")
    entries = data.get("tags")
    if not isinstance(entries, list) or not entries:
        raise ValueError(f"{source}: tags must be a non-empty list")
    tags: dict[int, Tag] = {}
    for i, entry in enumerate(entries):
        tag = _tag(entry, f"{source}: tags[{i}]")
        if tag.tag_id in tags:
            raise ValueError(f"{source}: tags[{i}].id {tag.tag_id} appears twice")
        tags[tag.tag_id] = tag
    length = width = None
    origin = (0.0, 0.0)
    if data.get("field") is not None:
        field = data["field"]
        if not isinstance(field, Mapping):
            raise ValueError(f"{source}: field must be a mapping with length and width")
        length = _number(field.get("length"), f"{source}: field.length")
        width = _number(field.get("width"), f"{source}: field.width")
        unknown = set(field) - {"length", "width", "origin"}
        if unknown:
            raise ValueError(f"{source}: field: unknown key(s) {sorted(unknown)}")
        if field.get("origin") is not None:
            ox, oy = _vector(field["origin"], 2, f"{source}: field.origin")
            origin = (ox, oy)
    return TagLayout(tags, family, length, width, origin)


def load_tag_layout(path: str | Path) -> TagLayout:
    """Read a tag layout YAML file (see the module docstring)."""
    import yaml

    with open(path, encoding="utf-8") as f:
        return tag_layout_from_dict(yaml.safe_load(f), str(path))
