"""Each input's message parts in the filter's frames (REP-105), no ROS imports.

Poses go to base_link in the world frame, twists and IMU data to base_link (core.frames does
the maths). A part already in those frames by name is taken as it is (remembered per input
and frame ids). robot_localization's ``_differential`` and ``_relative`` pose inputs
(core.pose_modes) turn a pose into its rates, or into the pose relative to the first one.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import replace
from typing import Any

from ekf_localization.core.config import EkfConfig
from ekf_localization.core.frames import (
    RigidTransform,
    TransformBuffer,
    already_in_filter_frames,
    to_filter_frames,
)
from ekf_localization.core.lru import Lru
from ekf_localization.core.measurements import (
    REJECT_NO_TRANSFORM,
    REJECT_STAMP_NOT_INCREASING,
    MeasurementPart,
    parts_of,
)
from ekf_localization.core.part_plans import RATE_PARTS
from ekf_localization.core.pose_modes import PoseDifferentiator, PoseRelative

FRAME_CACHE_CAP = 64  # per-frame entries kept (each Lru): frame ids come from messages, any number of them


class InputFrames:
    """The transform buffer and each input's way into the filter's frames.

    An input is registered once (:meth:`register`) with its settings: ``differential``,
    ``relative``, ``default_frame_id``, ``pose_frame``, ``pose_use_child_frame`` (inputs/parts.py)."""

    def __init__(self, config: EkfConfig, warn: Callable[[str], None]) -> None:
        self._config = config
        self._inputs: dict[str, Any] = {}
        self._used: dict[str, set[str]] = {}  # per input: the names of the message parts it reads
        self._layouts: dict[tuple[str, type], tuple] = {}  # (input, record class): the LAYOUT of those parts
        self._warn = warn
        # tf2 / /tf and /tf_static (fed by the node or bag_replay) and the static_transforms parameter,
        # pinned: messages for its frames do not replace it
        self.transforms = TransformBuffer()
        for parent, child, xyz_ypr in config.static_transforms:
            self.transforms.set_static(parent, child, RigidTransform.from_xyz_ypr(*xyz_ypr), pinned=True)
        self._pose_modes: dict[str, PoseDifferentiator | PoseRelative] = {}
        # (input, frame_id, child_frame_id) -> whether such messages are already in the filter's frames
        self._identity = Lru(FRAME_CACHE_CAP)
        # (input, target, source) of the missing transforms already warned about
        self._warned = Lru(FRAME_CACHE_CAP)

    def register(self, name: str, settings: Any, used_parts: set[str]) -> None:
        """Input ``name`` reads the message parts ``used_parts``, with ``settings``."""
        self._inputs[name] = settings
        self._used[name] = used_parts
        if settings.differential or settings.relative:
            self._pose_modes[name] = PoseDifferentiator() if settings.differential else PoseRelative()

    @property
    def frame_cache(self) -> tuple[int, int, int]:
        """(entries, cap, evictions) of the per-frame bookkeeping (ekf_node's /diagnostics)."""
        caches = (self._identity, self._warned)
        return sum(len(c) for c in caches), sum(c.cap for c in caches), sum(c.evictions for c in caches)

    def reset(self) -> None:
        """Forget the pose modes' previous poses (after a filter reset)."""
        for mode in self._pose_modes.values():
            mode.reset()

    def with_frame(self, source: str, measurement):
        """``measurement``, in ``<input>_default_frame_id`` when its frame_id is empty; None when a
        part the input uses still has no frame (rejected as no_frame: an empty frame is not
        base_link). An odometry twist is in the child_frame_id, which no default replaces."""
        if measurement.frame_id.strip().lstrip("/") and getattr(measurement, "child_frame_id", "x"):
            return measurement  # the usual case: every frame named
        default = self._inputs[source].default_frame_id
        if default and not measurement.frame_id.strip().lstrip("/"):
            measurement = replace(measurement, frame_id=default)
        used = self._used[source]
        if any(p.name in used and p.provided and not p.frame_id.strip().lstrip("/")
               for p in measurement.parts()):
            return None
        return measurement

    def _pose_of(self, source: str, part: MeasurementPart) -> str:
        inp = self._inputs[source]
        return (part.child_frame_id if inp.pose_use_child_frame else inp.pose_frame) or ""

    def parts(self, source: str, measurement,
              stamp: int) -> tuple[dict[str, MeasurementPart], dict[str, str]]:
        """The parts ``source`` uses in the filter's frames, and {part: reason} of those that could
        not be transformed (no transform, or a differential pose whose stamp did not increase).
        The parts it does not use are not built."""
        layout = self._layouts.get((source, type(measurement)))
        if layout is None:
            used = self._used[source]
            layout = self._layouts[source, type(measurement)] = tuple(
                lay for lay in measurement.LAYOUT if lay.name in used)
        all_parts = parts_of(measurement, layout)
        key = (source, measurement.frame_id, getattr(measurement, "child_frame_id", None))
        known = self._identity.get(key)
        if known is None:
            cfg = self._config
            used = self._used[source]
            known = source not in self._pose_modes and all(
                already_in_filter_frames(p, cfg.world_frame, cfg.base_link_frame, self._pose_of(source, p))
                for p in all_parts if p.name in used)
            self._identity.put(key, known)
        if known:  # nothing to transform
            return {part.name: part for part in all_parts}, {}
        return self._transformed(source, all_parts, stamp)

    def _transformed(self, source: str, all_parts: tuple[MeasurementPart, ...],
                     stamp: int) -> tuple[dict[str, MeasurementPart], dict[str, str]]:
        cfg = self._config
        parts: dict[str, MeasurementPart] = {}
        missing: dict[str, str] = {}
        for part in all_parts:
            if part.name not in self._used[source] or not part.provided:
                parts[part.name] = part
                continue
            mode = self._pose_modes.get(source) if part.name in RATE_PARTS else None
            own = part.frame_id.strip().lstrip("/") or cfg.world_frame  # a mode works in the sensor's frame
            world = cfg.world_frame if mode is None else own
            out, gap = to_filter_frames(part, stamp, self.transforms.lookup, world, cfg.base_link_frame,
                                        self._pose_of(source, part))
            if out is None:
                missing[part.name] = REJECT_NO_TRANSFORM
                if (source, *gap) not in self._warned:
                    self._warned.put((source, *gap), True)
                    self._warn(f"{source}: no transform {gap[0]} <- {gap[1]} (from tf2, /tf, /tf_static or "
                               f"static_transforms): its data is rejected as {REJECT_NO_TRANSFORM}")
                parts[part.name] = part
            elif mode is None:
                parts[part.name] = out
            else:
                self._apply_pose_mode(mode, out, stamp, parts, missing)
        return parts, missing

    def _apply_pose_mode(self, mode, part: MeasurementPart, stamp: int, parts: dict[str, MeasurementPart],
                         missing: dict[str, str]) -> None:
        """A pose / orientation part in its own frame -> its rates (differential) or relative pose."""
        if isinstance(mode, PoseRelative):
            values, cov = mode.update(part.values, part.covariance)
            frame = self._config.world_frame if part.name == "pose" else self._config.base_link_frame
            parts[part.name] = replace(part, frame_id=frame, values=values, covariance=cov)
            return
        rate_name = RATE_PARTS[part.name]
        out = mode.update(stamp, part.values, part.covariance)
        if out == "not_increasing":
            missing[rate_name] = REJECT_STAMP_NOT_INCREASING
        elif out is not None:
            parts[rate_name] = MeasurementPart(rate_name, part.first_field + 6, self._config.base_link_frame,
                                               out[0], out[1])
