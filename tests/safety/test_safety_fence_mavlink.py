"""A geofence uploaded over real MAVLink (UDP, 127.0.0.1) becomes the safety net's envelope."""

import numpy as np
import pytest
from pymavlink.dialects.v20 import ardupilotmega as M

from skyherd.flight.autopilot_api import Setpoint
from skyherd.flight.frames import euler_to_quat
from skyherd.flight.geo import ned_to_geodetic
from skyherd.flight.state import VehicleState
from skyherd.safety.config import default_envelope_path, load_envelope
from skyherd.safety.fence import envelope_from_fence_items
from skyherd.safety.supervisor import Mode, Supervisor
from tests.mavlink_support import Client, running_sitl

BASE, _ = load_envelope(default_envelope_path("quadrotor"))
INSTANCE = 41  # ports 14621 / 18611: away from the other suites' instances


def test_uploaded_l_shaped_fence_drives_the_supervisor():
    with running_sitl(instance=INSTANCE, speedup=10.0) as sitl, Client(INSTANCE) as c:
        c.wait_heartbeat()
        home = sitl.autopilot.home

        def ll(n, e):
            lat, lon, _ = ned_to_geodetic(home, np.array([n, e, 0.0]))
            return int(round(lat * 1e7)), int(round(lon * 1e7))

        l_shape = [(0, 0), (60, 0), (60, 20), (20, 20), (20, 60), (0, 60)]  # non-convex
        fence = [(M.MAV_FRAME_GLOBAL, 5001, 6, 0, 0, 0, *ll(n, e), 0.0) for n, e in l_shape]
        fence.append((M.MAV_FRAME_GLOBAL, 5004, 4.0, 0, 0, 0, *ll(10, 10), 0.0))
        assert c.mission_upload(fence, mission_type=1).type == M.MAV_MISSION_ACCEPTED
        stored = sitl.endpoint.missions.lists[1]
        spec = envelope_from_fence_items(stored, home, BASE)

    assert spec.version.startswith(BASE.version + "+fence-")
    env, geo = spec.envelope(), spec.geometry()
    assert len(env.piece_starts) >= 2  # split into convex pieces
    # geometry of the L (1e-7 deg ≈ 1 cm of rounding)
    assert geo.distance_outside(np.array([40.0, 40.0, -20])) == pytest.approx(
        20.0, abs=0.05
    )  # in the notch
    assert geo.distance_outside(np.array([50.0, 10.0, -20])) <= -9.9  # in the long arm
    assert geo.distance_outside(np.array([10.0, 10.0, -20])) == pytest.approx(
        4.0, abs=0.05
    )  # no-fly circle
    # The supervisor flies the uploaded fence: flying into the notch falls back, naming an edge
    sup = Supervisor(env)
    q = euler_to_quat(0, 0, 0)
    s = VehicleState(
        0.0,
        np.array([14.0, 40.0, -20.0]),
        np.array([3.0, 0, 0]),
        q,
        np.zeros(3),
        np.zeros(3),
        False,
    )
    d = sup.update(0.0, s, Setpoint(vel_ned=np.array([3.0, 0.0, 0.0])))  # stop at 19.8 > 18
    assert d.mode is Mode.FALLBACK and "fence 1" in d.reason and "edge" in d.reason
    # the same state flying along the arm (east, toward the corner at 60) is fine
    s2 = VehicleState(
        0.0,
        np.array([10.0, 30.0, -20.0]),
        np.array([0.0, 2.0, 0]),
        q,
        np.zeros(3),
        np.zeros(3),
        False,
    )
    ok = Supervisor(env).update(0.0, s2, Setpoint(vel_ned=np.array([0.0, 2.5, 0.0])))
    assert ok.mode is Mode.AI and np.allclose(ok.command.vel_ned, [0.0, 2.5, 0.0])
