"""tag_layout_from_wpilib: WPILib's AprilTagFieldLayout JSON -> this package's tag layout YAML.

    tag_layout_from_wpilib 2025-reefscape.json -o config/tags/reefscape.yaml [--tag-size 0.1651]

The JSON (the format FRC publishes each season)::

    {"tags": [{"ID": 1, "pose": {"translation": {"x": .., "y": .., "z": ..},
               "rotation": {"quaternion": {"W": .., "X": .., "Y": .., "Z": ..}}}}, ...],
     "field": {"length": 17.548, "width": 8.052}}

WPILib's tag frame is this package's (origin at the tag centre, +x out of the printed face,
+z up; see vision/tag_layout.py), and its field origin is a field corner (blue alliance
wall, right-hand side), so poses and the field size are copied as they are. The JSON has no
tag size: ``--tag-size`` (m, the black square's edge; FRC's 2024+ tags: 6.5 in = 0.1651 m).
The output is checked by reading it back with ``tag_layout_from_dict``. Exit 2 on a bad file.
"""

from __future__ import annotations

import argparse
import json
import math
import sys
from collections.abc import Mapping
from pathlib import Path

from ekf_localization.vision.tag_layout import TAG_FAMILY, tag_layout_from_dict

FRC_TAG_SIZE = 0.1651   # m (6.5 in)


def _get(data: object, key: str, where: str) -> object:
    if not isinstance(data, Mapping) or key not in data:
        raise ValueError(f"{where}: missing '{key}'")
    return data[key]


def _num(data: object, key: str, where: str) -> float:
    value = _get(data, key, where)
    if isinstance(value, bool) or not isinstance(value, int | float) or not math.isfinite(value):
        raise ValueError(f"{where}.{key}: expected a finite number, got {value!r}")
    return float(value)


def layout_from_wpilib(data: object, tag_size: float = FRC_TAG_SIZE,
                       source: str = "WPILib layout") -> dict:
    """The tag layout YAML's dict of a parsed AprilTagFieldLayout JSON; ValueError if bad."""
    if not (math.isfinite(tag_size) and tag_size > 0.0):
        raise ValueError(f"tag size must be > 0 (m), got {tag_size}")
    tags = _get(data, "tags", source)
    if not isinstance(tags, list):
        raise ValueError(f"{source}: 'tags' must be a list")
    out = []
    for i, tag in enumerate(tags):
        where = f"{source}: tags[{i}]"
        tag_id = _get(tag, "ID", where)
        pose = _get(tag, "pose", where)
        t = _get(pose, "translation", f"{where}.pose")
        q = _get(_get(pose, "rotation", f"{where}.pose"), "quaternion", f"{where}.pose.rotation")
        qw = f"{where}.pose.rotation.quaternion"
        out.append({"id": tag_id, "size": float(tag_size),
                    "position": [_num(t, k, f"{where}.pose.translation") for k in "xyz"],
                    "orientation": [_num(q, k, qw) for k in "XYZW"]})
    result: dict = {"tag_family": TAG_FAMILY, "tags": out}
    if isinstance(data, Mapping) and data.get("field") is not None:
        field = data["field"]
        result["field"] = {"length": _num(field, "length", f"{source}: field"),
                           "width": _num(field, "width", f"{source}: field")}
    tag_layout_from_dict(result, source)   # the same checks as loading the YAML
    return result


def main(argv: list[str] | None = None) -> int:
    import yaml

    parser = argparse.ArgumentParser(prog="tag_layout_from_wpilib", description=__doc__.split("\n")[0])
    parser.add_argument("json", help="WPILib AprilTagFieldLayout JSON")
    parser.add_argument("-o", "--output", help="YAML file to write (default: stdout)")
    parser.add_argument("--tag-size", type=float, default=FRC_TAG_SIZE,
                        help=f"tag edge (black square), m (default {FRC_TAG_SIZE})")
    args = parser.parse_args(argv)
    try:
        data = json.loads(Path(args.json).read_text(encoding="utf-8"))
        layout = layout_from_wpilib(data, args.tag_size, args.json)
    except (OSError, ValueError) as exc:   # json.JSONDecodeError is a ValueError
        print(f"tag_layout_from_wpilib: {exc}", file=sys.stderr)
        return 2
    text = (f"# from {Path(args.json).name} by tag_layout_from_wpilib (tag size {args.tag_size} m)\n"
            + yaml.safe_dump(layout, sort_keys=False, default_flow_style=None))
    if args.output:
        Path(args.output).write_text(text, encoding="utf-8")
    else:
        sys.stdout.write(text)
    return 0


if __name__ == "__main__":
    sys.exit(main())
