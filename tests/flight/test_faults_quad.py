"""Faults in the simulation (flight/faults.py) acting on the multirotor: the plan's parsing,
steady wind against the drag model's force balance, GPS glitch / drift / loss as the
autopilot sees and reports them (LOCAL_POSITION_NED), estimate noise, battery faults with
the autopilot's own failsafes, and determinism for a seed. Simulation time only."""

from __future__ import annotations

import math

import numpy as np
import pytest
from pymavlink.dialects.v20 import ardupilotmega as M

from skyherd.flight.autopilot_api import FlightMode
from skyherd.flight.faults import (
    FaultEvent,
    FaultPlan,
    FaultSpecError,
    SensorNoise,
    parse_fault_args,
    parse_fault_event,
    wind_from,
)
from skyherd.flight.mavlink.codec import decode_payload
from skyherd.flight.mavlink.telemetry import Identity, TelemetryBuilder
from skyherd.flight.multirotor import MultirotorAutopilot
from skyherd.flight.quadrotor import QuadrotorParams, WindModel


def run(ap, seconds: float) -> tuple[np.ndarray, np.ndarray]:
    """Step; (n, 3) estimated and (n, 3) true positions."""
    n = round(seconds / ap.control_dt)
    est, tru = np.empty((n, 3)), np.empty((n, 3))
    for k in range(n):
        ap.step()
        est[k] = ap.state.pos_ned
        tru[k] = ap.true_state.pos_ned
    return est, tru


def hovering(plan: FaultPlan | None = None, alt: float = 20.0, **kw) -> MultirotorAutopilot:
    ap = MultirotorAutopilot(faults=plan, **kw)
    assert ap.arm().ok and ap.takeoff(alt).ok
    run(ap, 12.0)
    return ap


def test_command_line_forms_parse_round_trip_and_bad_ones_say_why():
    plan = parse_fault_args(
        "16,90",
        "3,1.5",
        "0.5,0.1",
        [
            "gps_glitch@30:20,0,0:5",
            "gps_loss@40",
            "battery@60:0.06",
            "wind@10:5,0:2",
            "drain@1:300:60",
        ],
        seed=7,
    )
    assert plan.wind.mean_ned == pytest.approx((0.0, -16.0, 0.0), abs=1e-12)  # from the east
    assert (plan.wind.gust_std, plan.wind.gust_tau, plan.wind.seed) == (3.0, 1.5, 7)
    assert plan.noise == SensorNoise(0.5, 0.1)
    assert [e.kind for e in plan.events] == ["drain", "wind", "gps_glitch", "gps_loss", "battery"]
    g = plan.events[2]
    assert (g.t0, g.duration, g.vec) == (30.0, 5.0, (20.0, 0.0, 0.0))
    assert plan.events[3].duration is None  # to the end
    for e in plan.events:
        again = parse_fault_event(e.to_text())
        assert again.kind == e.kind and again.t0 == e.t0 and again.duration == e.duration
        assert again.vec == pytest.approx(e.vec, abs=1e-9) and again.value == e.value
    args = plan.to_args()
    back = parse_fault_args(
        *(args[args.index(f) + 1] if f in args else None for f in ("--wind", "--gust", "--noise")),
        [args[i + 1] for i, a in enumerate(args) if a == "--fault"],
        seed=7,
    )
    assert back.wind.mean_ned == pytest.approx(plan.wind.mean_ned, abs=1e-9)
    assert wind_from(10.0, 270.0) == pytest.approx((0.0, 10.0, 0.0), abs=1e-12)
    for bad, part in (
        (dict(wind="16"), "SPEED,FROM"),
        (dict(wind="99,0"), "[0, 60]"),
        (dict(gust="-1"), "STD"),
        (dict(faults=["gps_glitch@30"]), "T:ARGS"),
        (dict(faults=["meteor@3:1"]), "kind must be one of"),
        (dict(faults=["gps_glitch30:1,2,3"]), "KIND@T"),
        (dict(faults=["battery@3:1.5"]), "[0, 1]"),
        (dict(faults=["gps_loss@3:-1"]), "duration"),
        (dict(faults=["gps_glitch@nan:1,2,3"]), "finite"),
    ):
        with pytest.raises(FaultSpecError, match=part.replace("[", r"\[").replace("]", r"\]")):
            parse_fault_args(**bad)


def test_steady_wind_tilt_matches_the_drag_force_balance():
    """Hovering in a steady 8 m/s wind from the west (blowing east), at rest over the ground.
    The body sees the air at v_b = Rᵀ(0 − w); drag D_b = −c₁ v_b − c₂|v_b|v_b per body axis
    (flight/quadrotor.py). At rest the world-frame sum of drag, thrust T (−z_b) and weight is
    zero: with a pure roll φ the down balance gives T, the east balance is the residual
    below, solved by bisection for φ with the airframe's c₁, c₂. The autopilot's measured
    roll must match within 0.3°."""
    plan = parse_fault_args(wind="8,270")
    ap = hovering(plan)
    run(ap, 20.0)
    assert np.linalg.norm(ap.true_state.vel_ned) < 0.02
    roll = ap.true_state.euler[0]
    q = QuadrotorParams()
    w = 8.0

    def residual(phi: float) -> float:
        # body axes for roll phi: y_b = (0, cos φ, sin φ), z_b = (0, −sin φ, cos φ) in NED;
        # the air moves at +w east relative to the vehicle: v_air_rel = −w e_E in the body
        vy, vz = -w * math.cos(phi), w * math.sin(phi)
        dy = -q.drag_linear[1] * vy - q.drag_quadratic[1] * abs(vy) * vy
        dz = -q.drag_linear[2] * vz - q.drag_quadratic[2] * abs(vz) * vz
        # world east and down of drag + thrust T along −z_b; choose T so that down balances
        # east: dy cos φ − dz sin φ + T sin φ = 0; down: dy sin φ + dz cos φ − T cos φ + m g = 0
        t = (dy * math.sin(phi) + dz * math.cos(phi) + q.mass * q.gravity) / math.cos(phi)
        return dy * math.cos(phi) - dz * math.sin(phi) + t * math.sin(phi)

    lo, hi = -0.6, 0.0  # rolls left (negative) to lean into a wind blowing east
    for _ in range(60):
        mid = 0.5 * (lo + hi)
        if residual(lo) * residual(mid) <= 0:
            hi = mid
        else:
            lo = mid
    assert roll == pytest.approx(0.5 * (lo + hi), abs=math.radians(0.3))
    assert ap.wind_ned == pytest.approx([0.0, 8.0, 0.0], abs=1e-9)


def test_gps_glitch_seen_in_local_position_ned_and_flown_on():
    """A +20 m north glitch for 5 s at t = 20 s in HOLD: the estimate (and LOCAL_POSITION_NED)
    jumps by the offset at once; the autopilot flies its estimate back to the hold point, so
    the true position ends 20 m south; when the glitch ends it returns."""
    plan = FaultPlan(events=(FaultEvent("gps_glitch", 20.0, 5.0, (20.0, 0.0, 0.0)),))
    ap = hovering(plan)
    run(ap, 20.0 - ap.clock.t - ap.control_dt)
    before = ap.state.pos_ned.copy()
    tb = TelemetryBuilder(ap, Identity(1, 1, "px4", M.MAV_TYPE_QUADROTOR))
    ap.step()
    ap.step()
    lp = decode_payload(tb.build(M.MAVLINK_MSG_ID_LOCAL_POSITION_NED))
    assert lp.x - before[0] == pytest.approx(20.0, abs=0.05)
    assert ap.true_state.pos_ned[0] == pytest.approx(before[0], abs=0.05)
    est, tru = run(ap, 4.9)
    assert tru[-1, 0] == pytest.approx(before[0] - 20.0, abs=1.5)
    assert est[-1, 0] == pytest.approx(before[0], abs=1.5)
    est, tru = run(ap, 10.0)
    assert tru[-1, 0] == pytest.approx(before[0], abs=0.3)
    assert np.abs(est - tru)[round(0.2 / ap.control_dt) :].max() < 1e-9  # none after it


def test_gps_drift_grows_at_its_rate():
    plan = FaultPlan(events=(FaultEvent("gps_drift", 15.0, 10.0, (0.5, -0.2, 0.0)),))
    ap = hovering(plan)
    run(ap, 15.0 - ap.clock.t)
    est, tru = run(ap, 8.0)
    err = est - tru
    t = np.arange(1, len(err) + 1) * ap.control_dt
    assert err[:, 0] == pytest.approx(0.5 * (t - ap.control_dt), abs=0.01)
    assert err[:, 1] == pytest.approx(-0.2 * (t - ap.control_dt), abs=0.01)
    assert abs(tru[-1, 0] - tru[0, 0]) == pytest.approx(0.5 * 8.0, abs=1.0)  # flown on


def test_gps_loss_dead_reckons_then_lands_after_the_timeout():
    plan = FaultPlan(events=(FaultEvent("gps_loss", 15.0),))
    ap = hovering(plan, seed=3)
    run(ap, 15.0 - ap.clock.t - ap.control_dt)
    assert ap.gps_fix
    ap.drain_status()
    run(ap, 4.9)
    assert not ap.gps_fix and ap.position_valid and ap.mode == FlightMode.HOLD
    assert ap.reposition(np.array([0.0, 0.0, -20.0])).ok is not False  # still valid
    run(ap, 0.2)
    texts = " ".join(ap.drain_status())
    assert "gps fix lost" in texts and "position lost -> land" in texts
    assert ap.mode == FlightMode.LAND and not ap.position_valid
    r = ap.reposition(np.array([0.0, 0.0, -20.0]))
    assert not r.ok and "position" in r.reason
    run(ap, 40.0)
    assert not ap.armed and ap.true_state.on_ground
    # dead-reckoning error: ½ b t² with |b| ~ σ_b = 0.05 m/s² (seeded): bounded at 45 s
    err = ap.state.pos_ned[:2] - ap.true_state.pos_ned[:2]
    assert 0.0 < np.linalg.norm(err) < 0.5 * 4 * 0.05 * 45.0**2


def test_noise_statistics_and_same_seed_same_flight():
    plan = FaultPlan(noise=SensorNoise(pos_std=0.5, vel_std=0.1))
    ap1 = hovering(plan, seed=11)
    est, tru = run(ap1, 30.0)
    err = (est - tru)[:, 0]
    assert 0.25 < err.std() < 0.75  # σ_p = 0.5 (a 42 s sample of a τ = 1 s process)
    ap2 = hovering(plan, seed=11)
    est2, tru2 = run(ap2, 30.0)
    assert np.array_equal(tru, tru2) and np.array_equal(est, est2)
    ap3 = hovering(plan, seed=12)
    _, tru3 = run(ap3, 30.0)
    assert not np.array_equal(tru, tru3)


def test_battery_fault_fires_the_autopilots_failsafes_at_their_thresholds():
    """battery@20:0.065 drops the charge below BAT_CRIT_THR 7 %: RTL within the 1 Hz check;
    drain@20:2000 then pulls it under BAT_EMERGEN_THR 5 %: LAND. Both are the autopilot's own
    mode changes with their reasons in the status lines (STATUSTEXT over MAVLink)."""
    plan = parse_fault_args(faults=["battery@20:0.065", "drain@21:3000"])
    ap = hovering(plan)
    run(ap, 20.0 - ap.clock.t)
    ap.drain_status()
    run(ap, 1.05)
    texts = ap.drain_status()
    assert ap.mode == FlightMode.RTL and 0.06 < ap.battery_remaining < 0.07
    assert any("battery fault" in t for t in texts) and any(
        "critical -> return" in t for t in texts
    )
    # 3000 W extra: 7.4e-3 of the 74 Wh pack per s → below 5 % in ~2 s, plus the 1 s check
    n = 0
    while ap.mode != FlightMode.LAND and n < round(10 / ap.control_dt):
        ap.step()
        n += 1
    assert ap.mode == FlightMode.LAND and ap.battery_remaining <= 0.05
    assert ap.battery_remaining > 0.05 - 1.2 * 3000 / (74 * 3600)
    assert any("emergency -> land" in t for t in ap.drain_status())


def test_disarm_and_rtl_faults_act_on_the_autopilot_at_their_times():
    """disarm@T: a forced disarm in the air (the vehicle falls); rtl@T:D: RTL at T and the mode
    before it again at T + D (a ground station's RTL and back), each exactly once."""
    for text in ("disarm@25", "rtl@25.02:0.05", "rtl@30"):
        assert parse_fault_event(text).to_text() == text
    with pytest.raises(FaultSpecError, match="no duration"):
        parse_fault_event("disarm@25:3")
    with pytest.raises(FaultSpecError, match=r"rtl@T\[:DURATION\]"):
        parse_fault_event("rtl@25:1:2")
    ap = hovering(parse_fault_args(faults=["rtl@12.5:0.05"]))
    assert ap.mode == FlightMode.HOLD
    run(ap, 12.5 - ap.clock.t + 0.02)
    assert ap.mode == FlightMode.RTL
    run(ap, 0.05)
    assert ap.mode == FlightMode.HOLD  # back, and stays
    run(ap, 1.0)
    assert ap.mode == FlightMode.HOLD and any("fault: RTL" in t for t in ap.drain_status())
    ap = hovering(parse_fault_args(faults=["disarm@13"]))
    run(ap, 13.0 - ap.clock.t + 0.01)
    assert not ap.armed and any("forced" in t for t in ap.drain_status())
    _, tru = run(ap, 1.0)
    assert tru[-1, 2] > tru[0, 2] + 2.0  # falling: > 2 m in the first second


def test_gusts_deterministic_for_the_seed():
    plan = FaultPlan(wind=WindModel((3.0, 0.0, 0.0), gust_std=2.0, gust_tau=1.0, seed=5))
    a, b = hovering(plan), hovering(plan)
    ea, _ = run(a, 10.0)
    eb, _ = run(b, 10.0)
    assert np.array_equal(ea, eb) and np.ptp(ea[:, 0]) > 0.05


def test_sitl_command_line_takes_the_fault_flags(tmp_path):
    """`skyherd sitl` (instance 66) records the plan and its flags in config.json; a bad flag
    is bad usage with a one-line reason."""
    import argparse
    import json
    import signal

    from skyherd.scripts import sitl as sitl_cmd
    from skyherd.scripts.cli import UsageError

    parser = argparse.ArgumentParser()
    sitl_cmd.add_arguments(parser)
    common = ["--instance", "66", "--speedup", "0", "--runs-dir", str(tmp_path), "--no-tlog"]
    common += ["--state-dir", str(tmp_path / "state")]
    args = parser.parse_args(
        [*common, "--duration", "1", "--wind", "5,90", "--fault", "gps_loss@0.5:1"]
    )
    saved = {sig: signal.getsignal(sig) for sig in (signal.SIGINT, signal.SIGTERM)}
    try:
        assert sitl_cmd.run(args) == 0
    finally:  # run() installs its own handlers: give pytest its own back
        for sig, handler in saved.items():
            signal.signal(sig, handler)
    (cfg,) = tmp_path.glob("*/config.json")
    data = json.loads(cfg.read_text())
    assert data["fault_args"] == ["--wind", "5,90,0", "--fault", "gps_loss@0.5:1"]
    assert data["faults"]["events"][0]["kind"] == "gps_loss"
    bad = parser.parse_args([*common, "--fault", "gps_glitch@3:1,2"])
    with pytest.raises(UsageError, match="N,E,D"):
        sitl_cmd.run(bad)


def test_faults_over_mavlink_glitch_in_local_position_and_battery_failsafe():
    """Instance 67, real UDP, the SITL stepped in the test's thread: a 20 m north glitch at
    t = 16 s appears in LOCAL_POSITION_NED (what the autopilot believes); battery@20:0.065
    then shows as the autopilot's own switch to RTL (HEARTBEAT custom mode AUTO.RTL) with the
    "critical -> return" STATUSTEXT."""
    from test_quad_fence import _Gcs

    from skyherd.flight.clock import SimClock
    from skyherd.flight.mavlink import EndpointConfig
    from skyherd.flight.sitl import Sitl

    plan = parse_fault_args(faults=["gps_glitch@16:20,0,0:3", "battery@20:0.065"])
    ap = MultirotorAutopilot(clock=SimClock(), faults=plan)
    with Sitl(ap, EndpointConfig(instance=67), speedup=0) as sitl:
        gcs = _Gcs(sitl, instance=67)
        try:
            assert gcs.pump("HEARTBEAT") is not None
            assert gcs.command(M.MAV_CMD_COMPONENT_ARM_DISARM, 1).result == 0
            assert gcs.command(M.MAV_CMD_NAV_TAKEOFF, *[0] * 6, 584.0 + 15).result == 0
            gcs.pump("NONE", sim_s=15.5)
            gcs.seen.clear()
            gcs.pump("NONE", sim_s=1.5)  # 15.5 .. 17 s
            lp = [(m.time_boot_ms, m.x) for m in gcs.seen["LOCAL_POSITION_NED"]]
            before = [x for t, x in lp if t < 16000]
            after = [x for t, x in lp if 16000 <= t < 16300]
            assert before and after
            assert after[0] - before[-1] == pytest.approx(20.0, abs=0.3)
            hb = gcs.pump("HEARTBEAT", lambda m: m.custom_mode == (4 << 16) | (5 << 24), 8.0)
            assert hb is not None and ap.mode == FlightMode.RTL
            gcs.pump("NONE", sim_s=0.5)
            assert any("critical -> return" in t for t in gcs.texts), gcs.texts
            assert any("battery fault" in t for t in gcs.texts)
        finally:
            gcs.conn.close()
