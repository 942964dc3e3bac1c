"""Every formation setpoint goes through a safety net: its own supervisor per vehicle, the
fence around the plan and the other vehicles' positions as separation rows (issue 11.1)."""

import numpy as np

from flight.autopilot_api import FlightMode
from hil.client import Telemetry
from hil.formation import FormationParams, FormationVehicle, TrackRecorder, formation_envelope
from safety.supervisor import Mode, Supervisor, SupervisorParams


class Client:
    """What FormationVehicle needs of a VehicleClient: its telemetry and the stream hook."""

    def __init__(self):
        self.telemetry = Telemetry()
        self.fn = None

    def stream_offboard(self, fn):
        self.fn = fn


def tel_at(t, pos, vel=(0.0, 0.0, 0.0)):
    tel = Telemetry(time_boot_ms=int(round(t * 1000)), mode=FlightMode.OFFBOARD, armed=True)
    tel.pos_ned, tel.vel_ned = np.array(pos, float), np.array(vel, float)
    tel.quat, tel.omega_frd = np.array([1.0, 0, 0, 0]), np.zeros(3)
    return tel


def vehicles(paths, params=None):
    params = params or FormationParams()
    vs = []
    for k, path in enumerate(paths):
        c = Client()
        v = FormationVehicle(k, c, path[0], params.altitude(k), np.array(path, float),
                             params.step_s, TrackRecorder(None, len(paths)))  # fmt: skip
        vs.append(v)
    spec = formation_envelope([v.path_ne for v in vs], params)
    for v in vs:
        sup = Supervisor(spec.envelope(), SupervisorParams(hysteresis_s=1.0, hold_min_s=0.5))
        v.attach_net(sup, [w for w in vs if w is not v])
    return vs, spec


def test_plan_setpoint_is_certified_and_flown_as_planned():
    vs, spec = vehicles([[(0.0, 0.0), (0.0, 2.0)], [(10.0, 0.0), (10.0, 2.0)]])
    v0, v1 = vs
    v1.tel.pos_ned, v1.tel.vel_ned = np.array([0.0, 0.0, -9.5]), np.zeros(3)  # own frame
    tel = tel_at(0.0, (0.0, 0.0, -8.0))
    pos, vel, yaw = v0.certify(0.0, tel, np.array([0.0, 1.0, -8.0]), np.array([0.0, 1.0, 0.0]))
    d = v0.last_decision
    assert d.mode is Mode.AI and d.verdict == "accepted"
    assert np.allclose(pos, [0, 1, -8]) and np.allclose(vel, [0, 1, 0]) and yaw == 0.0
    rec = d.record(vehicle="uav0", pilot="formation")
    assert rec["proposed"]["pos_ned"] == [0.0, 1.0, -8.0] and rec["certified"]["yaw"] == 0.0
    assert spec.inclusions[0].points.min() == -10.0  # bounding box + 10 m


def test_setpoint_toward_another_vehicle_is_refused_by_the_separation_row():
    vs, _ = vehicles([[(0.0, 0.0), (0.0, 2.0)], [(0.0, 4.0), (0.0, 6.0)]])
    v0, v1 = vs
    # vehicle 1 hovers 3 m east of vehicle 0 at the same altitude (field frame (0, 3))
    v1.tel.pos_ned, v1.tel.vel_ned = np.array([0.0, -1.0, -8.0]), np.zeros(3)
    tel = tel_at(0.0, (0.0, 0.0, -8.0), (0.0, 1.5, 0.0))
    pos, vel, _ = v0.certify(0.0, tel, np.array([0.0, 3.0, -8.0]), np.array([0.0, 2.0, 0.0]))
    d = v0.last_decision
    assert d.mode is Mode.FALLBACK and d.reason == "separation 1 m from uav1"
    assert pos is None and np.allclose(vel, 0)  # brake (flown in OFFBOARD)


def test_setpoint_outside_the_formation_fence_is_refused():
    vs, _ = vehicles([[(0.0, 0.0), (0.0, 2.0)]])
    (v0,) = vs
    tel = tel_at(0.0, (0.0, 8.0, -8.0), (0.0, 2.0, 0.0))  # 4 m from the fence, 2 m/s at it
    v0.certify(0.0, tel, np.array([0.0, 9.0, -8.0]), np.array([0.0, 2.0, 0.0]))
    assert (
        v0.last_decision.mode is Mode.FALLBACK and "formation field edge" in v0.last_decision.reason
    )
