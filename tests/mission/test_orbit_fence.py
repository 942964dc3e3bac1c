"""The production orbit (mission/orbit.py OrbitMission) against the fence: a UGV team that
drives out of the field must not drag the orbit across it. The team's centre as the camera
would see it (TeamSight.centre) moves due north at 3 m/s from 300 m; at every decision the
mission moves its orbit centre toward it only as far as the circle still certifies
(hil.orbit.circle_certified with fence_reserve), so it stops short of the field edge."""

import numpy as np

from skyherd.mission.flight import Record
from skyherd.mission.orbit import Briefing, OrbitFlight, OrbitMission
from skyherd.mission.orbit_plan import OrbitParams, circle_certified, fence_reserve, plan_orbit
from skyherd.safety.config import ENVELOPE_DIR
from skyherd.safety.net import SafetyNet


def test_team_driving_out_of_the_field_freezes_the_orbit_inside_the_fence():
    net = SafetyNet.load("fixedwing", ENVELOPE_DIR / "fixedwing_field.toml")
    spec = net.envelope.spec
    lim = spec.limits
    band = (lim.floor_m + lim.margin_m, lim.ceiling_m - lim.margin_m - 15.0)
    reserve = fence_reserve(spec)
    assert 390.0 < reserve < 410.0  # 10 m + 2·189 m + 0.52 s·28 m/s
    flight = OrbitFlight()
    mission = OrbitMission(
        net, flight, Briefing((300.0, 0.0), 3.0, 20.0, 3), Record(), reserve, band
    )
    mission.plan = plan_orbit(OrbitParams(alt_min_m=band[0], alt_max_m=band[1]))
    R, h = mission.plan.radius_m, mission.plan.altitude_m
    norths = []
    for t in np.arange(0.0, 300.0, flight.decision_s):
        mission.sight.centre = np.array([300.0 + 3.0 * t, 0.0])  # the team, as seen
        mission._move_centre()
        norths.append(mission.centre[0])
    # the team drove on to ~1200 m north; the orbit centre stopped where its circle still
    # certifies (R + reserve inside the field edge at 1000 m)
    assert mission.sight.centre[0] > 1150.0
    assert mission.limited > 500
    assert circle_certified(net.supervisor.geometry, mission.centre, R, h, reserve, lim.margin_m)
    assert 1000.0 - R - reserve - 1.0 < mission.centre[0] <= 1000.0 - R - reserve
    assert np.all(np.diff(norths) >= -1e-9)  # it followed the team up to there, never back
    assert norths[10] == 300.0 + 3.0 * 10 * flight.decision_s  # unhindered before the edge
