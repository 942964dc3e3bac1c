"""Cascaded multirotor control, compiled with numba, run together with the physics.

One call of `control_step` = one autopilot period (control_dt): the position and velocity
loops run once, then for each physics substep the attitude loop, the rate loop, the mixer and
the physics (flight/quadrotor.py) run in turn. Nothing is allocated per substep.

  position  v_sp = K_p (p_sp − p) + v_ff, limited to |v_xy| ≤ v_xy,max, −v_up ≤ v_z ≤ v_dn
  velocity  a_sp = K_v (v_sp − v) + ∫ K_i (v_sp − v) dt; the integral only while
            |v_sp − v| < MPC_VEL_I_ERR and never further into a limit
  thrust    f = m (a_sp − g e_z) + c₁ a + c₂ |a| a, a = v_sp − ŵ  [N, NED] (drag feed-forward
            at the air-relative setpoint); f_z ≤ −T_min; tilt |f_xy| ≤ |f_z| tan θ_max;
            |f| ≤ T_max (horizontal gives way first)
  wind ŵ    the autopilot's own estimate from the accelerometer (PX4 EKF2's multirotor drag
            fusion): the rotors thrust along −z_b only, so the body x/y specific force is the
            drag, f_b = −(c₁ v_b + c₂ |v_b| v_b)/m per axis → the air-relative body velocity v_b;
            with no vertical wind, (v − ŵ) rotated into the body gives v_b: a 2×2 solve for
            ŵ_n, ŵ_e, low-passed with WIND_TAU_S. Fed forward shrunk by WIND_FF_MIN_MPS
            (|ŵ| − WIND_FF_MIN_MPS along ŵ, 0 below it: light wind is the integrator's)
  attitude  z_b,sp = −f/|f|, heading ψ_sp → R_sp = [x_b y_b z_b]  (Mellinger & Kumar 2011,
            eq. 6–8); collective T = f · (−z_b) projected on the current body axis
  att. err  q_e = q⁻¹ ⊗ q_sp (shortest way), ω_sp = 2 K_att ⊙ vec(q_e) + ψ̇_ff e_z, clipped
  rate      α_sp = K_p,r (ω_sp − ω) + ∫ K_i,r (ω_sp − ω) dt − K_d,r ω̇;  τ = I α_sp + ω × I ω
  mixer     flight/multirotor/mixer.py (its kernel, `mix`, is here)
Integrators freeze (per axis) while the output they drive is saturated, and are reset while
the vehicle rests on the ground.
"""

from __future__ import annotations

import hashlib
import math
import os
from pathlib import Path

from numba import njit

from skyherd.flight import quadrotor as _quadrotor
from skyherd.flight import quadrotor_kernels as _quadrotor_kernels
from skyherd.flight.multirotor import layout as _layout
from skyherd.flight.multirotor import mixer as _mixer
from skyherd.flight.multirotor.layout import (
    C_DRAG_LIN,
    C_DRAG_QUAD,
    C_KATT,
    C_KI_XY,
    C_KI_Z,
    C_KP_XY,
    C_KP_Z,
    C_KRD,
    C_KRI,
    C_KRP,
    C_KV_XY,
    C_KV_Z,
    C_MASS,
    C_MIX,
    C_RATE_MAX,
    C_RINT_MAX,
    C_T_IDLE,
    C_T_MAX,
    C_T_MIN,
    C_T_ROTOR_MAX,
    C_TILT_MAX,
    C_VINT_ERR,
    C_VINT_MAX,
    C_WDRAG_LIN,
    C_WDRAG_QUAD,
    C_WIND_FF_MIN,
    C_WIND_TAU,
    CS_F,
    CS_PREV_OMEGA,
    CS_QSP,
    CS_RATE_SP,
    CS_RINT,
    CS_SAT,
    CS_T,
    CS_TAU,
    CS_U,
    CS_VINT,
    CS_WIND,
    CS_WORK,
    K_C,
    K_P,
    N_K,
    N_W,
    SP_ARMED,
    SP_PITCH,
    SP_POS,
    SP_ROLL,
    SP_THRUST,
    SP_VEL,
    SP_VXY_MAX,
    SP_VZ_DN,
    SP_VZ_UP,
    SP_XY_MODE,
    SP_YAW,
    SP_YAWRATE,
    SP_Z_MODE,
    W_AUX,
    W_CS,
    W_SP,
    W_U,
    W_X,
    XY_ATT,
    XY_POS,
    Z_POS,
    Z_THRUST,
)
from skyherd.flight.multirotor.mixer import SAT_RP, SAT_THRUST_DN, SAT_THRUST_UP, SAT_YAW
from skyherd.flight.quadrotor import (
    A_ON_GROUND,
    P_G,
    P_IXX,
    P_IYY,
    P_IZZ,
    X_OMEGA,
    X_POS,
    X_QUAT,
    X_VEL,
)
from skyherd.flight.quadrotor_kernels import physics_substep


def _drop_stale_cache() -> None:
    """numba's on-disk cache is keyed on this file only, but the kernels here compile in
    flight/quadrotor_kernels.py, with constants of quadrotor.py, layout.py and mixer.py, too:
    drop this module's cache when any of them changed."""
    deps = [Path(__file__), Path(_quadrotor_kernels.__file__), Path(_quadrotor.__file__),
            Path(_layout.__file__), Path(_mixer.__file__)]  # fmt: skip
    stamp = hashlib.sha256(b"".join(p.read_bytes() for p in deps)).hexdigest()
    dirs = [Path(__file__).parent / "__pycache__"]
    if os.environ.get("NUMBA_CACHE_DIR"):
        dirs.append(Path(os.environ["NUMBA_CACHE_DIR"]))
    for d in dirs:
        mark = d / "control.deps-stamp"
        try:
            if mark.exists() and mark.read_text() == stamp:
                continue
            for f in d.rglob("control.*.nb[ic]"):
                f.unlink(missing_ok=True)
            d.mkdir(parents=True, exist_ok=True)
            mark.write_text(stamp)
        except OSError:
            pass  # read-only tree: numba falls back to its own cache location


_drop_stale_cache()


# ---- mixer (mixer.py: the allocation and its saturation priority)
@njit(cache=True, fastmath=False)
def mix(b, t_lo, t_hi, thrust, tx, ty, tz, u, work):
    """Write motor commands u (4,) in [0, 1]; return saturation flags (sum of SAT_*).

    b (16,) row-major allocation inverse; t_lo, t_hi per-rotor thrust bounds [N];
    work (12,) scratch space (no allocation on the hot path).
    """
    rp = work[0:4]
    yw = work[4:8]
    s = work[8:12]
    flags = 0.0
    rmax = -1e30
    rmin = 1e30
    for i in range(4):
        rp[i] = b[4 * i + 1] * tx + b[4 * i + 2] * ty
        yw[i] = b[4 * i + 3] * tz
        rmax = max(rmax, rp[i])
        rmin = min(rmin, rp[i])
    avail = t_hi - t_lo
    k = 1.0
    if rmax - rmin > avail:
        k = avail / (rmax - rmin)
        flags += SAT_RP
    hi = -1e30
    lo = 1e30
    for i in range(4):
        s[i] = b[4 * i] * thrust + k * rp[i]
        hi = max(hi, s[i])
        lo = min(lo, s[i])
    shift = 0.0
    if hi > t_hi:
        shift = t_hi - hi
        flags += SAT_THRUST_UP
    elif lo < t_lo:
        shift = t_lo - lo
        flags += SAT_THRUST_DN
    ky = 1.0
    for i in range(4):
        s[i] += shift
        if yw[i] > 1e-12:
            ky = min(ky, (t_hi - s[i]) / yw[i])
        elif yw[i] < -1e-12:
            ky = min(ky, (t_lo - s[i]) / yw[i])
    if ky < 1.0:
        ky = max(ky, 0.0)
        flags += SAT_YAW
    for i in range(4):
        ti = s[i] + ky * yw[i]
        ti = min(max(ti, t_lo), t_hi)
        u[i] = math.sqrt(ti / t_hi) if t_hi > 0.0 else 0.0
    return flags


@njit(cache=True, fastmath=False)
def _clip(v, lo, hi):
    return lo if v < lo else (hi if v > hi else v)


@njit(cache=True, fastmath=False)
def _quat_from_dcm(r00, r01, r02, r10, r11, r12, r20, r21, r22, q):
    tr = r00 + r11 + r22
    if tr > 0.0:
        s = math.sqrt(tr + 1.0) * 2.0
        q[0], q[1], q[2], q[3] = 0.25 * s, (r21 - r12) / s, (r02 - r20) / s, (r10 - r01) / s
    elif r00 > r11 and r00 > r22:
        s = math.sqrt(1.0 + r00 - r11 - r22) * 2.0
        q[0], q[1], q[2], q[3] = (r21 - r12) / s, 0.25 * s, (r01 + r10) / s, (r02 + r20) / s
    elif r11 > r22:
        s = math.sqrt(1.0 + r11 - r00 - r22) * 2.0
        q[0], q[1], q[2], q[3] = (r02 - r20) / s, (r01 + r10) / s, 0.25 * s, (r12 + r21) / s
    else:
        s = math.sqrt(1.0 + r22 - r00 - r11) * 2.0
        q[0], q[1], q[2], q[3] = (r10 - r01) / s, (r02 + r20) / s, (r12 + r21) / s, 0.25 * s


@njit(cache=True, fastmath=False)
def _attitude_from_thrust(fx, fy, fz, yaw, q):
    """q_sp (4,) with body z along −f and heading yaw."""
    n = math.sqrt(fx * fx + fy * fy + fz * fz)
    zx, zy, zz = -fx / n, -fy / n, -fz / n
    cx, cy = math.cos(yaw), math.sin(yaw)
    # y_b = z_b × x_c
    yx, yy, yz = zy * 0.0 - zz * cy, zz * cx - zx * 0.0, zx * cy - zy * cx
    ny = math.sqrt(yx * yx + yy * yy + yz * yz)
    yx, yy, yz = yx / ny, yy / ny, yz / ny
    # x_b = y_b × z_b
    xx, xy, xz = yy * zz - yz * zy, yz * zx - yx * zz, yx * zy - yy * zx
    _quat_from_dcm(xx, yx, zx, xy, yy, zy, xz, yz, zz, q)


@njit(cache=True, fastmath=False)
def _attitude_from_euler(roll, pitch, yaw, q):
    cr, sr = math.cos(0.5 * roll), math.sin(0.5 * roll)
    cp, sp = math.cos(0.5 * pitch), math.sin(0.5 * pitch)
    cy, sy = math.cos(0.5 * yaw), math.sin(0.5 * yaw)
    q[0] = cr * cp * cy + sr * sp * sy
    q[1] = sr * cp * cy - cr * sp * sy
    q[2] = cr * sp * cy + sr * cp * sy
    q[3] = cr * cp * sy - sr * sp * cy


@njit(cache=True, fastmath=False)
def _position_velocity(x, p, c, cs, sp, dt, on_ground):
    """Outer loops: write the thrust vector setpoint cs[CS_F:CS_F+3] [N, NED]."""
    m = c[C_MASS]
    g = p[P_G]
    # -- velocity setpoint
    vsx, vsy, vsz = sp[SP_VEL], sp[SP_VEL + 1], sp[SP_VEL + 2]
    if sp[SP_XY_MODE] == XY_POS:
        vsx += c[C_KP_XY] * (sp[SP_POS] - x[X_POS])
        vsy += c[C_KP_XY] * (sp[SP_POS + 1] - x[X_POS + 1])
    vxy = math.sqrt(vsx * vsx + vsy * vsy)
    if vxy > sp[SP_VXY_MAX]:
        k = sp[SP_VXY_MAX] / vxy
        vsx *= k
        vsy *= k
    if sp[SP_Z_MODE] == Z_POS:
        vsz += c[C_KP_Z] * (sp[SP_POS + 2] - x[X_POS + 2])
    vsz = _clip(vsz, -sp[SP_VZ_UP], sp[SP_VZ_DN])
    # -- velocity → acceleration → thrust vector (unsaturated)
    ex, ey, ez = vsx - x[X_VEL], vsy - x[X_VEL + 1], vsz - x[X_VEL + 2]
    fx = m * (c[C_KV_XY] * ex + cs[CS_VINT])
    fy = m * (c[C_KV_XY] * ey + cs[CS_VINT + 1])
    fz = m * (c[C_KV_Z] * ez + cs[CS_VINT + 2] - g)
    # drag feed-forward at the air-relative velocity setpoint: F = c₁ a + c₂ |a| a, a = v_sp − ŵ
    wx, wy = cs[CS_WIND], cs[CS_WIND + 1]
    wn = math.sqrt(wx * wx + wy * wy)
    if wn > c[C_WIND_FF_MIN]:
        k = 1.0 - c[C_WIND_FF_MIN] / wn
        rx, ry = vsx - k * wx, vsy - k * wy
    else:
        rx, ry = vsx, vsy  # bit for bit the calm-air feed-forward
    fx += c[C_DRAG_LIN] * rx + c[C_DRAG_QUAD] * abs(rx) * rx
    fy += c[C_DRAG_LIN] * ry + c[C_DRAG_QUAD] * abs(ry) * ry
    fz += c[C_DRAG_LIN + 1] * vsz + c[C_DRAG_QUAD + 1] * abs(vsz) * vsz
    if sp[SP_XY_MODE] == XY_ATT:
        fx = 0.0
        fy = 0.0
    # -- limits: vertical first, then tilt, then total
    fz_s = _clip(fz, -c[C_T_MAX], -c[C_T_MIN])
    fxy = math.sqrt(fx * fx + fy * fy)
    fxy_max = -fz_s * math.tan(c[C_TILT_MAX])
    room = math.sqrt(max(c[C_T_MAX] ** 2 - fz_s * fz_s, 0.0))
    fxy_max = min(fxy_max, room)
    kx = 1.0
    if fxy > fxy_max:
        kx = fxy_max / fxy
    fx_s, fy_s = fx * kx, fy * kx
    cs[CS_F], cs[CS_F + 1], cs[CS_F + 2] = fx_s, fy_s, fz_s
    # -- integrators: conditional (skip an axis pushing further into its limit)
    if on_ground:
        cs[CS_VINT] = 0.0
        cs[CS_VINT + 1] = 0.0
        cs[CS_VINT + 2] = 0.0
        return
    lim = c[C_VINT_MAX]
    emax = c[C_VINT_ERR]
    if math.sqrt(ex * ex + ey * ey) > emax:  # a transient, not a steady disturbance
        ex = 0.0
        ey = 0.0
    if abs(ez) > emax:
        ez = 0.0
    if sp[SP_XY_MODE] != XY_ATT:
        if not ((fx - fx_s) * ex > 0.0):
            cs[CS_VINT] = _clip(cs[CS_VINT] + c[C_KI_XY] * ex * dt, -lim, lim)
        if not ((fy - fy_s) * ey > 0.0):
            cs[CS_VINT + 1] = _clip(cs[CS_VINT + 1] + c[C_KI_XY] * ey * dt, -lim, lim)
    if not ((fz - fz_s) * ez > 0.0):
        cs[CS_VINT + 2] = _clip(cs[CS_VINT + 2] + c[C_KI_Z] * ez * dt, -lim, lim)


@njit(cache=True, fastmath=False)
def _drag_speed(f, lin, quad, m):
    """The air-relative body speed [m/s] whose drag gives specific force f [m/s^2] on one axis
    (signed: opposite to f)."""
    a = m * abs(f)
    if quad > 0.0:
        v = (math.sqrt(lin * lin + 4.0 * quad * a) - lin) / (2.0 * quad)
    elif lin > 0.0:
        v = a / lin
    else:
        return 0.0
    return -v if f > 0.0 else v


@njit(cache=True, fastmath=False)
def estimate_wind(x, aux, c, cs, dt):
    """Update the wind estimate cs[CS_WIND:CS_WIND+2] (module docstring) from the
    accelerometer aux[A_SPECIFIC] [m/s^2, FRD], the attitude and the velocity in x."""
    m = c[C_MASS]
    vbx = _drag_speed(aux[0], c[C_WDRAG_LIN], c[C_WDRAG_QUAD], m)
    vby = _drag_speed(aux[1], c[C_WDRAG_LIN + 1], c[C_WDRAG_QUAD + 1], m)
    qw, qx, qy, qz = x[X_QUAT], x[X_QUAT + 1], x[X_QUAT + 2], x[X_QUAT + 3]
    r00 = 1.0 - 2.0 * (qy * qy + qz * qz)
    r01 = 2.0 * (qx * qy - qw * qz)
    r10 = 2.0 * (qx * qy + qw * qz)
    r11 = 1.0 - 2.0 * (qx * qx + qz * qz)
    r20 = 2.0 * (qx * qz - qw * qy)
    r21 = 2.0 * (qy * qz + qw * qx)
    det = r00 * r11 - r10 * r01
    if abs(det) < 0.3:  # tilted beyond ~70°: body x/y no longer span the horizontal
        return
    vd = x[X_VEL + 2]  # no vertical wind: the air-relative down speed is the vehicle's
    bx, by = vbx - r20 * vd, vby - r21 * vd
    an = (r11 * bx - r10 * by) / det  # air-relative north, east: [r00 r10; r01 r11] a = b
    ae = (r00 * by - r01 * bx) / det
    k = min(dt / c[C_WIND_TAU], 1.0)
    cs[CS_WIND] += k * (x[X_VEL] - an - cs[CS_WIND])
    cs[CS_WIND + 1] += k * (x[X_VEL + 1] - ae - cs[CS_WIND + 1])


@njit(cache=True, fastmath=False)
def _inner(x, aux, p, c, cs, sp, u, dt):
    """Attitude loop, rate loop and mixer for one physics substep: writes u (4,)."""
    qw, qx, qy, qz = x[X_QUAT], x[X_QUAT + 1], x[X_QUAT + 2], x[X_QUAT + 3]
    r02 = 2.0 * (qx * qz + qw * qy)
    r12 = 2.0 * (qy * qz - qw * qx)
    r22 = 1.0 - 2.0 * (qx * qx + qy * qy)
    # -- collective
    if sp[SP_Z_MODE] == Z_THRUST:
        thrust = sp[SP_THRUST]
    elif sp[SP_XY_MODE] == XY_ATT:
        thrust = -cs[CS_F + 2] / max(r22, 0.5)
    else:
        thrust = -(cs[CS_F] * r02 + cs[CS_F + 1] * r12 + cs[CS_F + 2] * r22)
    thrust = _clip(thrust, 0.0, c[C_T_MAX])
    cs[CS_T] = thrust
    # -- attitude error q_e = q⁻¹ ⊗ q_sp
    sw, sx, sy, sz = cs[CS_QSP], cs[CS_QSP + 1], cs[CS_QSP + 2], cs[CS_QSP + 3]
    ew = qw * sw + qx * sx + qy * sy + qz * sz
    ex = qw * sx - qx * sw - qy * sz + qz * sy
    ey = qw * sy + qx * sz - qy * sw - qz * sx
    ez = qw * sz - qx * sy + qy * sx - qz * sw
    if ew < 0.0:
        ex, ey, ez = -ex, -ey, -ez
    rsp0 = _clip(2.0 * c[C_KATT] * ex, -c[C_RATE_MAX], c[C_RATE_MAX])
    rsp1 = _clip(2.0 * c[C_KATT + 1] * ey, -c[C_RATE_MAX + 1], c[C_RATE_MAX + 1])
    rsp2 = _clip(2.0 * c[C_KATT + 2] * ez + sp[SP_YAWRATE], -c[C_RATE_MAX + 2], c[C_RATE_MAX + 2])
    cs[CS_RATE_SP], cs[CS_RATE_SP + 1], cs[CS_RATE_SP + 2] = rsp0, rsp1, rsp2
    # -- rate PID (derivative on measurement) → angular acceleration → torque
    on_ground = aux[A_ON_GROUND] > 0.5
    ixx, iyy, izz = p[P_IXX], p[P_IYY], p[P_IZZ]
    inertia = (ixx, iyy, izz)
    rsp = (rsp0, rsp1, rsp2)
    sat = cs[CS_SAT]
    sat_rp = (sat % 2.0) >= 1.0
    sat_yaw = (sat % 4.0) >= 2.0
    tau = cs[CS_TAU : CS_TAU + 3]
    for k in range(3):
        w = x[X_OMEGA + k]
        err = rsp[k] - w
        dw = (w - cs[CS_PREV_OMEGA + k]) / dt
        cs[CS_PREV_OMEGA + k] = w
        if on_ground:
            cs[CS_RINT + k] = 0.0
        elif not ((k < 2 and sat_rp) or (k == 2 and sat_yaw)):
            cs[CS_RINT + k] = _clip(
                cs[CS_RINT + k] + c[C_KRI + k] * err * dt, -c[C_RINT_MAX], c[C_RINT_MAX]
            )
        acc = c[C_KRP + k] * err + cs[CS_RINT + k] - c[C_KRD + k] * dw
        tau[k] = inertia[k] * acc
    wx, wy, wz = x[X_OMEGA], x[X_OMEGA + 1], x[X_OMEGA + 2]
    tau[0] += wy * izz * wz - wz * iyy * wy
    tau[1] += wz * ixx * wx - wx * izz * wz
    tau[2] += wx * iyy * wy - wy * ixx * wx
    flags = mix(
        c[C_MIX : C_MIX + 16],
        c[C_T_IDLE],
        c[C_T_ROTOR_MAX],
        thrust,
        tau[0],
        tau[1],
        tau[2],
        u,
        cs[CS_WORK : CS_WORK + 12],
    )
    cs[CS_SAT] = flags
    for i in range(4):
        cs[CS_U + i] = u[i]


@njit(cache=True, fastmath=False)
def control_step(x, aux, p, c, cs, sp, u, dt, n):
    """One autopilot period: outer loops once, then n × (inner loops + physics) of dt [s]."""
    on_ground = aux[A_ON_GROUND] > 0.5
    if sp[SP_ARMED] < 0.5:
        for i in range(4):
            u[i] = 0.0
            cs[CS_U + i] = 0.0
        for k in range(6):
            cs[CS_VINT + k] = 0.0
        for _ in range(n):
            physics_substep(x, aux, p, u, dt)
        return
    if not on_ground:
        estimate_wind(x, aux, c, cs, dt * n)
    _position_velocity(x, p, c, cs, sp, dt * n, on_ground)
    q = cs[CS_QSP : CS_QSP + 4]
    if sp[SP_XY_MODE] == XY_ATT:
        _attitude_from_euler(sp[SP_ROLL], sp[SP_PITCH], sp[SP_YAW], q)
    else:
        _attitude_from_thrust(cs[CS_F], cs[CS_F + 1], cs[CS_F + 2], sp[SP_YAW], q)
    for _ in range(n):
        _inner(x, aux, p, c, cs, sp, u, dt)
        physics_substep(x, aux, p, u, dt)


@njit(cache=True, fastmath=False)
def control_step_packed(w, k, dt, n):
    """`control_step` over w = [x, aux, cs, sp, u] and k = [p, c] (views, no copies)."""
    control_step(
        w[W_X:W_AUX],
        w[W_AUX:W_CS],
        k[K_P:K_C],
        k[K_C:N_K],
        w[W_CS:W_SP],
        w[W_SP:W_U],
        w[W_U:N_W],
        dt,
        n,
    )
