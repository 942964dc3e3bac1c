"""The fixed-wing default mission plans its climb-out into the envelope (issue 11.7): the
runway take-off ends ~650 m north, beyond the certified region (fence − loiter reserve); the
autopilot's own loiter brings it back and the AI gets it only once the orbit certifies, so
the whole flight has no safety-net switch. In process (FixedWingAutopilot stepped directly)."""

import numpy as np

from flight.airframes_registry import make_autopilot
from flight.autopilot_api import FlightMode, Setpoint
from hil.orbit import ORBIT_CAMERA, OrbitCompanion, OrbitParams, fence_reserve, plan_orbit
from perception.pipeline import CameraRig, CameraRigParams
from policy.groundair.scenarios import Formation, draw_plan
from safety.config import ENVELOPE_DIR, load_envelope
from safety.monitor import make_z
from safety.supervisor import Supervisor, SupervisorParams


class Events:
    def __init__(self):
        self.records = []

    def write(self, record):
        self.records.append(record)


def test_default_climb_out_and_orbit_have_no_safety_net_switch():
    spec, sup = load_envelope(ENVELOPE_DIR / "fixedwing_field.toml")
    lim = spec.limits
    plan = plan_orbit(OrbitParams(alt_min_m=lim.floor_m + lim.margin_m,
                                  alt_max_m=lim.ceiling_m - lim.margin_m - 15.0))  # fmt: skip
    ap = make_autopilot("fixedwing", seed=0)
    assert ap.set_param("NAV_LOITER_RAD", plan.radius_m).ok
    team = Formation(draw_plan("lateral", np.random.default_rng(0), 3))
    events = Events()
    sv = Supervisor(spec.envelope(), SupervisorParams(**sup), events)
    comp = OrbitCompanion(plan, team, sv, CameraRig(ORBIT_CAMERA, 3, CameraRigParams("fast", 2.0)),
                          fence_reserve(spec))  # fmt: skip
    assert ap.arm().ok and ap.takeoff(40.0).ok
    while ap.mode is FlightMode.TAKEOFF or -ap.state.pos_ned[2] < 39.5:
        ap.step()
    north = float(ap.state.pos_ned[0])
    # where the take-off ends, the orbit's setpoint is not certifiable (the old hand-over)
    u = sv.implied_velocity(ap.state, comp.proposal(ap.state))
    assert north > 500.0 and sv.envelope.worst(make_z(ap.state, u)) > 0.0
    # the climb-out: the autopilot's own loiter toward the orbit until the net certifies
    target = np.array([comp.centre[0], comp.centre[1], -plan.altitude_m])
    assert ap.reposition(target).ok
    since, t_max = None, ap.clock.t + 300.0
    while ap.clock.t < t_max:
        for _ in range(5):
            ap.step()
        ok = comp.certified_now(ap.state)
        since = (since or ap.clock.t) if ok else None
        if since is not None and ap.clock.t - since >= 3.0:
            break
    assert since is not None, "never certified"
    t_handover = ap.clock.t
    north_max = north
    while ap.clock.t < t_handover + 120.0:
        state = ap.state
        comp.update(state.t, state)
        assert not comp.wants_hold
        pos, vel, yaw = comp.setpoint()
        assert ap.set_offboard_setpoint(Setpoint(pos_ned=pos, vel_ned=vel, yaw=yaw)).ok
        if ap.mode is not FlightMode.OFFBOARD:
            assert ap.set_mode(FlightMode.OFFBOARD).ok
        for _ in range(5):
            ap.step()
            state = ap.state
        north_max = max(north_max, float(state.pos_ned[0]))
    assert sv.stats.switches == 0 and not events.records, sv.stats.reasons
    assert north_max < 1000.0 - lim.margin_m
    d = float(np.hypot(*(ap.state.pos_ned[:2] - comp.centre)))
    assert abs(d - plan.radius_m) < 0.25 * plan.radius_m  # on the orbit
