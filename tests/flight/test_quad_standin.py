"""The built-in quadrotor as a PX4 stand-in (flight/airframes/px4_standin.toml): PX4's
default limits hold in flight, and its step responses are the documented ones."""

from __future__ import annotations

import tomllib

import numpy as np
import pytest

from skyherd.flight.airframes_registry import PX4_STANDIN, make_autopilot
from skyherd.flight.autopilot_api import FlightMode, Setpoint
from skyherd.flight.multirotor import MultirotorAutopilot

PX4_DEFAULTS = {  # PX4 v1.14 parameter reference defaults
    "MPC_TKO_SPEED": 1.5,
    "MPC_XY_VEL_MAX": 12.0,
    "MPC_XY_CRUISE": 5.0,
    "MPC_ACC_HOR": 3.0,
    "MPC_XY_TRAJ_P": 0.5,
    "MPC_ACC_UP_MAX": 4.0,
    "MPC_ACC_DOWN_MAX": 3.0,
    "MIS_TAKEOFF_ALT": 2.5,
}


def fly(ap, seconds: float, tgt=None) -> np.ndarray:
    """(n, 7): t, position (3), velocity (3) of the truth; streams a position at 50 Hz."""
    n = round(seconds / ap.control_dt)
    out = np.empty((n, 7))
    for k in range(n):
        if tgt is not None and k % 5 == 0:
            ap.set_offboard_setpoint(Setpoint(pos_ned=tgt))
        ap.step()
        s = ap.state
        out[k, 0], out[k, 1:4], out[k, 4:7] = s.t, s.pos_ned, s.vel_ned
    return out


def settle(r: np.ndarray, axis: int, target: float, band: float) -> float:
    out = np.nonzero(np.abs(r[:, axis] - target) > band)[0]
    return float(r[out[-1] + 1, 0] - r[0, 0]) if len(out) else 0.0


def test_standin_file_holds_px4_defaults_and_loads_through_the_registry():
    table = tomllib.loads(PX4_STANDIN.read_text())["params"]
    for name, value in PX4_DEFAULTS.items():
        assert table[name] == value, name
    ap = make_autopilot("quadrotor", params_file=PX4_STANDIN)
    assert ap.get_param("SH_POS_SMOOTH") == 2.0 and ap.get_param("MPC_TKO_SPEED") == 1.5
    with pytest.raises(ValueError, match="cannot read"):
        make_autopilot("quadrotor", params_file=PX4_STANDIN.with_name("nope.toml"))


def test_standin_takeoff_step_and_limits():
    """Takeoff to 10 m climbs at ≤ MPC_TKO_SPEED (+10 %); a 20 m offboard position step
    shapes a reference whose acceleration never exceeds MPC_ACC_HOR (the vehicle, tracking it
    through the attitude loop's lag, peaks 30 % above), does not overshoot and settles within
    5 % in 7.4–8.4 s (measured 7.9 s; within 0.2 m at 11.6 s) — skyherd's defaults 3.3 s;
    PX4 SIH 11.1 s per issue 12. Takeoff 10 m within 5 %: 7.8–8.8 s (8.6 s)."""
    ap = MultirotorAutopilot(params_file=PX4_STANDIN)
    assert ap.arm().ok and ap.takeoff(10.0).ok
    r = fly(ap, 20.0)
    assert 1.4 < -r[:, 6].min() < 1.5 * 1.1  # the velocity loop overshoots its limit by 5 %
    assert 7.8 < settle(r, 3, -10.0, 0.5) < 8.8
    tgt = np.array([20.0, 0.0, -10.0])
    ap.set_offboard_setpoint(Setpoint(pos_ned=tgt))
    assert ap.set_mode(FlightMode.OFFBOARD).ok
    n = round(25.0 / ap.control_dt)
    r = np.empty((n, 7))
    ref_acc = 0.0
    for k in range(n):
        if k % 5 == 0:
            ap.set_offboard_setpoint(Setpoint(pos_ned=tgt))
        ap.step()
        s = ap.state
        r[k, 0], r[k, 1:4], r[k, 4:7] = s.t, s.pos_ned, s.vel_ned
        ref_acc = max(ref_acc, float(np.hypot(*ap._ref_a[:2])))
    assert ref_acc <= 3.0 + 1e-9
    acc = np.diff(r[:, 4]) / ap.control_dt
    acc = np.convolve(acc, np.ones(25) / 25, mode="valid")  # 0.1 s mean: no rotor ripple
    assert np.abs(acc).max() < 3.0 * 1.35
    assert 7.4 < settle(r, 1, 20.0, 1.0) < 8.4
    assert 11.0 < settle(r, 1, 20.0, 0.2) < 12.2
    assert r[:, 1].max() < 20.0 + 0.05  # no overshoot
    # the defaults: unshaped, 3.3 s
    ap = MultirotorAutopilot()
    ap.arm()
    ap.takeoff(10.0)
    fly(ap, 12.0)
    ap.set_offboard_setpoint(Setpoint(pos_ned=tgt))
    ap.set_mode(FlightMode.OFFBOARD)
    assert settle(fly(ap, 15.0, tgt), 1, 20.0, 1.0) < 4.0
