"""visualization_msgs/MarkerArray from plain point lists (the geometry is ``core/ellipse.py``'s).

The namespaces are the contract between the nodes that publish markers (ekf_node,
pure_pursuit_node, tag_localizer), the shipped RViz / Foxglove layouts in ``config/`` and
``field_view`` (which reads the camera fixes from ekf_node's markers and the camera's field of
view and the tags it sees from tag_localizer's).
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
from builtin_interfaces.msg import Duration, Time
from geometry_msgs.msg import Point
from std_msgs.msg import ColorRGBA
from visualization_msgs.msg import Marker, MarkerArray

from ekf_localization.core.units import ns_to_sec_nanosec, seconds_to_ns

EKF_MARKER_TOPIC = "~/markers"  # ekf_node's private topic: <namespace>/ekf_node/markers
EKF_MARKER_TOPIC_OUTSIDE = "ekf_node/markers"  # that topic as another node in the namespace names it
PURE_PURSUIT_MARKER_TOPIC = "pure_pursuit/markers"
TAG_LOCALIZER_MARKER_TOPIC = "~/markers"  # tag_localizer's private topic
TAG_LOCALIZER_MARKER_TOPIC_OUTSIDE = "tag_localizer/markers"
NS_ELLIPSE = "covariance_95"
NS_FIXES_ACCEPTED = "camera_fixes/accepted"
NS_FIXES_GATED = "camera_fixes/gated"
NS_PATH = "path"
NS_LOOKAHEAD = "lookahead"
NS_TARGET = "target"
NS_CAMERA_FOV = "camera_fov"  # tag_localizer: the camera's field of view on the floor, in base_link
NS_TAGS_SEEN = "tags_seen"  # tag_localizer: the layout tags in the newest image, in map

RGBA = tuple[float, float, float, float]
ELLIPSE_RGBA: RGBA = (0.1, 0.5, 1.0, 1.0)
ACCEPTED_RGBA: RGBA = (0.1, 0.8, 0.2, 0.9)
GATED_RGBA: RGBA = (1.0, 0.15, 0.1, 0.9)
PATH_RGBA: RGBA = (0.95, 0.75, 0.1, 1.0)
LOOKAHEAD_RGBA: RGBA = (0.8, 0.3, 0.9, 0.8)
TARGET_RGBA: RGBA = (0.8, 0.3, 0.9, 1.0)
CAMERA_FOV_RGBA: RGBA = (0.05, 0.65, 0.91, 0.8)
TAGS_SEEN_RGBA: RGBA = (0.05, 0.65, 0.91, 1.0)
MARKER_Z = 0.01  # m above the floor, so the markers sit on the field image


def _base(ns: str, marker_type: int, frame_id: str, stamp: Time, rgba: RGBA, lifetime_s: float) -> Marker:
    m = Marker()
    m.header.frame_id = frame_id
    m.header.stamp = stamp
    m.ns = ns
    m.id = 0
    m.type = marker_type
    m.action = Marker.ADD
    m.pose.orientation.w = 1.0
    m.color = ColorRGBA(r=rgba[0], g=rgba[1], b=rgba[2], a=rgba[3])
    sec, nanosec = ns_to_sec_nanosec(seconds_to_ns(lifetime_s))
    m.lifetime = Duration(sec=sec, nanosec=nanosec)
    return m


def _points(xy: np.ndarray | Sequence[Sequence[float]]) -> list[Point]:
    return [Point(x=float(x), y=float(y), z=MARKER_Z) for x, y in np.asarray(xy, dtype=float).reshape(-1, 2)]


def line_strip(ns: str, frame_id: str, stamp: Time, xy, rgba: RGBA, width: float,
               lifetime_s: float = 0.0) -> Marker:
    """A LINE_STRIP through the (N, 2) points ``xy`` (width in m)."""
    m = _base(ns, Marker.LINE_STRIP, frame_id, stamp, rgba, lifetime_s)
    m.scale.x = float(width)
    m.points = _points(xy)
    return m


def sphere_list(ns: str, frame_id: str, stamp: Time, xy, rgba: RGBA, diameter: float,
                lifetime_s: float = 0.0) -> Marker:
    """A SPHERE_LIST at the (N, 2) points; none: a DELETE of the namespace's marker."""
    m = _base(ns, Marker.SPHERE_LIST, frame_id, stamp, rgba, lifetime_s)
    m.scale.x = m.scale.y = m.scale.z = float(diameter)
    m.points = _points(xy)
    if not m.points:
        m.action = Marker.DELETE
    return m


def marker_array(markers: Sequence[Marker]) -> MarkerArray:
    return MarkerArray(markers=list(markers))


def points_of(array: MarkerArray, ns: str) -> list[tuple[float, float]] | None:
    """The (x, y) points of namespace ``ns`` in ``array`` ([] for a DELETE, None when absent)."""
    for m in array.markers:
        if m.ns == ns:
            return [] if m.action != Marker.ADD else [(p.x, p.y) for p in m.points]
    return None
