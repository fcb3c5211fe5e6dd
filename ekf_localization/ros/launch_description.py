"""What the package's launch files start, in one place (no ROS or launch imports).

* ``launch/ekf.launch.py`` (:func:`ekf_nodes`): ``ekf_node`` alone, for a robot whose drivers
  publish the inputs; ``pure_pursuit_node`` too only when ``path_file:=`` is given.
* ``launch/sim.launch.py`` (:func:`sim_nodes`): ``sim_node`` + ``ekf_node`` + ``pure_pursuit_node``;
  with ``camera:=images`` one ``tag_localizer`` per camera, with ``cameras:=2`` a second camera
  (``camera1``: its tag_localizer in namespace ``camera1``, fused as pose1).
* ``launch/ekf_localization.launch.py`` (deprecated, :func:`legacy_forward`): forwards to one of them.

Each launch file declares :data:`EKF_ARGUMENTS` / :data:`SIM_ARGUMENTS` and turns the
:class:`NodeSpec` list into ``launch_ros`` Nodes (:mod:`ekf_localization.ros.launch_actions`).
Namespaces: every node of one launch runs in ``namespace`` and uses relative topic names, so two
robots launched with ``namespace:=r1`` and ``namespace:=r2`` never share a topic except ``/tf``,
``/tf_static``, ``/clock`` and ``/diagnostics``; ``frame_prefix:=r1/`` (robot_state_publisher's
``frame_prefix``) keeps their TF frames apart on the shared ``/tf``.
"""

from __future__ import annotations

import os
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field

PACKAGE = "ekf_localization"

# launch argument -> the topic of the shipped YAMLs it remaps (ekf_node's inputs; cmd_vel is also
# pure_pursuit_node's output, so the follower and the filter stay connected)
INPUT_REMAPS: dict[str, str] = {
    "odom_topic": "odometry/dead_wheels",
    "pose_topic": "camera/pose",
    "imu_topic": "imu/data",
    "cmd_vel_topic": "cmd_vel",
    "joint_states_topic": "joint_states",
    "set_pose_topic": "set_pose",
}
# the frames frame_prefix applies to, and their defaults when the params file does not set them
# (map, the field, stays shared by every robot)
PREFIXED_FRAMES: dict[str, str] = {"odom_frame": "odom", "base_link_frame": "base_link"}

_COMMON = {
    "namespace": ("", "namespace of every node (e.g. r1); topics and services move under it"),
    "frame_prefix": ("", "prefix of this robot's odom and base_link frames (e.g. r1/; "
                         "robot_state_publisher's frame_prefix); map stays shared"),
}

EKF_ARGUMENTS: dict[str, tuple[str, str]] = {  # name -> (default, description); {config} = share/config
    **_COMMON,
    "params_file": ("{config}/ekf.yaml", "ekf_node parameter file"),
    "use_sim_time": ("false", "run on /clock (true when a simulator or a bag played with --clock "
                              "publishes it)"),
    **{name: (topic, f"the topic ekf_node reads as '{topic}'" + (" (and pure_pursuit_node writes)"
                                                                   if topic == "cmd_vel" else ""))
       for name, topic in INPUT_REMAPS.items()},
    "path_file": ("", "a path YAML: also start pure_pursuit_node to follow it (default: no follower)"),
    "pure_pursuit_params": ("{config}/pure_pursuit.yaml", "pure_pursuit_node parameter file"),
}

SIM_ARGUMENTS: dict[str, tuple[str, str]] = {
    **_COMMON,
    "use_sim_time": ("true", "run on the simulator's /clock (false: wall time; set it for two "
                             "simulators on one domain, which would otherwise both publish /clock)"),
    "sim_params": ("{config}/sim.yaml", "sim_node parameter file"),
    "ekf_params": ("", "ekf_node parameter file (default: ekf.yaml, with cameras:=2 ekf_two_cameras.yaml)"),
    "pure_pursuit_params": ("{config}/pure_pursuit.yaml", "pure_pursuit_node parameter file"),
    "path_file": ("{config}/paths/seed000_test_path.yaml", "path for pure_pursuit_node to follow"),
    "camera": ("poses", "poses: sim_node's finished camera poses; images: rendered AprilTag images, "
                        "one tag_localizer per camera"),
    "cameras": ("1", "1, or 2: a second camera (sim.yaml camera1, facing backward) on camera1/*, fused "
                     "as pose1"),
    "tag_localizer_params": ("{config}/tag_localizer.yaml", "tag_localizer parameter file (camera:=images)"),
    "tag_layout": ("{config}/tags/ftc_seed000.yaml", "the tags sim_node renders and tag_localizer solves "
                                                    "against (camera:=images)"),
}
# the cameras sim_node can carry: their topic namespaces (camera/image_raw, camera1/pose, ...)
CAMERAS = ("camera", "camera1")
# the second camera's tag_localizer runs in namespace camera1 and reads and writes these names in it
# (config/tag_localizer.yaml's are the first camera's camera/image_raw, camera/camera_info, camera/pose)
SECOND_CAMERA_TOPICS = {"image_topic": "image_raw", "camera_info_topic": "camera_info", "pose_topic": "pose"}

# the deprecated launch/ekf_localization.launch.py's arguments (use_sim chooses the file)
LEGACY_ARGUMENTS: dict[str, tuple[str, str]] = {
    "use_sim": ("true", "true: sim.launch.py; false: ekf.launch.py (no follower unless path_file is given)"),
    "use_sim_time": ("", "default: the value of use_sim"),
    "sim_params": ("", "sim_node parameter file"),
    "ekf_params": ("", "ekf_node parameter file"),
    "pure_pursuit_params": ("", "pure_pursuit_node parameter file"),
    "path_file": ("", "path for pure_pursuit_node to follow"),
}


@dataclass(frozen=True)
class NodeSpec:
    """One node: executable, node name, namespace, parameter files (in order), overrides, remaps."""

    executable: str
    name: str
    namespace: str = ""
    param_files: tuple[str, ...] = ()
    overrides: dict[str, object] = field(default_factory=dict)
    remaps: tuple[tuple[str, str], ...] = ()

    def command(self, executable_path: list[str] | None = None) -> list[str]:
        """The process a launch_ros Node with these settings runs (``ros2 run`` form)."""
        args = list(executable_path or [self.executable]) + ["--ros-args", "-r", f"__node:={self.name}"]
        if self.namespace:
            args += ["-r", f"__ns:=/{self.namespace.strip('/')}"]
        for path in self.param_files:
            args += ["--params-file", path]
        for key, value in self.overrides.items():
            args += ["-p", f"{key}:={_yaml(value)}"]
        for src, dst in self.remaps:
            args += ["-r", f"{src}:={dst}"]
        return args


def _yaml(value: object) -> str:
    if isinstance(value, bool):
        return "true" if value else "false"
    return str(value)


def flag(value: str | bool | None, name: str) -> bool | None:
    """A launch argument's true/false ('' or None: not given)."""
    if value is None or value == "":
        return None
    if isinstance(value, bool):
        return value
    text = str(value).strip().lower()
    if text in ("true", "1", "yes", "on"):
        return True
    if text in ("false", "0", "no", "off"):
        return False
    raise ValueError(f"launch argument '{name}': expected true or false, got {value!r}")


def defaults(arguments: Mapping[str, tuple[str, str]], share_dir: str) -> dict[str, str]:
    """Each argument's default value, with the package's share directory filled in."""
    config = os.path.join(share_dir, "config")
    return {name: default.replace("{config}", config) for name, (default, _) in arguments.items()}


def _values(arguments: Mapping[str, tuple[str, str]], share_dir: str, given: Mapping[str, object]) -> dict:
    unknown = set(given) - set(arguments)
    if unknown:
        raise ValueError(f"unknown launch arguments {sorted(unknown)}; known: {sorted(arguments)}")
    return {**defaults(arguments, share_dir), **{k: v for k, v in given.items() if v is not None}}


def _namespace(value: object) -> str:
    return str(value).strip().strip("/")


def _section(params_file: str, node: str, namespace: str) -> Mapping[str, object]:
    """The parameters ``params_file`` gives ``node`` in ``namespace`` ({} when it cannot be read)."""
    from ekf_localization.ros.params_match import params_file_section

    try:
        return params_file_section(params_file, f"/{namespace}/{node}" if namespace else f"/{node}")
    except (OSError, KeyError, TypeError, ValueError):
        return {}


def frame_overrides(params_file: str, node: str, namespace: str, prefix: str) -> dict[str, str]:
    """``odom_frame``/``base_link_frame`` of ``node`` (in ``namespace``) in ``params_file`` with
    ``prefix`` in front ({} without a prefix); a frame the file does not set gets its default."""
    if not prefix:
        return {}
    section = _section(params_file, node, namespace)
    return {key: prefix + str(section.get(key, default)).lstrip("/")
            for key, default in PREFIXED_FRAMES.items()}


def _remaps(values: Mapping[str, object]) -> tuple[tuple[str, str], ...]:
    return tuple((topic, str(values[name])) for name, topic in INPUT_REMAPS.items()
                 if str(values[name]).strip() and str(values[name]) != topic)


def ekf_nodes(share_dir: str, **arguments: object) -> list[NodeSpec]:
    """ekf.launch.py's nodes: ekf_node; pure_pursuit_node when ``path_file`` is given."""
    a = _values(EKF_ARGUMENTS, share_dir, arguments)
    ns, prefix = _namespace(a["namespace"]), str(a["frame_prefix"])
    use_sim_time = bool(flag(a["use_sim_time"], "use_sim_time"))
    remaps = _remaps(a)
    params = str(a["params_file"])
    frames = frame_overrides(params, "ekf_node", ns, prefix)
    clock = {"use_sim_time": use_sim_time}
    # the command topic: the launch argument, else the params file's cmd_vel_topic (a controller's)
    cmd_vel = tuple(r for r in remaps if r[0] == "cmd_vel")
    own = {"cmd_vel_topic": cmd_vel[0][1]} if cmd_vel else {}
    if not cmd_vel:
        in_file = _section(params, "ekf_node", ns).get("cmd_vel_topic")
        if isinstance(in_file, str) and in_file.strip() and in_file.strip() != "cmd_vel":
            cmd_vel = (("cmd_vel", in_file.strip()),)
    nodes = [NodeSpec("ekf_node", "ekf_node", ns, (params,), {**clock, **frames, **own}, remaps)]
    if str(a["path_file"]).strip():
        nodes.append(NodeSpec("pure_pursuit_node", "pure_pursuit_node", ns, (str(a["pure_pursuit_params"]),),
                              {"use_sim_time": use_sim_time, "path_file": str(a["path_file"])}, cmd_vel))
    return nodes


def _camera_count(value: object) -> int:
    text = str(value).strip()
    if text not in ("1", "2"):
        raise ValueError(f"launch argument 'cameras': expected 1 or 2, got {value!r}")
    return int(text)


def sim_nodes(share_dir: str, corner_inputs: Callable[..., dict] | None = None,
              **arguments: object) -> list[NodeSpec]:
    """sim.launch.py's nodes: sim_node (publishing /clock when the others use it), ekf_node and
    pure_pursuit_node; with ``camera:=images`` a tag_localizer per camera (the second one in
    namespace ``camera1``), and ekf_node's ``tag_cornersN`` inputs from ``corner_inputs(tag_yaml,
    layout, sim_yaml, cameras, sim_overrides)`` (the simulator's cameras: sim.launch.py passes
    sim_robot's; empty unless tag_localizer's ``single_tag`` is corners)."""
    a = _values(SIM_ARGUMENTS, share_dir, arguments)
    ns, prefix = _namespace(a["namespace"]), str(a["frame_prefix"])
    use_sim_time = bool(flag(a["use_sim_time"], "use_sim_time"))
    cameras = _camera_count(a["cameras"])
    mode = str(a["camera"]).strip()
    if mode not in ("poses", "images"):
        raise ValueError(f"launch argument 'camera': expected poses or images, got {a['camera']!r}")
    config = os.path.join(share_dir, "config")
    sim = str(a["sim_params"])
    ekf = str(a["ekf_params"]).strip() or os.path.join(
        config, "ekf_two_cameras.yaml" if cameras == 2 else "ekf.yaml")
    sim_overrides: dict[str, object] = {"publish_clock": use_sim_time,
                                        **frame_overrides(sim, "sim_node", ns, prefix)}
    if cameras == 2:
        sim_overrides["camera1.enabled"] = True
    layout = str(a["tag_layout"])
    if mode == "images":
        sim_overrides.update({"camera.enabled": False, "camera_images.enabled": True,
                              "camera_images.tag_layout": layout})
    if prefix and mode == "images":  # this robot's camera frames on the shared /tf_static
        section = _section(sim, "sim_node", ns)
        for key, default in (("camera_images", "camera_optical"), ("camera1", "camera1_optical"))[:cameras]:
            group = section.get(key)
            frame = group.get("frame_id", default) if isinstance(group, Mapping) else default
            sim_overrides[f"{key}.frame_id"] = prefix + str(frame).lstrip("/")
    ekf_extra = {}
    if mode == "images" and corner_inputs is not None:
        ekf_extra = corner_inputs(str(a["tag_localizer_params"]), layout, sim, cameras, sim_overrides)
    # the clock's source runs on wall time; it publishes /clock when the others use it
    nodes = [NodeSpec("sim_node", "sim_node", ns, (sim,), sim_overrides),
             NodeSpec("ekf_node", "ekf_node", ns, (ekf,),
                      {"use_sim_time": use_sim_time, **frame_overrides(ekf, "ekf_node", ns, prefix),
                       **ekf_extra}),
             NodeSpec("pure_pursuit_node", "pure_pursuit_node", ns, (str(a["pure_pursuit_params"]),),
                      {"use_sim_time": use_sim_time, "path_file": str(a["path_file"])})]
    if mode == "images":
        tags = str(a["tag_localizer_params"])
        base = {"use_sim_time": use_sim_time, "layout_file": layout}
        if prefix:
            base["base_link_frame"] = prefix + str(_section(tags, "tag_localizer", ns).get(
                "base_link_frame", PREFIXED_FRAMES["base_link_frame"])).lstrip("/")
        for camera in range(cameras):
            sub = "/".join(p for p in (ns, CAMERAS[camera]) if p) if camera else ns
            nodes.append(NodeSpec("tag_localizer", "tag_localizer", sub, (tags,),
                                  {**base, **(SECOND_CAMERA_TOPICS if camera else {})}))
    return nodes


def legacy_forward(**arguments: object) -> tuple[str, dict[str, str], str]:
    """The old ekf_localization.launch.py's arguments as (launch file, its arguments, deprecation
    message). With ``use_sim:=false`` the follower starts only when ``path_file`` is given."""
    a = {k: str(v) for k, v in _values(LEGACY_ARGUMENTS, "", arguments).items()}
    use_sim = flag(a["use_sim"], "use_sim")
    use_sim_time = flag(a["use_sim_time"], "use_sim_time")
    use_sim_time = bool(use_sim) if use_sim_time is None else use_sim_time
    out = {"use_sim_time": "true" if use_sim_time else "false"}
    if use_sim:
        target = "sim.launch.py"
        out.update({k: a[k] for k in ("sim_params", "ekf_params", "pure_pursuit_params", "path_file")
                    if a[k]})
    else:
        target = "ekf.launch.py"
        out.update({k: a[k] for k in ("pure_pursuit_params", "path_file") if a[k]})
        if a["ekf_params"]:
            out["params_file"] = a["ekf_params"]
    shown = " ".join(f"{k}:={v}" for k, v in out.items())
    message = (f"ekf_localization.launch.py is deprecated and will be removed: use "
               f"'ros2 launch {PACKAGE} {target} {shown}' (starting that now)")
    return target, out, message
