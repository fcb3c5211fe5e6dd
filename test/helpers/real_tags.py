"""Real photographs of tag36h11 tags, kept outside the repository, and the detection match.

The photographs live in the directory named by the environment variable ``EKF_REAL_TAGS``,
else in ``<repo>/../shared/data/real_tags`` when that exists (docs/apriltags.md: sources,
licences and layout). ``data_dir`` returns it, or ``None`` with ``MISSING`` saying why, so
that the tests and benchmarks that need them skip cleanly.

``reference_detect`` is the bare AprilRobotics library (``dt_apriltags``) with its own
settings at full resolution (``quad_decimate`` 1, ``quad_sigma`` 0, ``refine_edges`` 1,
``decode_sharpening`` 0.25), corners moved into this package's pixel convention like
``vision/detectors/apriltag_lib.py``. ``match`` pairs another detector's tags with them: the
same id and every corner within ``MATCH_PX``.
"""

from __future__ import annotations

import os
import weakref
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ekf_localization.vision.detection import TagDetection
from ekf_localization.vision.detectors.apriltag_lib import release

ENV = "EKF_REAL_TAGS"
FALLBACK = Path(__file__).resolve().parents[2].parent / "shared" / "data" / "real_tags"
MATCH_PX = 2.0
TAG_SIZE = 0.065                     # m, the dt_apriltags photographs' tags (test_info.yaml)
# the rotation series: the tag turned about its vertical axis by the angle in the file name
ROTATION_ANGLES_DEG = tuple(range(-70, 80, 10))
REFERENCE_SETTINGS = {"quad_decimate": 1.0, "quad_sigma": 0.0, "refine_edges": 1,
                      "decode_sharpening": 0.25}


def data_dir() -> Path | None:
    """The photographs' directory: ``$EKF_REAL_TAGS``, else :data:`FALLBACK` if it exists."""
    env = os.environ.get(ENV)
    if env:
        path = Path(env).expanduser()
        return path if (path / "dt_apriltags").is_dir() else None
    return FALLBACK if (FALLBACK / "dt_apriltags").is_dir() else None


def missing_reason() -> str:
    """Why :func:`data_dir` found no photographs (for ``pytest.skip`` and the benchmarks)."""
    env = os.environ.get(ENV)
    where = f"{ENV}={env} has no dt_apriltags/ folder" if env else \
        f"{ENV} is not set and {FALLBACK} does not exist"
    return f"real tag photographs not found ({where}); see docs/apriltags.md for their layout"


def _dir() -> Path:
    path = data_dir()
    if path is None:
        raise FileNotFoundError(missing_reason())
    return path


def rotation_camera() -> Path:
    """The rotation series' calibration YAML."""
    return _dir() / "dt_apriltags" / "camera_rotation.yaml"


@dataclass(frozen=True)
class RealImage:
    path: Path
    camera: Path | None              # calibration YAML (vision/camera_yaml.py), if known
    group: str


def rotation_path(angle_deg: int) -> Path:
    return _dir() / "dt_apriltags" / f"test_image_rotation_{angle_deg}.png"


def images() -> list[RealImage]:
    """Every kept photograph with its camera: 640x480 PNGs, then the 799x533 JPEGs."""
    data = _dir()
    dt = data / "dt_apriltags"
    out = [RealImage(dt / "test_image.png", dt / "camera_sample.yaml", "dt_apriltags sample")]
    out += [RealImage(p, dt / "camera_multiple.yaml", "dt_apriltags multiple")
            for p in sorted(dt.glob("test_image_multiple_*.png"))]
    out += [RealImage(rotation_path(a), dt / "camera_rotation.yaml", "dt_apriltags rotation")
            for a in ROTATION_ANGLES_DEG]
    out += [RealImage(p, None, "apriltag (NASA Swarmathon)")
            for p in sorted((data / "apriltag").glob("*.jpg"))]
    missing = [str(i.path) for i in out if not i.path.exists()]
    if missing:
        raise FileNotFoundError(f"real tag images missing: {missing}")
    return out


def read_grey(path: Path) -> np.ndarray:
    import cv2

    image = cv2.imread(str(path), cv2.IMREAD_GRAYSCALE)
    if image is None:
        raise ValueError(f"cannot read {path}")
    return image


def library_detector(**settings: float) -> object:
    """The bare ``dt_apriltags.Detector`` with :data:`REFERENCE_SETTINGS` (``settings`` override
    them); free it with ``apriltag_lib.release``."""
    from dt_apriltags import Detector

    return Detector(families="tag36h11", nthreads=1, **{**REFERENCE_SETTINGS, **settings})


class ReferenceDetector:
    """The bare library with :data:`REFERENCE_SETTINGS`, hamming 0 as the package keeps."""

    name = "library defaults (decimate 1)"

    def __init__(self, **settings: float) -> None:
        self._detector = library_detector(**settings)
        weakref.finalize(self, release, self._detector)

    def detect(self, image: np.ndarray) -> list[TagDetection]:
        found = self._detector.detect(np.ascontiguousarray(image, dtype=np.uint8))
        return [TagDetection(int(d.tag_id), np.asarray(d.corners, float).reshape(4, 2) - 0.5,
                             int(d.hamming), float(d.decision_margin))
                for d in found if d.hamming == 0]


@dataclass(frozen=True)
class Match:
    reference: int          # tags the reference found
    matched: int            # of them, found by the other detector (same id, corners <= MATCH_PX)
    extra: int              # the other detector's tags that match none of the reference's
    worst_px: float         # largest corner distance over the matched tags

    def __add__(self, other: Match) -> Match:
        return Match(self.reference + other.reference, self.matched + other.matched,
                     self.extra + other.extra, max(self.worst_px, other.worst_px))


def match(reference: list[TagDetection], ours: list[TagDetection]) -> Match:
    """Greedy one-to-one pairing by id and the largest corner distance (<= MATCH_PX)."""
    free = list(range(len(ours)))
    matched, worst = 0, 0.0
    for ref in reference:
        best, best_d = None, MATCH_PX
        for j in free:
            if ours[j].tag_id != ref.tag_id:
                continue
            d = float(np.max(np.linalg.norm(np.asarray(ours[j].corners) - ref.corners, axis=1)))
            if d <= best_d:
                best, best_d = j, d
        if best is not None:
            free.remove(best)
            matched += 1
            worst = max(worst, best_d)
    return Match(len(reference), matched, len(free), worst)
