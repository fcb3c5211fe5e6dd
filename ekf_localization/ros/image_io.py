"""sensor_msgs/Image, CompressedImage and CameraInfo -> a mono8 numpy image and a PinholeCamera, or
the reason not.

Reads attributes only (rclpy and rosbags messages alike). Each failure is an
:class:`BadImageError` whose ``reason`` is the counter's name on /diagnostics.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from ekf_localization.vision.pinhole import PinholeCamera

# encoding -> bytes per pixel. Colour is converted to grey (ITU-R BT.601 luma); mono16 keeps
# its high byte (value >> 8, the full 16-bit range mapped onto 8 bits); the packed YUV 4:2:2
# encodings keep their Y bytes (sensor_msgs/image_encodings.hpp: yuv422 is UYVY, Y at the odd
# bytes; yuv422_yuy2 is YUYV, Y at the even bytes). 16UC1 is not read: it is a depth image.
ENCODINGS = {"mono8": 1, "8UC1": 1, "rgb8": 3, "bgr8": 3, "rgba8": 4, "bgra8": 4, "mono16": 2,
             "yuv422": 2, "yuv422_yuy2": 2}
MAX_SIDE = 16384


class BadImageError(ValueError):
    """An image or CameraInfo that cannot be used: ``reason`` (a counter name) and the details."""

    def __init__(self, reason: str, detail: str) -> None:
        super().__init__(detail)
        self.reason = reason


def _bytes(data: Any) -> np.ndarray:
    """uint8 view of a message's data (bytes, array.array, list or numpy)."""
    if isinstance(data, np.ndarray):
        return np.ascontiguousarray(data).reshape(-1).view(np.uint8)
    try:
        return np.frombuffer(memoryview(data).cast("B"), dtype=np.uint8)  # no copy
    except TypeError:  # a list of ints
        return np.asarray(data, dtype=np.uint8).reshape(-1)


_JPEG_START, _JPEG_END = b"\xff\xd8", b"\xff\xd9"
_PNG_START, _PNG_END = b"\x89PNG", b"IEND"


def _truncated(data: np.ndarray) -> bool:
    """A JPEG without its end-of-image marker, or a PNG without its IEND chunk, near the end."""
    head, tail = data[:4].tobytes(), data[-16:].tobytes()
    if head.startswith(_JPEG_START):
        return _JPEG_END not in tail
    if head.startswith(_PNG_START):
        return _PNG_END not in tail
    return False


def image_to_mono8(msg: Any) -> np.ndarray:
    """(H, W) uint8 of an Image message; BadImageError(bad_encoding | empty_image | bad_size |
    truncated_image | bad_data_size)."""
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
    data = _bytes(msg.data)
    if data.size < step * h:
        raise BadImageError("truncated_image", f"{data.size} bytes of data, {step * h} expected")
    if data.size > step * h:
        raise BadImageError("bad_data_size", f"{data.size} bytes of data, step x height is {step * h}")
    rows = data.reshape(h, step)[:, : w * channels]
    if channels == 1:
        return np.ascontiguousarray(rows)
    if encoding == "mono16":  # the high byte: the first of each pair when big-endian
        return np.ascontiguousarray(rows[:, (0 if int(msg.is_bigendian) else 1)::2])
    if encoding.startswith("yuv422"):
        return np.ascontiguousarray(rows[:, (0 if encoding == "yuv422_yuy2" else 1)::2])
    pixels = rows.reshape(h, w, channels)
    rgb = pixels[:, :, :3] if encoding.startswith("rgb") else pixels[:, :, 2::-1]
    grey = rgb.astype(np.float32) @ np.array([0.299, 0.587, 0.114], dtype=np.float32)
    return np.clip(np.rint(grey), 0, 255).astype(np.uint8)


def compressed_to_mono8(msg: Any) -> np.ndarray:
    """(H, W) uint8 of a CompressedImage (JPEG or PNG, told apart by their own header bytes) through
    OpenCV's decoder, straight to grey; BadImageError(bad_encoding | empty_image | corrupt_image |
    bad_size)."""
    import cv2

    fmt = str(msg.format)
    if "compresseddepth" in fmt.lower():
        raise BadImageError("bad_encoding", f"format {fmt!r}: a compressed depth image, not a camera image")
    data = _bytes(msg.data)
    if data.size == 0:
        raise BadImageError("empty_image", "CompressedImage with no data")
    if _truncated(data):  # some OpenCV versions decode a cut-off file, its rest filled grey
        raise BadImageError("corrupt_image", f"format {fmt!r}, {data.size} bytes: the file ends early "
                                             "(no JPEG end marker or PNG IEND chunk)")
    try:
        image = cv2.imdecode(data, cv2.IMREAD_GRAYSCALE)
    except cv2.error as exc:
        raise BadImageError("corrupt_image", f"format {fmt!r}: {exc}") from None
    if image is None or image.size == 0:
        raise BadImageError("corrupt_image", f"format {fmt!r}, {data.size} bytes: not a JPEG or PNG "
                                             "that OpenCV decodes")
    if max(image.shape) > MAX_SIDE:
        raise BadImageError("bad_size", f"image of size {image.shape[1]}x{image.shape[0]} "
                                        f"(more than {MAX_SIDE} px a side)")
    return image


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
