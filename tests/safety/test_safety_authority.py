"""The net yields to the autopilot: scripted timelines of safety.authority and the real
autopilot's battery failsafe behind apply_decision (issue 11 item 2)."""

import numpy as np

from skyherd.flight.autopilot_api import FlightMode, Setpoint
from skyherd.flight.multirotor.autopilot import MultirotorAutopilot
from skyherd.safety.authority import Authority, Phase
from skyherd.safety.net import SafetyNet, apply_decision, load_net
from skyherd.safety.supervisor import Health, Mode


class Sink:
    def __init__(self):
        self.records = []

    def write(self, r):
        self.records.append(r)


def fly_timeline(auth, timeline, want_fn, t_end, dt=0.5):
    """Scripted autopilot: `timeline` {t: mode it switches to by itself}; the net asks for
    want_fn(t) and the autopilot obeys accepted requests. Returns the requests (t, mode)."""
    mode, asks = FlightMode.OFFBOARD, []
    auth.start(0.0, mode)
    for k in range(int(t_end / dt)):
        t = k * dt
        if t in timeline:
            mode = timeline[t]
        auth.observe(t, mode)
        ask = auth.request(want_fn(t))
        if ask is not None:
            asks.append((t, ask))
            auth.requested(t, ask, True)
            mode = ask
    return asks


def test_battery_rtl_at_40_s_no_offboard_request_after_it():
    sink = Sink()
    auth = Authority(sink)
    # the net alternates HOLD (fallback) and OFFBOARD; the autopilot goes RTL by itself at 40 s
    asks = fly_timeline(auth, {40.0: FlightMode.RTL},
                        lambda t: FlightMode.HOLD if 10 <= t < 20 else FlightMode.OFFBOARD, 80.0)  # fmt: skip
    assert asks == [(10.0, FlightMode.HOLD), (20.0, FlightMode.OFFBOARD)]
    assert not [a for a in asks if a[0] >= 40.0]
    assert auth.phase is Phase.ENDED and auth.mission == "end"
    y = [r for r in sink.records if r["event"] == "yield"]
    assert len(y) == 1 and y[0]["t"] == 40.0 and y[0]["autopilot_mode"] == "RTL"
    assert "not asked for by the net" in y[0]["reason"] and "mission ends" in y[0]["reason"]


def test_gcs_hold_waits_and_offboard_from_the_operator_gives_authority_back():
    auth = Authority()
    asks = fly_timeline(auth, {30.0: FlightMode.HOLD, 50.0: FlightMode.OFFBOARD},
                        lambda t: FlightMode.OFFBOARD, 70.0)  # fmt: skip
    assert asks == []  # never asks for OFFBOARD itself after the operator's HOLD
    assert auth.phase is Phase.AI  # given back at 50 s by the operator
    assert [y[1] for y in auth.yields] == ["HOLD"]


def test_stale_heartbeat_and_denied_request_are_not_a_takeover():
    auth = Authority()
    auth.start(0.0, FlightMode.OFFBOARD)
    auth.requested(1.0, FlightMode.HOLD, True)
    auth.observe(1.1, FlightMode.OFFBOARD)  # heartbeat not updated yet
    auth.observe(1.5, FlightMode.HOLD)  # the switch the net asked for
    auth.requested(2.0, FlightMode.OFFBOARD, False)  # denied
    auth.observe(2.5, FlightMode.HOLD)  # unchanged: not a takeover
    assert auth.has_authority
    auth.observe(3.0, FlightMode.LAND)  # emergency land while the net asked for HOLD
    assert auth.phase is Phase.ENDED and auth.request(FlightMode.OFFBOARD) is None


def test_real_autopilot_battery_failsafe_is_not_undone():
    """A push toward the fence while the battery reaches critical: the autopilot's RTL and
    its emergency LAND are never switched back to OFFBOARD (26 times, before)."""
    ap = MultirotorAutopilot(battery_start=0.085)
    ap.arm()
    ap.takeoff(15.0)
    while ap.mode is FlightMode.TAKEOFF and ap.clock.t < 30:
        ap.step()
    sink = Sink()
    sup = load_net("quadrotor")
    auth = Authority(sink)
    ap.set_offboard_setpoint(Setpoint(vel_ned=np.zeros(3)))
    assert ap.set_mode(FlightMode.OFFBOARD).ok
    auth.start(ap.clock.t, ap.mode)
    modes, offboard_after, t_rtl = [], 0, None
    n_sub = round(0.02 / ap.control_dt)
    while ap.clock.t < 200 and ap.armed:
        t = ap.clock.t
        d = sup.update(t, ap.state, Setpoint(vel_ned=np.array([2.0, 0.0, 0.0])), Health())
        apply_decision(ap, d, authority=auth)
        if t_rtl is None and ap.mode is FlightMode.RTL:
            t_rtl = t
        if t_rtl is not None and ap.mode is FlightMode.OFFBOARD:
            offboard_after += 1
        modes.append(ap.mode)
        for _ in range(n_sub):
            ap.step()
        if t_rtl is not None and ap.clock.t - t_rtl > 15:
            break
    assert t_rtl is not None, "battery critical never reached"
    assert offboard_after == 0
    assert auth.mission == "end" and auth.yields[0][1] == "RTL"
    assert [r["event"] for r in sink.records] == ["handover", "yield"]


def test_apply_decision_without_authority_never_leaves_rtl():
    ap = MultirotorAutopilot()
    ap.arm()
    ap.takeoff(10.0)
    while ap.mode is FlightMode.TAKEOFF and ap.clock.t < 30:
        ap.step()
    assert ap.return_to_launch().ok
    sup = load_net("quadrotor")
    d = sup.update(ap.clock.t, ap.state, Setpoint(vel_ned=np.zeros(3)), Health())
    assert d.mode is Mode.AI
    r = apply_decision(ap, d)
    assert not r.ok and "RTL" in r.reason and ap.mode is FlightMode.RTL


def test_safety_net_step_requests_nothing_after_a_yield():
    sup = load_net("quadrotor")
    net = SafetyNet(sup, camera=False)
    st = MultirotorAutopilot(start_pos_ned=(0.0, 0.0, -20.0)).state
    net.handover(0.0, FlightMode.OFFBOARD)
    for k in range(10):
        net.message(k * 0.02, "HEARTBEAT")
        net.message(k * 0.02, "LOCAL_POSITION_NED")
        d = net.step(k * 0.02, st, Setpoint(vel_ned=np.zeros(3)), FlightMode.OFFBOARD)
        assert d.mode is Mode.AI and net.request(d) is None
    d = net.step(0.3, st, Setpoint(vel_ned=np.zeros(3)), FlightMode.POSCTL, "RC override")
    assert (
        net.request(d) is None
        and net.authority.mission == "wait"
        and "RC override" in net.authority.reason
    )


def test_request_registered_before_sending_and_undone_when_denied():
    auth = Authority()
    auth.start(0.0, FlightMode.HOLD, asked=FlightMode.HOLD)
    auth.requested(1.0, FlightMode.OFFBOARD, True)  # before sending: the switch may show first
    auth.observe(1.05, FlightMode.OFFBOARD)
    assert auth.has_authority
    auth.requested(2.0, FlightMode.HOLD, True)
    auth.requested(2.1, FlightMode.HOLD, False)  # refused: OFFBOARD is the request again
    auth.observe(2.5, FlightMode.HOLD)  # so a HOLD now is not the net's
    assert auth.phase is Phase.WAIT
