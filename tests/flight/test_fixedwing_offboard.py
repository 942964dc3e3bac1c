"""The fixed-wing's offboard stream through real MAVLink, stepped on the simulation clock.

The orbit's hand-over (issue 11, item 7): the built-in fixed-wing left OFFBOARD for AUTO.LOITER
~1-2 s after the orbit took over. Cause: the in-process client's receive thread stalled ~240 ms
of wall time on its first orbit sample (2.4 s of simulation at --speedup 10), more than
COM_OF_LOSS_T = 0.5 s, and the autopilot's offboard-loss failsafe loitered — silently, which made
it look like a refusal. These tests drive the vehicle (flight.sitl, real UDP on 127.0.0.1,
pymavlink's codec) one step at a time as a lockstep companion would: a setpoint per 0.1 s tick,
stamped with the tick's (older) time, arriving one 20 ms step later.
"""

from __future__ import annotations

import numpy as np
import pytest
from mavlink_rig import Peer
from pymavlink.dialects.v20 import ardupilotmega as M

from skyherd.flight.airframes_registry import make_autopilot
from skyherd.flight.autopilot_api import FlightMode
from skyherd.flight.clock import SimClock
from skyherd.flight.mavlink import EndpointConfig
from skyherd.flight.mavlink.offboard import (
    IGNORE_ACC,
    IGNORE_POS,
    IGNORE_VEL,
    IGNORE_YAW,
    IGNORE_YAW_RATE,
)
from skyherd.flight.sitl import Sitl

INSTANCE = 85  # the fw helper's MAVLink instances: 85-89
POS_VEL = IGNORE_ACC | IGNORE_YAW | IGNORE_YAW_RATE  # 0xDC0: what the orbit may send
POS_ONLY = POS_VEL | IGNORE_VEL  # 0xDF8
VEL_ONLY = POS_VEL | IGNORE_POS  # 0xDC7
TICK_S = 0.1  # the lockstep camera tick


def texts(msgs) -> list[str]:
    """STATUSTEXTs, chunks (id, chunk_seq) joined as a ground station does."""
    out, parts = [], {}
    for m in msgs:
        if m.get_type() != "STATUSTEXT":
            continue
        if not m.id:
            out.append(m.text)
            continue
        parts.setdefault(m.id, []).append(m.text)
        if len(m.text) < 50:
            out.append("".join(parts.pop(m.id)))
    return out


class FwRig:
    """The built-in fixed-wing in level flight at 60 m over home (HOLD), its endpoint on real
    sockets, a pymavlink peer where the API link sends; the test steps the simulation."""

    def __init__(self, instance: int = INSTANCE):
        self.ap = make_autopilot("fixedwing", clock=SimClock(), instance=instance)
        self.cfg = EndpointConfig(instance=instance)
        self.sitl = Sitl(self.ap, self.cfg, speedup=0.0)
        self.peer = Peer(14540 + instance)
        self.sys = self.cfg.system_id
        self.ap.start_in_air(60.0, 24.0)
        self.got: list = []
        self.modes: list[tuple[float, FlightMode]] = []

    def step(self, seconds: float) -> None:
        for _ in range(round(seconds / self.ap.control_dt)):
            self.sitl.step()
            self.got.extend(self.peer.recv())
            if not self.modes or self.modes[-1][1] is not self.ap.mode:
                self.modes.append((self.ap.clock.t, self.ap.mode))

    def send(self, msg) -> None:
        self.peer.send(msg, self.cfg.api_bind)

    def setpoint(self, pos=(0.0, 0.0, -60.0), vel=(0.0, 0.0, 0.0), mask=POS_VEL, stamp_s=None):
        t = self.ap.clock.t if stamp_s is None else stamp_s
        self.send(M.MAVLink_set_position_target_local_ned_message(
            round(1000 * t), self.sys, 1, M.MAV_FRAME_LOCAL_NED, mask, *pos, *vel,
            0.0, 0.0, 0.0, 0.0, 0.0))  # fmt: skip

    def command(self, cmd: int, *p: float) -> None:
        params = list(p) + [0.0] * (7 - len(p))
        self.send(self.peer.mav.command_long_encode(self.sys, 1, cmd, 0, *params))

    def ticks(self, seconds: float, make_setpoint, skip=lambda t: False) -> None:
        """Lockstep ticks: at t_k the companion answers with a setpoint stamped t_k (skipped
        when `skip(t_k)`); it is handled one step later (L = 20 ms)."""
        for _ in range(round(seconds / TICK_S)):
            t_k = self.ap.clock.t
            if not skip(t_k):
                self.setpoint(**make_setpoint(t_k), stamp_s=t_k)
            self.step(TICK_S)

    def acks(self, cmd: int) -> list[int]:
        return [m.result for m in self.got if m.get_type() == "COMMAND_ACK" and m.command == cmd]

    def close(self) -> None:
        self.peer.close()
        self.sitl.close()


def _handover(rig: FwRig, centre, radius_m: float) -> float:
    """As the orbit: NAV_LOITER_RAD = R over MAVLink, the hold target streamed, then OFFBOARD
    (the mode command after the first setpoints). Returns the hand-over time [s]."""
    rig.send(rig.peer.mav.param_set_encode(rig.sys, 1, b"NAV_LOITER_RAD", radius_m,
                                           M.MAV_PARAM_TYPE_REAL32))  # fmt: skip
    rig.step(0.2)
    hold = [*rig.ap.state.pos_ned[:2], -60.0]
    rig.ticks(0.5, lambda t: {"pos": hold, "mask": POS_ONLY})
    rig.command(M.MAV_CMD_DO_SET_MODE, M.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED, 6)  # PX4 OFFBOARD
    rig.ticks(0.5, lambda t: {"pos": hold, "mask": POS_ONLY})
    assert rig.acks(M.MAV_CMD_DO_SET_MODE) == [M.MAV_RESULT_ACCEPTED]
    assert rig.ap.mode is FlightMode.OFFBOARD
    return rig.ap.clock.t


def test_orbit_stream_with_old_stamps_keeps_offboard_for_60s():
    """Position + velocity (0xDC0, the orbit's mask), stamped with the tick time 0.1 s before
    it acts: accepted every tick (the autopilot times arrivals, not stamps); the aircraft
    orbits the streamed centre at NAV_LOITER_RAD and never leaves OFFBOARD."""
    rig = FwRig()
    try:
        r = 150.0
        centre = np.array([400.0, 100.0])
        _handover(rig, centre, r)

        def orbit(t_k):
            v = rig.ap.state.vel_ned  # the orbit's feed-forward: accepted, the position flies
            return {"pos": [*centre, -60.0], "vel": list(v), "mask": POS_VEL}

        dist = []
        for _ in range(60):
            rig.ticks(1.0, orbit)
            dist.append(float(np.hypot(*(rig.ap.state.pos_ned[:2] - centre))))
        assert [m for _, m in rig.modes[-1:]] == [FlightMode.OFFBOARD]
        assert all(m is not FlightMode.HOLD for t, m in rig.modes if t > 1.5)
        assert rig.sitl.endpoint.stats["setpoint_dropped"] == 0
        assert rig.sitl.endpoint.stats["setpoint_refused"] == 0
        assert not any("offboard" in x for x in texts(rig.got))
        # established on the circle for the last 20 s (radius within 10 %)
        assert max(abs(d - r) for d in dist[-20:]) < 0.1 * r
        # the other masks a client may use: position only, velocity only (course + climb)
        rig.ticks(2.0, lambda t: {"pos": [*centre, -60.0], "mask": POS_ONLY})
        rig.ticks(2.0, lambda t: {"vel": [0.0, 24.0, 0.0], "mask": VEL_ONLY})
        assert rig.ap.mode is FlightMode.OFFBOARD
        assert rig.ap.phase.value == "course"
    finally:
        rig.close()


def test_a_stalled_client_loses_offboard_after_com_of_loss_t_and_the_vehicle_says_why():
    """The hand-over failure: the client's first orbit sample came 2.1 s late. A gap of 0.4 s
    is tolerated; 0.7 s > COM_OF_LOSS_T (0.5 s) loiters (HOLD = AUTO.LOITER) — and the vehicle
    now says so in a STATUSTEXT with the gap (before: silent, the mode just changed)."""
    rig = FwRig()
    try:
        t0 = _handover(rig, np.array([400.0, 100.0]), 150.0)
        orbit = lambda t: {"pos": [400.0, 100.0, -60.0], "mask": POS_VEL}  # noqa: E731
        rig.ticks(2.0, orbit, skip=lambda t: t0 + 1.0 <= t < t0 + 1.35)  # 0.4 s gap: kept
        assert rig.ap.mode is FlightMode.OFFBOARD
        t1 = rig.ap.clock.t
        rig.ticks(3.0, orbit, skip=lambda t: t >= t1 + 1.0 - 1e-9)  # the client stops
        lost = [t for t, m in rig.modes if m is FlightMode.HOLD and t > t1]
        assert len(lost) == 1
        # the last setpoint acted at t1 + 0.92 (stamped 0.9, one step later); 0.5 s after it
        assert lost[0] - (t1 + 0.92) == pytest.approx(0.52, abs=0.021)
        said = [x for x in texts(rig.got) if "offboard setpoints lost" in x]
        assert len(said) == 1 and "COM_OF_LOSS_T 0.5 s" in said[0] and "-> hold" in said[0]
        gap = float(said[0].split("none for ")[1].split(" s")[0])
        assert 0.5 < gap <= 0.54
    finally:
        rig.close()


def test_a_refused_setpoint_is_reported_once_and_the_stream_ages_to_hold():
    """With a 300 m cylinder (GF_MAX_HOR_DIST), an orbit centre whose loiter circle leaves it is
    refused: one STATUSTEXT naming the fence (setpoints have no answer), the stream ages, the
    offboard-loss failsafe loiters. The earlier, accepted centre is what it flew until then."""
    rig = FwRig()
    try:
        _handover(rig, np.array([0.0, 0.0]), 150.0)
        rig.send(rig.peer.mav.param_set_encode(rig.sys, 1, b"GF_MAX_HOR_DIST", 300.0,
                                               M.MAV_PARAM_TYPE_REAL32))  # fmt: skip
        rig.ticks(1.0, lambda t: {"pos": [0.0, 0.0, -60.0], "mask": POS_ONLY})
        assert rig.ap.mode is FlightMode.OFFBOARD  # 150 m circle about home fits in 300 m
        rig.ticks(2.0, lambda t: {"pos": [250.0, 0.0, -60.0], "mask": POS_ONLY})
        said = [x for x in texts(rig.got) if "offboard setpoint refused" in x]
        assert len(said) == 1 and "geofence" in said[0]
        assert rig.sitl.endpoint.stats["setpoint_refused"] == 20
        assert rig.ap.mode is FlightMode.HOLD
        assert any("offboard setpoints lost" in x for x in texts(rig.got))
    finally:
        rig.close()
