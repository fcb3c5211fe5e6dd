"""sensor_msgs/Image and CameraInfo -> a mono8 numpy image and a PinholeCamera, or the reason not.

Reads attributes only (rclpy and rosbags messages alike). Each failure is an
:class:`BadImageError` whose ``reason`` is the counter's name on /diagnostics.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from ekf_localization.vision.pinhole import PinholeCamera

# encoding -> channels; colour images are converted to grey (ITU-R BT.601 luma)
ENCODINGS = {"mono8": 1, "8UC1": 1, "rgb8": 3, "bgr8": 3, "rgba8": 4, "bgra8": 4}
MAX_SIDE = 16384


class BadImageError(ValueError):
    """An image or CameraInfo that cannot be used: ``reason`` (a counter name) and the details."""

    def __init__(self, reason: str, detail: str) -> None:
        super().__init__(detail)
        self.reason = reason


def image_to_mono8(msg: Any) -> np.ndarray:
    """(H, W) uint8 of an Image message; BadImageError(bad_encoding | empty_image | truncated_image)."""
    encoding = str(msg.encoding)
    channels = ENCODINGS.get(encoding)
    if channels is None:
        raise BadImageError("bad_encoding", f"encoding {encoding!r} is not one of {', '.join(ENCODINGS)}")
    h, w, step = int(msg.height), int(msg.width), int(msg.step)
    if h <= 0 or w <= 0:
        raise BadImageError("empty_image", f"image of size {w}x{h}")
    if h > MAX_SIDE or w > MAX_SIDE:
        raise BadImageError("bad_size", f"image of size {w}x{h} (more than {MAX_SIDE} px a side)")
    if step < w * channels:
        raise BadImageError("truncated_image", f"step {step} < width {w} x {channels} bytes")
    data = np.frombuffer(bytes(msg.data) if not isinstance(msg.data, np.ndarray) else msg.data.tobytes(),
                         dtype=np.uint8)
    if data.size < step * h:
        raise BadImageError("truncated_image", f"{data.size} bytes of data, {step * h} expected")
    rows = data[: step * h].reshape(h, step)[:, : w * channels].reshape(h, w, channels)
    if channels == 1:
        return np.ascontiguousarray(rows[:, :, 0])
    rgb = rows[:, :, :3] if encoding.startswith("rgb") else rows[:, :, 2::-1]
    grey = rgb.astype(np.float32) @ np.array([0.299, 0.587, 0.114], dtype=np.float32)
    return np.clip(np.rint(grey), 0, 255).astype(np.uint8)


def camera_info_to_pinhole(msg: Any) -> PinholeCamera:
    """The PinholeCamera of a CameraInfo (K, the distortion model and D: one of
    vision/camera_geometry.py's DISTORTION_MODELS); BadImageError("bad_camera_info") otherwise."""
    try:
        k = [float(v) for v in msg.k]
        d = [float(v) for v in msg.d]
        w, h = int(msg.width), int(msg.height)
        model = str(msg.distortion_model)
    except (TypeError, ValueError, AttributeError) as exc:
        raise BadImageError("bad_camera_info", f"unreadable CameraInfo: {exc}") from None
    if len(k) != 9 or not all(math.isfinite(v) for v in k + d):
        raise BadImageError("bad_camera_info", "K must be 9 finite numbers and D finite")
    fx, fy, cx, cy = k[0], k[4], k[2], k[5]
    if not (fx > 0.0 and fy > 0.0) or w <= 0 or h <= 0:
        raise BadImageError("bad_camera_info", f"fx {fx}, fy {fy}, size {w}x{h}: focal lengths and size "
                                               "must be > 0")
    try:
        return PinholeCamera(w, h, fx, fy, cx, cy, tuple(d), model)
    except ValueError as exc:   # the distortion model or D (vision/camera_geometry.py)
        raise BadImageError("bad_camera_info", str(exc)) from None
