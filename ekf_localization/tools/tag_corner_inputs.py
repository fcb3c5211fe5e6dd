"""ekf_node's ``tag_cornersN`` inputs for every tag of a layout, as parameters.

tag_localizer with ``single_tag: corners`` publishes a single tag's corner pixels on
``tag_corners/tag_<id>`` (relative to its namespace); ekf_node fuses each tag as an input of its
own (inputs/tag_corners.py), whose model holds the tag's corners in the map, the camera's
intrinsics and mount, and the corner noise. :func:`tag_corner_inputs` writes those inputs for a
whole layout from the same sources tag_localizer uses: the layout file, the camera (CameraInfo's
K, for undistorted pixels), its mount in base_link, and tag_localizer's corner noise, so that R
is the covariance tag_localizer's PnP fixes are made from.

On a robot, print them for ekf_node's parameter file (the layout and the corner noise from
tag_localizer's YAML; K from your CameraInfo; the mount as in TF's base_link -> camera, body frame):

    python -m ekf_localization.tools.tag_corner_inputs --tag-localizer config/tag_localizer.yaml \
        --camera FX FY CX CY --mount X Y Z ROLL PITCH YAW --camera-frame camera_optical
"""

from __future__ import annotations

import argparse
import sys
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from ekf_localization.vision.corner_noise import CornerNoise
from ekf_localization.vision.tag_layout import TagLayout

INPUT = "tag_corners"
TOPIC_PREFIX = "tag_corners"   # tag_localizer's publisher: <namespace>/tag_corners/tag_<id>


def corners_topic(tag_id: int, namespace: str = "") -> str:
    """The topic tag_localizer (in ``namespace``, empty: the root) sends tag ``tag_id``'s corners on."""
    ns = namespace.strip("/")
    return f"{ns}/{TOPIC_PREFIX}/tag_{tag_id}" if ns else f"{TOPIC_PREFIX}/tag_{tag_id}"


def tag_corner_inputs(layout: TagLayout, camera: Sequence[float], camera_mount: Sequence[float],
                      noise: CornerNoise, *, camera_frame: str = "", namespace: str = "", first: int = 0,
                      rejection_threshold: float = 5.0) -> dict[str, Any]:
    """``tag_corners<first + k>_*`` for the layout's tags in id order: ``camera`` [fx, fy, cx, cy]
    (undistorted pixels), ``camera_mount`` the camera body frame (x forward, z up) in base_link
    [x, y, z, roll, pitch, yaw], ``noise`` tag_localizer's corner noise, ``camera_frame`` the
    corners' frame_id (empty: any), ``namespace`` tag_localizer's, ``rejection_threshold`` the
    Mahalanobis gate in σ (config/ekf.yaml's pose0 has 5)."""
    if len(camera) != 4 or len(camera_mount) != 6:
        raise ValueError("camera is [fx, fy, cx, cy] and camera_mount [x, y, z, roll, pitch, yaw]")
    values: dict[str, Any] = {}
    for k, tag_id in enumerate(sorted(layout.tags), start=first):
        name = f"{INPUT}{k}"
        values.update({
            name: corners_topic(tag_id, namespace),
            f"{name}_corners": [float(v) for v in layout.tags[tag_id].corners_map().reshape(-1)],
            f"{name}_camera": [float(v) for v in camera],
            f"{name}_camera_mount": [float(v) for v in camera_mount],
            f"{name}_camera_frame": camera_frame,
            f"{name}_pixel_std": float(noise.pixel_std),
            f"{name}_tag_shift_std": float(noise.tag_shift_std),
            f"{name}_blur_std_per_px": float(noise.blur_std_per_px),
            f"{name}_exposure_time": float(noise.exposure_time),
            f"{name}_unknown_motion_blur_px": float(noise.unknown_motion_blur_px),
            f"{name}_rejection_threshold": float(rejection_threshold),
        })
    return values


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--tag-localizer", type=Path, required=True,
                    help="tag_localizer's parameter file: the layout and the corner noise")
    ap.add_argument("--camera", type=float, nargs=4, required=True, metavar=("FX", "FY", "CX", "CY"),
                    help="CameraInfo's K (tag_localizer sends undistorted pixels of it)")
    ap.add_argument("--mount", type=float, nargs=6, required=True,
                    metavar=("X", "Y", "Z", "ROLL", "PITCH", "YAW"),
                    help="the camera body frame (x forward, z up) in base_link, m and rad")
    ap.add_argument("--camera-frame", default="", help="the corners' frame_id (empty: any)")
    ap.add_argument("--namespace", default="", help="tag_localizer's namespace (a second camera's)")
    ap.add_argument("--first", type=int, default=0, help="N of the first tag_cornersN")
    ap.add_argument("--rejection-threshold", type=float, default=5.0, help="Mahalanobis gate, σ")
    args = ap.parse_args(argv)
    import yaml

    from ekf_localization.ros.parameters import ParameterError, parameters_from_yaml
    from ekf_localization.ros.tag_localizer_parameters import NODE_NAME, parse_settings

    try:
        settings = parse_settings(parameters_from_yaml(args.tag_localizer, NODE_NAME))
        values = tag_corner_inputs(settings.layout, args.camera, args.mount, settings.corner_noise,
                                   camera_frame=args.camera_frame, namespace=args.namespace, first=args.first,
                                   rejection_threshold=args.rejection_threshold)
    except (OSError, ValueError, ParameterError) as exc:
        print(f"tag_corner_inputs: {exc}", file=sys.stderr)
        return 2
    print(yaml.safe_dump({"ekf_node": {"ros__parameters": values}}, sort_keys=False, default_flow_style=None),
          end="")
    return 0


if __name__ == "__main__":
    sys.exit(main())
