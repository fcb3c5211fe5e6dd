"""How a swerve drive's body velocity follows its commanded twist: modules that steer at a limited
rate (docs/models.md, "Swerve response"; no ROS imports).

The state holds the body twist v, not the modules' angles: module i (at pᵢ = (xᵢ, yᵢ)) is taken to
point along its velocity vector u⁰ᵢ = Aᵢ v (models/swerve.py), at angle φ⁰ᵢ with speed s⁰ᵢ = |u⁰ᵢ|.
Over a step T toward the command c, with the target vector tᵢ = Aᵢ c:

1. the target angle is the one of (|tᵢ|, ∠tᵢ) and (−|tᵢ|, ∠tᵢ + π) nearer φ⁰ᵢ: the error eᵢ lies
   in [−π/2, π/2] and the target speed is s*ᵢ = ±|tᵢ|;
2. the module turns by δᵢ = clip(eᵢ, ±ρT) (ρ: ``steer_rate_limit``), leaving rᵢ = eᵢ − δᵢ;
3. its speed follows the drive response (:func:`~ekf_localization.models.drive_response.axis_response`
   with the vx axis's τ and limits) toward s*ᵢ cos rᵢ: a module still turning pushes only with
   the target's component along its wheel;
4. uᵢ(T) = sᵢ(T)·(cos, sin)(φ⁰ᵢ + δᵢ) and the body twist is their least-squares fit,
   v(T) = A⁺ u(T); the displacement is A⁺ Σ (∫sᵢ dt)·(cos, sin)(φ⁰ᵢ + δᵢ/2).

A standing module (s⁰ᵢ ≈ 0) is taken as pointing at its target. The Jacobian is carried through
these steps per module (a 2×2 block ∂uᵢ/∂u⁰ᵢ); the speed's derivative by its command is
1 − ∂s(T)/∂s⁰ (∫: T − ∂∫/∂s⁰), exact when the acceleration and deceleration limits are equal
(the response is then unchanged by shifting speed and command together).
"""

from __future__ import annotations

import math

import numpy as np

from ekf_localization.models.axis_response import axis_response

STILL = 1e-6  # m/s: a module slower than this is standing (its angle is not that of its vector)
SWERVE_PARAMS = 15  # index in DriveResponse.params where the swerve mode's entries start


def swerve_params(steer_rate_limit: float, positions: np.ndarray) -> list[float]:
    """The swerve mode's entries of the flat parameter vector: ρ, n, positions (n, 2), A⁺ (3, 2n)."""
    p = np.asarray(positions, dtype=float).reshape(-1, 2)
    A = np.zeros((2 * len(p), 3))
    A[0::2, 0] = 1.0
    A[1::2, 1] = 1.0
    A[0::2, 2] = -p[:, 1]
    A[1::2, 2] = p[:, 0]
    return [float(steer_rate_limit), float(len(p)), *p.ravel().tolist(), *np.linalg.pinv(A).ravel().tolist()]


def swerve_modules(v, c, T: float, dp: tuple[float, ...], r: list[list[float]]) -> None:
    """Swerve mode: r (3 rows of 8 floats) [v(T), ∫v dt, ∂v(T)/∂v0 (3), ∂∫/∂v0 (3)] (module docstring)."""
    tau = dp[0]
    acc = dp[3]
    dec = dp[6]
    base = SWERVE_PARAMS
    turn_max = dp[base] * T
    n = int(dp[base + 1])
    pos = dp[base + 2:base + 2 + 2 * n]
    fit = dp[base + 2 + 2 * n:base + 2 + 8 * n]  # (3, 2n) row-major
    rows = []
    tmp = [0.0] * 4
    v0, v1, v2 = v[0], v[1], v[2]
    for i in range(n):
        px = pos[2 * i]
        py = pos[2 * i + 1]
        ux = v0 - v2 * py
        uy = v1 + v2 * px
        tx = c[0] - c[2] * py
        ty = c[1] + c[2] * px
        s0 = math.hypot(ux, uy)
        m = math.hypot(tx, ty)
        clipped = False
        turn = 0.0
        dcs = 0.0  # ∂(speed command)/∂φ0
        if s0 > STILL:
            ca = ux / s0
            sa = uy / s0
            st = m
            if m > 0.0:
                e = math.atan2(ca * ty - sa * tx, ca * tx + sa * ty)
                if e > 0.5 * math.pi:
                    e -= math.pi
                    st = -m
                elif e < -0.5 * math.pi:
                    e += math.pi
                    st = -m
                if e > turn_max:
                    turn = turn_max
                    clipped = True
                elif e < -turn_max:
                    turn = -turn_max
                    clipped = True
                else:
                    turn = e
            rest = e - turn if m > 0.0 else 0.0
            cs = st * math.cos(rest)
            if clipped:
                dcs = st * math.sin(rest)
            inv = 1.0 / s0
        else:  # standing: pointing at its target (or along x with no target)
            if m > 0.0:
                ca = tx / m
                sa = ty / m
            else:
                ca = 1.0
                sa = 0.0
            s0 = ux * ca + uy * sa
            cs = m
            inv = 0.0
        axis_response(s0, cs, T, tau, acc, dec, tmp)
        sT, g, S, h = tmp
        ct = math.cos(turn)
        snt = math.sin(turn)
        dx = ca * ct - sa * snt  # the wheel's direction at T
        dy = sa * ct + ca * snt
        cm = math.cos(0.5 * turn)
        sm = math.sin(0.5 * turn)
        mx = ca * cm - sa * sm  # and at mid-step
        my = sa * cm + ca * sm
        # ∂s(T)/∂u0 and ∂∫s/∂u0: along d0 (speed) and n0/s0 (angle, through the speed command)
        gs = (1.0 - g) * dcs * inv
        hs = (T - h) * dcs * inv
        ds_x = g * ca - gs * sa
        ds_y = g * sa + gs * ca
        dS_x = h * ca - hs * sa
        dS_y = h * sa + hs * ca
        kT = sT * inv if clipped else 0.0  # s(T)·∂φ(T)/∂φ0 / s0
        kM = S * inv * (1.0 if clipped else 0.5)  # ∫s·∂φ(T/2)/∂φ0 / s0
        # 2x2 blocks ∂u(T)/∂u0 and ∂∫u/∂u0
        a00 = dx * ds_x - dy * kT * -sa
        a01 = dx * ds_y - dy * kT * ca
        a10 = dy * ds_x + dx * kT * -sa
        a11 = dy * ds_y + dx * kT * ca
        b00 = mx * dS_x - my * kM * -sa
        b01 = mx * dS_y - my * kM * ca
        b10 = my * dS_x + mx * kM * -sa
        b11 = my * dS_y + mx * kM * ca
        # per component: [u(T), ∫u, ∂u(T)/∂v (3), ∂∫u/∂v (3)], with ∂u0/∂v = Aᵢ = [[1, 0, −py], [0, 1, px]]
        rows.append((sT * dx, S * mx, a00, a01, a01 * px - a00 * py, b00, b01, b01 * px - b00 * py))
        rows.append((sT * dy, S * my, a10, a11, a11 * px - a10 * py, b10, b11, b11 * px - b10 * py))
    res = (np.array(fit).reshape(3, 2 * n) @ np.array(rows)).tolist()  # the fit A⁺ of every column
    r[0][:] = res[0]
    r[1][:] = res[1]
    r[2][:] = res[2]
