"""A camera mount's offset fitted with the pods or the driven wheels (tools/mount_calibration.py
through tools/pod_calibration.py) on synthetic drives (docs/models.md, "Camera mount")."""

from __future__ import annotations

import dataclasses

import numpy as np
from test_driven_calibration import MEC_TRUE
from test_driven_calibration import problem as driven_problem
from test_pod_calibration import NOMINAL, problem, synthetic, twist

from ekf_localization.models.sensors.dead_wheels import PodGeometry
from ekf_localization.tools import mount_calibration as mc
from ekf_localization.tools import pod_calibration as pc

PODS = PodGeometry((0.19, -0.15, 0.12), (0.02, -0.02, 1.55), (1.03, 0.97, 1.02))  # parallel mean 0


def mounted_fixes(data, delta):
    """The synthetic drive's fixes as a camera whose mount is off by Δ gives them: F = B ∘ Δ."""
    fixes, enc = data
    pose = pc.at_mount(fixes.pose, np.asarray(delta, float))
    pose[:, 2] = np.remainder(pose[:, 2] + np.pi, 2 * np.pi) - np.pi
    return dataclasses.replace(fixes, pose=pose), enc


def test_the_jacobian_with_a_mount_and_a_gauge_is_the_finite_difference() -> None:
    p = problem(mounted_fixes(synthetic(20.0, PODS, fix_sd=0.01, seed=2), (0.0, 0.0, 0.035)))
    start = mc.Mounted(NOMINAL, (0.01, -0.02, 0.01), mc.pod_gauge(NOMINAL))
    free = np.ones(12, bool)
    f = pc._Fit(p, start, free)
    x = np.r_[pc.initial_poses(p, start).ravel(), start.vector]
    x += 1e-3 * np.random.default_rng(1).standard_normal(len(x))
    J = f.jacobian(x).toarray()
    for i in [*range(6), *range(3 * p.n - 3, 3 * p.n + 12)]:
        step = np.zeros_like(x)
        step[i] = 1e-7
        fd = (f.residuals(x + step) - f.residuals(x - step)) / 2e-7
        np.testing.assert_allclose(J[:, i], fd, atol=1e-5 * max(1.0, np.abs(fd).max()))


def test_a_mount_yaw_is_recovered_with_the_pods_and_the_gauge_held() -> None:
    """A 2° mount yaw with every pod angle free: the parallel pods' mean angle stays at the file's
    (0), and Δθ and every pod come out exactly from noise-free data."""
    p = problem(mounted_fixes(synthetic(30.0, PODS), (0.0, 0.0, np.radians(2.0))))
    start = mc.Mounted(NOMINAL, gauge=mc.pod_gauge(NOMINAL))
    free = np.r_[np.ones(9, bool), False, False, True]  # the mount's x, y: held (a base_link shift)
    r = pc.fit(p, start, free)
    np.testing.assert_allclose(r.pods.vector, np.r_[PODS.vector, 0.0, 0.0, np.radians(2.0)], atol=1e-7)
    ok, std = pc.observable(p, start, free, mc.limits(pc.limits(3)))
    assert ok[free].all() and std[11] < mc.MOUNT_MAX_STD[2]


def test_without_the_gauge_a_common_pod_rotation_trades_with_the_mount_yaw() -> None:
    p = problem(mounted_fixes(synthetic(30.0, PODS, fix_sd=0.005, seed=4), (0.0, 0.0, 0.03)))
    free = np.r_[np.ones(9, bool), False, False, True]
    ok, std = pc.observable(p, mc.Mounted(NOMINAL), free, mc.limits(pc.limits(3)))
    assert not ok[free].all()  # one of the angles or the yaw is held: the drive cannot tell them apart


def test_the_wheels_give_the_whole_mount_and_turning_alone_its_translation() -> None:
    delta = (0.03, -0.02, np.radians(2.0))
    data = mounted_fixes(synthetic(30.0, MEC_TRUE, drive=twist), delta)
    start = mc.Mounted(MEC_TRUE)
    free = np.r_[False, False, True, True, True]
    r = pc.fit(driven_problem(data), start, free)
    np.testing.assert_allclose(r.pods.mount, delta, atol=1e-7)
    turning = mounted_fixes(synthetic(30.0, MEC_TRUE, drive=_turning), delta)
    ok, _ = pc.observable(driven_problem(turning), start, free, mc.limits(MEC_TRUE.limits()))
    assert ok[2] and ok[3] and not ok[4]  # a turn in place: the circle gives x, y but not the yaw


def test_the_corrected_mount_composes_the_offset_with_the_believed_one() -> None:
    believed = np.array([0.1, 0.05, 0.2])
    true = np.array([0.12, 0.03, 0.25])
    delta = pc.at_mount(true[None, :], mc.inverse(believed))[0]  # Δ = M ∘ M₀⁻¹
    np.testing.assert_allclose(mc.corrected_mount(delta, believed), true, atol=1e-12)


def _turning(t: np.ndarray, pushes: bool = True) -> np.ndarray:
    return twist(t, False)
