"""The shipped AprilTag detector on real photographs, against the bare library, in one run.

    python benchmarks/bench_tag_real_images.py [--repeats 5] [--doc]

The photographs are read from the directory ``$EKF_REAL_TAGS`` (else
``<repo>/../shared/data/real_tags``; docs/apriltags.md gives their sources and layout: 26
dt-apriltags test images with their intrinsics, 3 NASA Swarmathon JPEGs). Printed:

- detections: the tags the bare AprilRobotics library finds with its own settings at full
  resolution (``quad_decimate`` 1, ``quad_sigma`` 0; test/helpers/real_tags.py), how many of
  them each detector matches (same id, all four corners within 2 px) and its extra tags; the
  rows are the shipped detector (``vision/detectors`` defaults), the library's ``quad_decimate``
  2 (its built-in default), the blur ``quad_sigma`` 0.8 and the other detector, OpenCV's aruco;
- speed at 640x480 on one core: CPU time (``time.process_time``, OpenCV on one thread) per
  frame over the 640x480 images (the NASA ones resized), and frames/s; the JPEG decode time
  per frame (the same frames encoded at quality 90, decoded to grey by OpenCV);
- image statistics of the photographs, of the simulator's camera (config/sim.yaml
  ``camera_images``: ``noise_std``, ``optics_blur_std``) and of the tag tests' renderer
  (test/helpers/tag_images.py, with ``PHOTO_NOISE_STD`` and ``PHOTO_BLUR_STD``, and with 2 grey
  levels of noise and no lens blur): the pixel noise (Immerkær's estimate over the flatter half,
  grey levels) and the edge blur (std of the edge's derivative across the tags' outer edges,
  px); each detector's time on the rendered frames, and the shipped detector's on
  bench_tag_detectors' base scene at noise 0.5, 1 and 2;
- tag_detect's pose of the rotation series against its stated pose.

``--doc`` writes the figures into docs/performance.md (benchmarks/perf_doc.py).
"""

from __future__ import annotations

import argparse
import math
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "test"))
sys.path.insert(0, str(Path(__file__).resolve().parent))

import bench_tag_detectors  # noqa: E402
from helpers import real_tags, tag_images  # noqa: E402

from ekf_localization.tools.tag_detect import tag_pose  # noqa: E402
from ekf_localization.vision.camera_yaml import load_camera_yaml  # noqa: E402
from ekf_localization.vision.detectors import make_detector  # noqa: E402
from ekf_localization.vision.detectors.apriltag_lib import release  # noqa: E402

SIZE = (640, 480)
RENDER_NOISE_SWEEP = (0.5, 1.0, 2.0)     # grey levels of the renderer's noise


def detectors() -> dict[str, object]:
    return {"shipped": make_detector("apriltag"),
            "library quad_decimate 2": real_tags.ReferenceDetector(quad_decimate=2.0),
            "quad_sigma 0.8": make_detector("apriltag", quad_sigma=0.8),
            "opencv aruco": make_detector("opencv")}


def cpu_per_frame(detect, frames: list[np.ndarray], repeats: int) -> float:
    """Seconds of CPU per call of ``detect`` over ``frames``, ``repeats`` times (warm)."""
    detect(frames[0])
    t0 = time.process_time()
    for _ in range(repeats):
        for f in frames:
            detect(f)
    return (time.process_time() - t0) / (repeats * len(frames))


def noise_std(image: np.ndarray) -> float:
    """Immerkær's fast noise estimate (grey levels) over the flatter half of the image (the
    pixels of least Sobel gradient), so that edges and texture count less."""
    import cv2

    f = image.astype(np.float64)
    mask = np.array([[1, -2, 1], [-2, 4, -2], [1, -2, 1]], dtype=np.float64)
    r = np.abs(cv2.filter2D(f, -1, mask))[1:-1, 1:-1]
    grad = np.hypot(cv2.Sobel(f, -1, 1, 0), cv2.Sobel(f, -1, 0, 1))[1:-1, 1:-1]
    flat = grad <= np.median(grad)
    return float(math.sqrt(math.pi / 2.0) * np.mean(r[flat]) / 6.0)


def edge_blur(image: np.ndarray, corners: np.ndarray, min_edge_px: float = 60.0) -> list[float]:
    """Blur (px) at the middle of each outer edge of a tag at least ``min_edge_px`` long: the
    std of the intensity profile's derivative along the edge normal, within a third of a cell."""
    import cv2

    out = []
    for i in range(4):
        a, b = corners[i], corners[(i + 1) % 4]
        length = float(np.linalg.norm(b - a))
        if length < min_edge_px:
            continue
        t = (b - a) / length
        n = np.array([-t[1], t[0]])
        reach = length / 8.0 / 3.0 + 2.0                      # px: well inside the black border
        s = np.arange(-reach, reach + 1e-9, 0.25)
        along = np.linspace(0.35, 0.65, 9)                    # average along the edge's middle
        pts = (a + np.outer(along, b - a))[:, None, :] + s[None, :, None] * n
        prof = cv2.remap(image.astype(np.float32), pts[..., 0].astype(np.float32),
                         pts[..., 1].astype(np.float32), cv2.INTER_LINEAR).mean(axis=0)
        g = np.abs(np.gradient(prof, s))
        g = np.clip(g - 0.1 * g.max(), 0.0, None)
        if g.sum() <= 0.0:
            continue
        mu = float(np.sum(g * s) / g.sum())
        out.append(float(math.sqrt(np.sum(g * (s - mu) ** 2) / g.sum())))
    return out


def rendered_frames(n: int, noise_std: float, blur_std: float, wall_m: float = 1.7) -> list[np.ndarray]:
    """benchmarks/bench_tag_localizer.py's scene (three tags, ``wall_m`` + 0.4 m from the wall:
    1.2-2.2 m at the default; 0.9 m gives edges long enough for the blur estimate)."""
    rng = np.random.default_rng(0)
    return [tag_images.render(np.array([wall_m + 0.4 * math.sin(0.15 * i), 1.6 + 0.025 * i, 0.0, 0.0,
                                        0.0, math.pi - 0.1 * math.sin(0.2 * i)]),
                              (1, 2, 3), noise_std=noise_std, rng=rng, blur_std=blur_std)
            for i in range(n)]


def simulator_frames(n: int) -> list[np.ndarray]:
    """The simulator's camera (config/sim.yaml ``camera_images``, its renderer settings) facing a
    wall of four 16.5 cm tags from 0.8-1.35 m, still (no motion blur)."""
    from ekf_localization.ros.parameters import parameters_from_yaml
    from ekf_localization.vision.tag_layout import tag_layout_from_dict
    from sim_robot.ros.sim_params import parse_parameters
    from sim_robot.world.camera_render import CameraRenderer, optical_pose, planar_pose

    values = parameters_from_yaml(Path(__file__).resolve().parents[1] / "config" / "sim.yaml", "sim_node")
    values["camera_images.enabled"] = True
    config = parse_parameters(values)[1].camera_images
    layout = tag_layout_from_dict({"tags": [{"id": i, "size": 0.1651, "position": [0.0, 0.5 + 0.45 * i, 0.3],
                                             "yaw": 0.0} for i in range(4)]})
    renderer = CameraRenderer(config.camera, layout, config.render)
    rng = np.random.default_rng(3)
    return [renderer.render(optical_pose(planar_pose(0.8 + 0.05 * i, 1.2 + 0.03 * i, 0.3 + 0.01 * i,
                                                     math.pi + 0.05 * math.sin(i))), None, rng)
            for i in range(n)]


def image_statistics(frames: list[np.ndarray], reference) -> tuple[float, float]:
    """(median noise std, median edge blur) of ``frames`` (blur on the reference's tags)."""
    noise = [noise_std(f) for f in frames]
    blur = [b for f in frames for d in reference.detect(f) for b in edge_blur(f, d.corners)]
    return float(np.median(noise)), float(np.median(blur)) if blur else math.nan


def rotation_poses() -> list[tuple[int, np.ndarray, float, np.ndarray]]:
    """(stated angle, camera <- tag, reprojection RMS px, the library's own camera <- tag) of
    each rotation image: tag_detect's solve, and the library's (another algorithm, its own
    tag axes) on the same corners."""
    camera = load_camera_yaml(real_tags.rotation_camera())
    detector = make_detector("apriltag")
    library = real_tags.library_detector()
    out = []
    try:
        for angle in real_tags.ROTATION_ANGLES_DEG:
            image = real_tags.read_grey(real_tags.rotation_path(angle))
            T, _, rms = tag_pose(detector.detect(image)[0], camera, real_tags.TAG_SIZE)
            lib = library.detect(image, True, (camera.fx, camera.fy, camera.cx, camera.cy),
                                 real_tags.TAG_SIZE)[0]
            L = np.eye(4)
            L[:3, :3], L[:3, 3] = lib.pose_R, np.ravel(lib.pose_t)
            out.append((angle, T, rms, L))
    finally:
        release(library)
    return out


def rotation_angle_deg(A: np.ndarray, B: np.ndarray) -> float:
    """The angle (deg) of the rotation between the frames A and B (4x4, same parent)."""
    c = (np.trace(A[:3, :3].T @ B[:3, :3]) - 1.0) / 2.0
    return math.degrees(math.acos(min(1.0, max(-1.0, c))))


def turn_about_vertical(T0: np.ndarray, T: np.ndarray) -> tuple[float, float]:
    """(signed angle deg about the tag's vertical +z, the rest of the rotation deg) of T relative
    to T0, both camera <- tag."""
    from scipy.spatial.transform import Rotation

    rel = Rotation.from_matrix(T0[:3, :3].T @ T[:3, :3]).as_rotvec()   # in the tag frame
    about_z = float(rel[2])
    rest = float(np.linalg.norm(rel - np.array([0.0, 0.0, about_z])))
    return math.degrees(about_z), math.degrees(rest)


def main() -> int:
    import cv2

    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--repeats", type=int, default=5, help="passes over the frames for the timing")
    ap.add_argument("--doc", action="store_true", help="write the figures into docs/performance.md")
    args = ap.parse_args()
    cv2.setNumThreads(1)
    if real_tags.data_dir() is None:
        print(real_tags.missing_reason(), file=sys.stderr)
        return 2
    images = real_tags.images()
    grey = [real_tags.read_grey(i.path) for i in images]
    reference = real_tags.ReferenceDetector()
    dets = detectors()

    # detections, on the images as kept
    refs = [reference.detect(g) for g in grey]
    print(f"{len(images)} photographs, {sum(map(len, refs))} tags found by the "
          f"{reference.name}:")
    totals = {}
    for name, det in dets.items():
        total = real_tags.Match(0, 0, 0, 0.0)
        for g, r in zip(grey, refs, strict=True):
            total = total + real_tags.match(r, det.detect(g))
        totals[name] = total
        print(f"  {name:26s} matches {total.matched}/{total.reference} (worst corner "
              f"{total.worst_px:.2f} px), {total.extra} extra")

    # speed at 640x480
    frames = [g if g.shape[::-1] == SIZE else cv2.resize(g, SIZE, interpolation=cv2.INTER_AREA)
              for g in grey]
    speed = {"library defaults (decimate 1)": cpu_per_frame(reference.detect, frames, args.repeats)}
    speed.update({name: cpu_per_frame(det.detect, frames, args.repeats) for name, det in dets.items()})
    jpegs = [cv2.imencode(".jpg", f, [cv2.IMWRITE_JPEG_QUALITY, 90])[1] for f in frames]
    decode = cpu_per_frame(lambda b: cv2.imdecode(b, cv2.IMREAD_GRAYSCALE), jpegs, 4 * args.repeats)
    print(f"640x480, one core, CPU per frame over {len(frames)} frames x {args.repeats}:")
    for name, s in speed.items():
        print(f"  {name:30s} {1e3 * s:6.1f} ms  {1.0 / s:6.0f} frames/s")
    print(f"  JPEG decode (quality 90, to grey) {1e3 * decode:.2f} ms per frame; the shipped "
          f"detector + decode: {1.0 / (speed['shipped'] + decode):.0f} frames/s")

    # the photographs against the renderer
    photo = (tag_images.PHOTO_NOISE_STD, tag_images.PHOTO_BLUR_STD)
    rendered = {"rendered, noise 2, no lens blur": rendered_frames(40, 2.0, 0.0),
                f"rendered, noise {photo[0]:g}, blur {photo[1]:g}": rendered_frames(40, *photo)}
    groups = {"dt-apriltags photographs": [g for g, i in zip(grey, images, strict=True) if i.camera],
              "NASA JPEGs": [g for g, i in zip(grey, images, strict=True) if i.camera is None],
              "simulator (config/sim.yaml), 0.8-1.35 m": simulator_frames(12),
              **{f"{name}, 0.5-1.3 m": rendered_frames(20, *settings, wall_m=0.9)
                 for name, settings in (("rendered, noise 2, no lens blur", (2.0, 0.0)),
                                        (f"rendered, noise {photo[0]:g}, blur {photo[1]:g}", photo))}}
    print("image statistics, median: pixel noise (grey levels), edge blur (px)")
    for name, group in groups.items():
        noise, blur = image_statistics(group, reference)
        print(f"  {name:44s} noise {noise:.2f}, blur " + ("-" if math.isnan(blur) else f"{blur:.2f} px"))
    for label, frames_r in rendered.items():
        rend_speed = {name: cpu_per_frame(det.detect, frames_r, 1) for name, det in dets.items()}
        print(f"  {label}, 1.2-2.2 m: " + ", ".join(f"{n} {1e3 * s:.1f} ms" for n, s in rend_speed.items()))
    sweep = []
    for noise in RENDER_NOISE_SWEEP:
        rng = np.random.default_rng(1)
        scene = [bench_tag_detectors._frame(bench_tag_detectors.Condition("base", noise_std=noise), rng)[0]
                 for _ in range(10)]
        sweep.append(f"noise {noise:g}: {1e3 * cpu_per_frame(dets['shipped'].detect, scene, 1):.1f} ms")
    print("  the shipped detector on bench_tag_detectors' base scene (CameraRenderer, 2 m): "
          + ", ".join(sweep))

    # tag_detect's pose on the rotation series
    poses = rotation_poses()
    T0, L0 = next((T, L) for a, T, _, L in poses if a == 0)
    print("rotation series (tag_detect --camera camera_rotation.yaml --tag-size 0.065): stated "
          "angle: turn about the tag's vertical from the 0 deg image, the rest of that rotation, "
          "distance, tag centre x y z in the camera frame, reprojection RMS")
    errors, dists, lib_dt, lib_da = [], [], [], []
    for angle, T, rms, L in poses:
        turn, rest = turn_about_vertical(T0, T)
        errors.append(turn - angle)
        dists.append(float(np.linalg.norm(T[:3, 3])))
        lib_dt.append(float(np.linalg.norm(T[:3, 3] - L[:3, 3])))
        lib_da.append(abs(rotation_angle_deg(T0, T) - rotation_angle_deg(L0, L)))
        print(f"  {angle:+4d} deg: {turn:+6.1f} deg, rest {rest:3.1f} deg, {dists[-1]:.4f} m, "
              + " ".join(f"{v:+.4f}" for v in T[:3, 3]) + f" m, {rms:.2f} px")
    errors = np.array(errors)
    print(f"  turn - stated: mean {errors.mean():+.1f} deg, RMS {np.sqrt(np.mean(errors ** 2)):.1f} deg, "
          f"max |.| {np.abs(errors).max():.1f} deg; distance {min(dists):.3f}-{max(dists):.3f} m "
          f"(stated position 0.30 m ahead, 0.05 m up, in a robot frame)")
    print(f"  against the library's own pose solver: position within {1e3 * max(lib_dt):.2f} mm, "
          f"turn from the 0 deg image within {max(lib_da):.2f} deg")

    if args.doc:
        from perf_doc import write_row

        ship, ref_s = speed["shipped"], speed["library defaults (decimate 1)"]
        m = totals["shipped"]
        write_row("AprilTag detector on real photographs, 640x480 (CPU per frame)",
                  f"{1e3 * ship:.1f} ms ({1.0 / ship:.0f} frames/s), {m.matched}/{m.reference} "
                  f"of the library's tags matched, {m.extra} extra",
                  f"bare library (decimate 1): {1e3 * ref_s:.1f} ms; JPEG decode {1e3 * decode:.2f} ms")
    return 0


if __name__ == "__main__":
    sys.exit(main())
