"""One message in one compiled call: checks, snapshot, prediction and updates.

The Localizer's common case is a message of a *lane* input (its record type, already in
the filter's frames, no tilt or process input) that lands at the end of the timeline with
no command acting: its parts' checks (:func:`~ekf_localization.core.measurements.fuse_into`),
the snapshot a later rewind restores, one prediction step and one linear update per part
are then one call of the model's ``message_kernel``, instead of a call per stage (each
numba call costs about 0.15 µs per array argument to dispatch, more than a 6×6 update).

A model provides that kernel by composing the helpers below with its predict kernel's
no-command step (``models.mecanum._make_message_kernel``)::

    message_step(X, P, buf, dt, Q, ints, floats, work, nis, v0, c0, v1, c1, fuse) -> code

- ``buf`` is the entry's own float64 array (``StepLayout.size``, filled by the kernel): the prior
  state and covariance (the snapshot), then each part's z and R. With ``fuse`` false (a
  replay after a rewind) the z and R already there are applied again and v0..c1 are not read.
- ``ints`` and ``floats`` are the input's constants packed by :class:`StepLayout`.
- ``nis`` (rows, 2): the running (sum, count) of squared distances; each part adds to its row.
- ``v0, c0, v1, c1`` are the parts' value and covariance arrays as the record holds them
  (one part: the same pair twice). Separate arrays, not tuples: numba dispatches a tuple
  argument about 1 µs slower.
- ``code`` is -1 when a part fails its checks (nothing changed: the general path then
  says why); otherwise bit 0 says the prediction was finite and bits 3j+1.. hold part j's
  status (kernels.STATUS_*), so 1 means "predicted, every part applied".

The arithmetic is that of the separate kernels (the same inlined functions), so a message
gives bit-for-bit the state it gives through them.
"""

from __future__ import annotations

import math

import numpy as np

from ekf_localization.core.kernels import njit, update_one
from ekf_localization.core.measurements import fuse_into

MAX_PART = 6  # components of one part (a pose or a twist)
MAX_LANES = 2  # parts per message (an odometry's pose and twist, an IMU's orientation and rate)
# per part in ``ints``: k, first field, flags-not-provided, z offset, R offset, H offset (in floats),
# NIS row; then idx (MAX_PART), z_is_angle (MAX_PART)
LANE_INTS = 7 + 2 * MAX_PART
STATUS_BITS = 3  # kernels.STATUS_* < 8


@njit(cache=True, inline="always")
def fuse_lanes(buf, ints, floats, v0, c0, v1, c1, n: int) -> bool:
    """Every part's z and R·scale into ``buf`` (fuse_into); False as soon as one fails."""
    lanes = ints[n]
    bounds = floats[1:16]
    for j in range(lanes):
        base = n + 3 + j * LANE_INTS
        k = ints[base]
        values = v0 if j == 0 else v1
        cov = c0 if j == 0 else c1
        if ints[base + 2] != 0 and cov[0, 0] == -1.0:  # sensor_msgs' "not provided" flag
            return False
        z = buf[ints[base + 3]:ints[base + 3] + k]
        R = buf[ints[base + 4]:ints[base + 4] + k * k].reshape((k, k))
        if fuse_into(values, cov, ints[base + 7:base + 7 + k], bounds, ints[base + 1],
                     floats[16 + 2 * j + 1], z, R) != 0:
            return False
    return True


@njit(cache=True, inline="always")
def snapshot_into(x, P, buf, n: int) -> None:
    """The state before this message (what a rewind to it restores) into ``buf[: n + n²]``."""
    for i in range(n):
        buf[i] = x[i]
        for j in range(n):
            buf[n + i * n + j] = P[i, j]


@njit(cache=True, inline="always", error_model="numpy")
def update_lanes(x, P, buf, ints, floats, work, nis, n: int, predicted: bool) -> int:
    """Every part's linear update (its model selects state rows), in order, each squared
    distance added to its row of ``nis`` (sum, count); the code."""
    lanes = ints[n]
    x_is_angle = ints[:n]
    mask = ints[n + 2:n + 2 + MAX_PART]  # ones
    code = 1 if predicted else 0
    for j in range(lanes):
        base = n + 3 + j * LANE_INTS
        k = ints[base]
        z = buf[ints[base + 3]:ints[base + 3] + k]
        R = buf[ints[base + 4]:ints[base + 4] + k * k].reshape((k, k))
        H = floats[ints[base + 5]:ints[base + 5] + k * n].reshape((k, n))
        z_is_angle = ints[base + 7 + MAX_PART:base + 7 + MAX_PART + k]
        status, d2 = update_one(x, P, z, z, True, H, R, mask, floats[16 + 2 * j], z_is_angle, x_is_angle,
                                floats[0], work, n, k)
        if d2 < math.inf:  # nan: the update stopped before the distance
            row = ints[base + 6]
            nis[row, 0] += d2
            nis[row, 1] += 1.0
        code |= status << (1 + STATUS_BITS * j)
    return code


class StepLayout:
    """The packed constants of one input's message kernel and its entries' buffer layout.

    ``parts``: per fused part, (k, first field, flags-not-provided, local indices, state rows,
    z_is_angle, gate², variance scale, NIS row), in the order the kernel applies them.
    ``ints``: x_is_angle (n), the number of parts, 0, MAX_PART ones (the update mask), then
    LANE_INTS per part; ``floats``: min_variance, the 15 plausible bounds, (gate², scale) per
    part, then each part's H (k × n, ones at its state rows). ``buf``: the prior x and P, then
    each part's z and R.
    """

    def __init__(self, n: int, x_is_angle: np.ndarray, min_variance: float, bounds: np.ndarray,
                 parts: list[tuple]) -> None:
        if not 1 <= len(parts) <= MAX_LANES:
            raise ValueError(f"{len(parts)} parts: the message kernel takes 1..{MAX_LANES}")
        ints = np.zeros(n + 3 + LANE_INTS * len(parts), dtype=np.int64)
        ints[:n] = np.asarray(x_is_angle, dtype=bool)
        ints[n] = len(parts)
        ints[n + 2:n + 2 + MAX_PART] = 1
        h_offset = 16 + 2 * len(parts)
        floats = np.zeros(h_offset + sum(p[0] for p in parts) * n)
        floats[0] = min_variance
        floats[1:16] = bounds
        offset = n + n * n
        self.views: list[tuple[int, int, int]] = []  # per part: (k, z offset, R offset)
        for j, (k, first, flags, local, rows, z_is_angle, gate_sq, scale, nis_row) in enumerate(parts):
            if not 1 <= k <= MAX_PART:
                raise ValueError(f"a part of {k} components: the message kernel takes 1..{MAX_PART}")
            base = n + 3 + j * LANE_INTS
            ints[base:base + 7] = (k, first, int(flags), offset, offset + k, h_offset, nis_row)
            ints[base + 7:base + 7 + k] = local
            ints[base + 7 + MAX_PART:base + 7 + MAX_PART + k] = z_is_angle
            floats[16 + 2 * j:18 + 2 * j] = (gate_sq, scale)
            H = floats[h_offset:h_offset + k * n].reshape(k, n)
            H[np.arange(k), np.asarray(rows)] = 1.0
            h_offset += k * n
            self.views.append((k, offset, offset + k))
            offset += k + k * k
        self.n = n
        self.ints = ints
        self.floats = floats
        self.size = offset

    def prior(self, buf: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Views of the snapshot in ``buf``: (x (n,), P (n, n))."""
        n = self.n
        return buf[:n], buf[n:n + n * n].reshape(n, n)

    def fused(self, buf: np.ndarray, j: int) -> tuple[np.ndarray, np.ndarray]:
        """Views of part j's z (k,) and R (k, k) in ``buf``."""
        k, zo, ro = self.views[j]
        return buf[zo:zo + k], buf[ro:ro + k * k].reshape(k, k)


def work_shape(n: int) -> tuple[int, int]:
    """The scratch of a message kernel: the predict kernels' and the update kernels' (m ≤ MAX_PART)."""
    return max(4 * n + 1, 4 + 5 * MAX_PART + 3 * n), max(n, MAX_PART)
