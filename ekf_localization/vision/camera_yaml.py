"""A camera's intrinsics from a calibration YAML (the format of ROS ``camera_calibration``).

    image_width: 640
    image_height: 480
    camera_matrix: {rows: 3, cols: 3, data: [fx, 0, cx, 0, fy, cy, 0, 0, 1]}
    distortion_model: plumb_bob          # optional: plumb_bob, rational_polynomial, equidistant or none
    distortion_coefficients: {rows: 1, cols: 5, data: [k1, k2, p1, p2, k3]}   # optional

This is the file ``camera_calibration`` writes and ``camera_info_manager`` reads (a
CameraInfo's K, D and size). ``data`` may also be given as a plain list.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import yaml

from ekf_localization.vision.pinhole import PinholeCamera


def _data(value: object, n: int | None, what: str) -> list[float]:
    if isinstance(value, dict):
        value = value.get("data")
    if not isinstance(value, list | tuple):
        raise ValueError(f"{what}: expected a list of numbers (or a mapping with data)")
    try:
        out = [float(v) for v in value]
    except (TypeError, ValueError):
        raise ValueError(f"{what}: expected numbers, got {value!r}") from None
    if n is not None and len(out) != n:
        raise ValueError(f"{what}: expected {n} numbers, got {len(out)}")
    if not all(np.isfinite(out)):
        raise ValueError(f"{what}: not finite: {out}")
    return out


def camera_from_dict(data: object, source: str = "camera") -> PinholeCamera:
    """The :class:`PinholeCamera` of a calibration mapping; ValueError naming what is wrong."""
    if not isinstance(data, dict):
        raise ValueError(f"{source}: expected a mapping with image_width, image_height, camera_matrix")
    try:
        width, height = int(data["image_width"]), int(data["image_height"])
        k = _data(data["camera_matrix"], 9, f"{source}: camera_matrix")
    except KeyError as e:
        raise ValueError(f"{source}: missing {e.args[0]}") from None
    except (TypeError, ValueError) as e:
        raise ValueError(f"{source}: {e}") from None
    if width <= 0 or height <= 0:
        raise ValueError(f"{source}: image size {width}x{height} must be positive")
    fx, fy, cx, cy = k[0], k[4], k[2], k[5]
    if fx <= 0.0 or fy <= 0.0:
        raise ValueError(f"{source}: focal lengths fx {fx}, fy {fy} must be positive")
    model = str(data.get("distortion_model") or "")
    if model in ("", "none"):  # no distortion: plumb_bob with D = 0
        model = PinholeCamera.__dataclass_fields__["distortion_model"].default
        d = []
    else:
        d = _data(data["distortion_coefficients"], None, f"{source}: distortion_coefficients") \
            if data.get("distortion_coefficients") is not None else []
    try:
        return PinholeCamera(width, height, fx, fy, cx, cy, tuple(d), model)
    except ValueError as e:  # camera_geometry.distortion_coefficients: an unknown model, a bad D
        raise ValueError(f"{source}: {e}") from None


def load_camera_yaml(path: str | Path) -> PinholeCamera:
    """The camera of a calibration YAML file (module docstring); ValueError when it is not one."""
    try:
        data = yaml.safe_load(Path(path).read_text())
    except (OSError, yaml.YAMLError) as e:
        raise ValueError(f"{path}: cannot read: {e}".splitlines()[0]) from None
    return camera_from_dict(data, str(path))
