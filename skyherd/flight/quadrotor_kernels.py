"""The quadrotor's physics as numba kernels (flight/quadrotor.py has the model, its parameters
and the readable `Quadrotor` around these): flat float64 arrays, nothing allocated per step.
Kept apart from quadrotor.py so that a process that flies the kernels compiled ahead of time
(flight.multirotor.compiled: `skyherd sim`) never imports numba."""

from __future__ import annotations

import math

from numba import njit

from skyherd.flight.quadrotor import (
    A_ENERGY,
    A_ON_GROUND,
    A_SHAFT_POWER,
    A_SPECIFIC,
    A_THRUST,
    A_WIND,
    P_CLIN,
    P_CQUAD,
    P_G,
    P_IXX,
    P_IYY,
    P_IZZ,
    P_KF,
    P_KM,
    P_MASS,
    P_RX,
    P_RY,
    P_SPIN,
    P_TAU,
    P_WMAX,
    X_MOTOR,
    X_OMEGA,
    X_POS,
    X_QUAT,
    X_VEL,
)


@njit(cache=True, fastmath=False)
def _level_with_yaw(x):
    """Replace the attitude in x by the level one with the same heading."""
    qw, qx, qy, qz = x[X_QUAT], x[X_QUAT + 1], x[X_QUAT + 2], x[X_QUAT + 3]
    yaw = math.atan2(2.0 * (qw * qz + qx * qy), 1.0 - 2.0 * (qy * qy + qz * qz))
    x[X_QUAT] = math.cos(0.5 * yaw)
    x[X_QUAT + 1] = 0.0
    x[X_QUAT + 2] = 0.0
    x[X_QUAT + 3] = math.sin(0.5 * yaw)


@njit(cache=True, fastmath=False)
def physics_substep(x, aux, p, u, dt):
    """Advance the state x (17,) by dt [s] under motor commands u (4,) in [0, 1] (NaN → 0).

    Writes aux (8,): specific force (body), on_ground flag, thrust, shaft power, energy.
    """
    m = p[P_MASS]
    g = p[P_G]
    kf = p[P_KF]
    km = p[P_KM]
    wmax = p[P_WMAX]
    alpha = 1.0 - math.exp(-dt / p[P_TAU])
    # -- motors and rotor forces
    thrust = 0.0
    mx = 0.0
    my = 0.0
    mz = 0.0
    power = 0.0
    for i in range(4):
        c = u[i]
        if not (c > 0.0):  # also catches NaN
            c = 0.0
        elif c > 1.0:
            c = 1.0
        w = x[X_MOTOR + i]
        w += (c * wmax - w) * alpha
        x[X_MOTOR + i] = w
        ti = kf * w * w
        qi = km * w * w
        thrust += ti
        mx -= p[P_RY + i] * ti
        my += p[P_RX + i] * ti
        mz += p[P_SPIN + i] * qi
        power += qi * w
    aux[A_THRUST] = thrust
    aux[A_SHAFT_POWER] = power
    aux[A_ENERGY] += power * dt
    # -- rotation matrix body → world
    qw, qx, qy, qz = x[X_QUAT], x[X_QUAT + 1], x[X_QUAT + 2], x[X_QUAT + 3]
    r00 = 1.0 - 2.0 * (qy * qy + qz * qz)
    r01 = 2.0 * (qx * qy - qw * qz)
    r02 = 2.0 * (qx * qz + qw * qy)
    r10 = 2.0 * (qx * qy + qw * qz)
    r11 = 1.0 - 2.0 * (qx * qx + qz * qz)
    r12 = 2.0 * (qy * qz - qw * qx)
    r20 = 2.0 * (qx * qz - qw * qy)
    r21 = 2.0 * (qy * qz + qw * qx)
    r22 = 1.0 - 2.0 * (qx * qx + qy * qy)
    vx, vy, vz = x[X_VEL], x[X_VEL + 1], x[X_VEL + 2]
    # body-frame air-relative velocity and drag
    avx, avy, avz = vx - aux[A_WIND], vy - aux[A_WIND + 1], vz - aux[A_WIND + 2]
    vbx = r00 * avx + r10 * avy + r20 * avz
    vby = r01 * avx + r11 * avy + r21 * avz
    vbz = r02 * avx + r12 * avy + r22 * avz
    fbx = -p[P_CLIN] * vbx - p[P_CQUAD] * abs(vbx) * vbx
    fby = -p[P_CLIN + 1] * vby - p[P_CQUAD + 1] * abs(vby) * vby
    fbz = -p[P_CLIN + 2] * vbz - p[P_CQUAD + 2] * abs(vbz) * vbz - thrust
    ax = (r00 * fbx + r01 * fby + r02 * fbz) / m
    ay = (r10 * fbx + r11 * fby + r12 * fbz) / m
    az = (r20 * fbx + r21 * fby + r22 * fbz) / m + g
    # -- resting on the ground: held until the thrust lifts it
    if aux[A_ON_GROUND] > 0.5:
        if az < 0.0:
            aux[A_ON_GROUND] = 0.0
        else:
            for k in range(3):
                x[X_VEL + k] = 0.0
                x[X_OMEGA + k] = 0.0
            x[X_POS + 2] = 0.0
            aux[A_SPECIFIC] = 0.0
            aux[A_SPECIFIC + 1] = 0.0
            aux[A_SPECIFIC + 2] = -g
            return
    aux[A_SPECIFIC] = fbx / m
    aux[A_SPECIFIC + 1] = fby / m
    aux[A_SPECIFIC + 2] = fbz / m
    # -- translation: exact for constant acceleration over dt
    x[X_POS] += (vx + 0.5 * ax * dt) * dt
    x[X_POS + 1] += (vy + 0.5 * ay * dt) * dt
    x[X_POS + 2] += (vz + 0.5 * az * dt) * dt
    x[X_VEL] = vx + ax * dt
    x[X_VEL + 1] = vy + ay * dt
    x[X_VEL + 2] = vz + az * dt
    # -- rotation: I ω̇ = M − ω × Iω
    ixx, iyy, izz = p[P_IXX], p[P_IYY], p[P_IZZ]
    wx, wy, wz = x[X_OMEGA], x[X_OMEGA + 1], x[X_OMEGA + 2]
    dwx = (mx - (wy * izz * wz - wz * iyy * wy)) / ixx
    dwy = (my - (wz * ixx * wx - wx * izz * wz)) / iyy
    dwz = (mz - (wx * iyy * wy - wy * ixx * wx)) / izz
    nwx, nwy, nwz = wx + dwx * dt, wy + dwy * dt, wz + dwz * dt
    x[X_OMEGA], x[X_OMEGA + 1], x[X_OMEGA + 2] = nwx, nwy, nwz
    # q ← q ⊗ exp(½ ω_mid dt)
    hx = 0.5 * (wx + nwx) * dt
    hy = 0.5 * (wy + nwy) * dt
    hz = 0.5 * (wz + nwz) * dt
    ang = math.sqrt(hx * hx + hy * hy + hz * hz)  # = |ω| dt
    if ang > 1e-12:
        s = math.sin(0.5 * ang) / ang
        dw, dx, dy, dz = math.cos(0.5 * ang), hx * s, hy * s, hz * s
        nqw = qw * dw - qx * dx - qy * dy - qz * dz
        nqx = qw * dx + qx * dw + qy * dz - qz * dy
        nqy = qw * dy - qx * dz + qy * dw + qz * dx
        nqz = qw * dz + qx * dy - qy * dx + qz * dw
        n = 1.0 / math.sqrt(nqw * nqw + nqx * nqx + nqy * nqy + nqz * nqz)
        x[X_QUAT], x[X_QUAT + 1], x[X_QUAT + 2], x[X_QUAT + 3] = (
            nqw * n,
            nqx * n,
            nqy * n,
            nqz * n,
        )
    # -- touchdown: never below ground, never bounce
    if x[X_POS + 2] >= 0.0:
        x[X_POS + 2] = 0.0
        if x[X_VEL + 2] > 0.0:
            x[X_VEL + 2] = 0.0
        if az >= 0.0:  # thrust does not hold the weight: it rests
            aux[A_ON_GROUND] = 1.0
            for k in range(3):
                x[X_VEL + k] = 0.0
                x[X_OMEGA + k] = 0.0
            _level_with_yaw(x)
            aux[A_SPECIFIC] = 0.0
            aux[A_SPECIFIC + 1] = 0.0
            aux[A_SPECIFIC + 2] = -g


@njit(cache=True, fastmath=False)
def physics_steps(x, aux, p, u, dt, n):
    """n physics steps of dt [s] under constant motor commands u (4,)."""
    for _ in range(n):
        physics_substep(x, aux, p, u, dt)
