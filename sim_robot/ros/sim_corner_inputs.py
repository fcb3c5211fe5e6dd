"""ekf_node's ``tag_cornersN`` inputs for the simulated cameras: K, mount and optical frame of
sim_node's ``camera_images`` (and ``camera1``), so that the images demo's filter fuses a lone
tag's corners as the simulator's camera projects them.

The demo (tools/demo.py) runs this as a process and adds what it prints to its run's
ekf_params.yaml (the layers: ekf_localization never imports the simulator):

    python -m sim_robot.ros.sim_corner_inputs --config CONFIG_DIR --sim-params SIM_YAML
           [--cameras 1|2] [--single-tag METHOD]

prints a YAML mapping of parameters (empty when ``single_tag``, from config/tag_localizer.yaml
or ``--single-tag``, is not ``corners``).
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path
from typing import Any

import yaml

from ekf_localization.ros.launch_description import CAMERAS
from ekf_localization.tools.demo_images import LAYOUT
from ekf_localization.tools.tag_corner_inputs import tag_corner_inputs
from ekf_localization.vision.heading_prior import CORNERS


def ekf_overrides(cfg: Path, sim_yaml: Path, cameras: int = 1,
                  single_tag: str | None = None) -> dict[str, Any]:
    """The images demo's: config/tag_localizer.yaml and the demo's layout under ``cfg``."""
    return corner_inputs(cfg / "tag_localizer.yaml", cfg / LAYOUT, sim_yaml, cameras, single_tag=single_tag)


def corner_inputs(tag_yaml: Path | str, layout: Path | str, sim_yaml: Path | str, cameras: int = 1,
                  sim_overrides: dict[str, Any] | None = None,
                  single_tag: str | None = None) -> dict[str, Any]:
    """ekf_node's extra parameters: when tag_localizer's ``single_tag`` (``tag_yaml``, or
    ``single_tag``) is corners, one ``tag_cornersN`` per tag of ``layout`` and camera, the
    simulator's camera as tag_localizer sees it (K of its CameraInfo, its mount and optical frame,
    from ``sim_yaml`` with ``sim_overrides``, e.g. a launch's frame prefix); else none."""
    from ekf_localization.ros.parameters import parameters_from_yaml
    from ekf_localization.ros.tag_localizer_parameters import NODE_NAME, parse_settings
    from sim_robot.ros.sim_params import parse_parameters

    tag_values = parameters_from_yaml(Path(tag_yaml), NODE_NAME)
    tag_values["layout_file"] = str(layout)
    if single_tag is not None:
        tag_values["single_tag"] = single_tag
    tag = parse_settings(tag_values)
    if tag.single_tag != CORNERS:
        return {}
    values = parameters_from_yaml(Path(sim_yaml), "sim_node")
    values.update(sim_overrides or {})
    values.update({"camera_images.enabled": True, "camera_images.tag_layout": str(layout),
                   "camera1.enabled": cameras == 2})
    sim = parse_parameters(values)[1]
    views = ((sim.camera_images, sim.camera_frame), (sim.camera1_images, sim.camera1_frame))[:cameras]
    out: dict[str, Any] = {}
    for k, (images, frame) in enumerate(views):
        x, y, z, yaw, pitch = images.mount          # the simulator's planar mount: no roll
        cam = images.camera
        out.update(tag_corner_inputs(tag.layout, (cam.fx, cam.fy, cam.cx, cam.cy), (x, y, z, 0.0, pitch, yaw),
                                     tag.corner_noise, camera_frame=frame, namespace=CAMERAS[k] if k else "",
                                     first=len(tag.layout.tags) * k))
    return out


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="sim_corner_inputs", description=__doc__,
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--config", type=Path, required=True, help="config directory (tag_localizer.yaml)")
    parser.add_argument("--sim-params", type=Path, required=True, help="sim_node's YAML")
    parser.add_argument("--cameras", type=int, choices=[1, 2], default=1)
    parser.add_argument("--single-tag", default=None)
    args = parser.parse_args(sys.argv[1:] if argv is None else argv)
    from ekf_localization.ros.parameters import ParameterError

    try:
        values = ekf_overrides(args.config, args.sim_params, args.cameras, args.single_tag)
    except (ParameterError, OSError, ValueError) as exc:
        print(f"sim_corner_inputs: {exc}".replace("\n", " "), file=sys.stderr)
        return 2
    sys.stdout.write(yaml.safe_dump(values, sort_keys=False) if values else "{}\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
