"""A companion's mode change crossing the autopilot's own failsafe (docs/safety.md, Runs 7-8).

The battery failsafe switches at a whole second; a companion's DO_SET_MODE decided before it
could see that switch arrives a lockstep latency (20 ms) later. Through the real endpoint on
loopback UDP: the autopilot refuses it (TEMPORARILY_REJECTED, the reason in STATUSTEXT) and
stays in its failsafe; a ground station may still take over, as a PX4 user can."""

from __future__ import annotations

from pymavlink.dialects.v20 import ardupilotmega as M

from skyherd.flight.autopilot_api import FlightMode
from skyherd.runio.constants import COMPANION_COMPONENT, LOCKSTEP_LATENCY_S
from tests.mavlink_rig import Peer, Rig, texts

INSTANCE = 75
HOLD = (M.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED, 4, 3)  # PX4 AUTO / LOITER


def _to_failsafe(rig: Rig) -> float:
    """Hover, then make the charge critical: step until the battery check switches to RTL."""
    rig.fly(10.0)
    rig.ap._battery_drop += rig.ap.battery_remaining - 0.065  # a failing cell (flight.faults)
    while rig.ap.mode is not FlightMode.RTL:
        rig.sitl.step()
        assert rig.ap.clock.t < 30.0
    return rig.ap.clock.t


def test_a_companion_request_within_the_latency_is_refused():
    with Rig(INSTANCE) as rig:
        companion = Peer(0, rig.sys, COMPANION_COMPONENT)
        try:
            t_fs = _to_failsafe(rig)
            ack = rig.command(M.MAV_CMD_DO_SET_MODE, *HOLD, peer=companion)
            assert rig.ap.clock.t - t_fs <= LOCKSTEP_LATENCY_S
            assert ack is not None and ack.result == M.MAV_RESULT_TEMPORARILY_REJECTED
            assert rig.ap.mode is FlightMode.RTL  # the failsafe stands
            rig.step(0.1)
            got = companion.recv()
            assert rig.ap.mode is FlightMode.RTL
            assert any("failsafe in force" in x for x in texts(got)) or rig.ap.failsafe_in_force
        finally:
            companion.close()


def test_a_ground_station_may_still_take_over_then_the_companion_may_ask():
    with Rig(INSTANCE) as rig:
        companion = Peer(0, rig.sys, COMPANION_COMPONENT)
        try:
            _to_failsafe(rig)
            rig.ap.params.set("BAT_CRIT_THR", 0.0)  # no new failsafe after the takeover
            rig.ap.params.set("BAT_EMERGEN_THR", 0.0)
            ack = rig.command(M.MAV_CMD_DO_SET_MODE, *HOLD)  # the rig's client: 255/190
            assert ack is not None and ack.result == M.MAV_RESULT_ACCEPTED
            assert rig.ap.mode is FlightMode.HOLD and not rig.ap.failsafe_in_force
            ack = rig.command(M.MAV_CMD_DO_SET_MODE, M.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED, 4, 5,
                              peer=companion)  # fmt: skip
            assert ack is not None and ack.result == M.MAV_RESULT_ACCEPTED  # AUTO / RTL
            assert rig.ap.mode is FlightMode.RTL
        finally:
            companion.close()
