"""The orbit behind the safety net, in process (FixedWingAutopilot stepped directly, no
sockets): a UGV team that drives out of the field must not drag the orbit across the fence."""

import math

import numpy as np
import pytest

from flight.airframes_registry import make_autopilot
from flight.autopilot_api import FlightMode, Setpoint
from hil.orbit import (
    ORBIT_CAMERA,
    OrbitCompanion,
    OrbitParams,
    circle_certified,
    fence_reserve,
    plan_orbit,
)
from perception.pipeline import CameraRig, CameraRigParams
from policy.groundair.scenarios import Formation, draw_plan
from safety.config import ENVELOPE_DIR, load_envelope
from safety.supervisor import Supervisor, SupervisorParams


class Events:
    def __init__(self):
        self.records = []

    def write(self, record):
        self.records.append(record)


def test_team_driving_out_of_the_field_freezes_the_orbit_inside_the_fence():
    spec, sup = load_envelope(ENVELOPE_DIR / "fixedwing_field.toml")
    lim = spec.limits
    plan = plan_orbit(OrbitParams(alt_min_m=lim.floor_m + lim.margin_m,
                                  alt_max_m=lim.ceiling_m - lim.margin_m - 5.0))  # fmt: skip
    ap = make_autopilot("fixedwing", seed=0)
    ap.start_in_air(plan.altitude_m, 24.0, 0.0)
    assert ap.set_param("NAV_LOITER_RAD", plan.radius_m).ok
    team_plan = draw_plan("lateral", np.random.default_rng(0), 3)
    team = Formation(
        draw_plan("lateral", np.random.default_rng(0), 3).__class__(
            **{**team_plan.__dict__, "speed": 3.0, "heading0": 0.0, "weave_amp": 0.0}
        )
    )  # due north at 3 m/s, straight
    team.cn = 300.0
    events = Events()
    sv = Supervisor(spec.envelope(), SupervisorParams(**sup), events)
    rig = CameraRig(ORBIT_CAMERA, 3, CameraRigParams("fast", 5.0))
    reserve = fence_reserve(spec)
    assert 390.0 < reserve < 410.0  # 10 m + 2·189 m + 0.52 s·28 m/s
    comp = OrbitCompanion(plan, team, sv, rig, reserve)
    state = ap.state
    north_max, t_end = -math.inf, 300.0
    while state.t < t_end:
        d = comp.update(state.t, state)
        if comp.wants_hold:
            if ap.mode is not FlightMode.HOLD:
                ap.set_mode(FlightMode.HOLD)
        else:
            pos, vel, yaw = comp.setpoint()
            assert ap.set_offboard_setpoint(Setpoint(pos_ned=pos, vel_ned=vel, yaw=yaw)).ok
            if ap.mode is not FlightMode.OFFBOARD:
                assert ap.set_mode(FlightMode.OFFBOARD).ok, d.reason
        for _ in range(5):  # 0.1 s per companion update
            ap.step()
            state = ap.state
        north_max = max(north_max, float(state.pos_ned[0]))
    # the team drove on to ~1200 m north; the orbit centre stopped where its circle still
    # certifies (R + reserve inside the field edge at 1000 m), and so did the aircraft
    assert team.cn > 1150.0
    assert comp.limited > 500
    assert circle_certified(sv.geometry, comp.centre, plan.radius_m, plan.altitude_m, lim.margin_m)
    assert (
        1000.0 - plan.radius_m - reserve - 1.0 < comp.centre[0] <= 1000.0 - plan.radius_m - reserve
    )
    assert north_max < 1000.0 - lim.margin_m
    # no safety-net switch: the frozen orbit keeps the envelope's own fence reserve
    assert sv.stats.switches == 0 and not events.records
    # the gimbal keeps pointing at the departing team: its depression is atan(h / distance)
    last = comp.samples[-1]
    dist = float(np.hypot(*(last.centre_ne - last.pos_ned[:2])))
    assert dist > 450.0
    assert last.tilt_rad == pytest.approx(math.atan2(-last.pos_ned[2], dist), abs=1e-9)
    early = [s for s in comp.samples if 60.0 < s.t < 100.0]
    assert np.mean([s.all_detected for s in early]) >= 0.9
