"""What the net takes in and gives out: yaw, position setpoints, the per-decision record,
health from arrivals, the parameter guard, the GPS-glitch guard and envelope validation."""

import json
import math

import numpy as np
import pytest

from skyherd.flight.autopilot_api import FlightMode, Setpoint
from skyherd.flight.geo import GRAVITY
from skyherd.flight.multirotor.params import MULTIROTOR_PARAMS
from skyherd.flight.state import VehicleState
from skyherd.safety.config import EnvelopeFileError, default_envelope_path, load_envelope
from skyherd.safety.consistency import ParamGuard, check_params
from skyherd.safety.health import HealthTracker
from skyherd.safety.net import load_net
from skyherd.safety.supervisor import Health, Mode, Severity, Supervisor, SupervisorParams

SPEC, _ = load_envelope(default_envelope_path("quadrotor"))
FW, _ = load_envelope(default_envelope_path("fixedwing"))


def st(t, p=(0.0, 0.0, -20.0), v=(0.0, 0.0, 0.0)):
    return VehicleState(t, np.array(p, float), np.array(v, float), np.array([1.0, 0, 0, 0]),
                        np.zeros(3), np.array([0, 0, -GRAVITY]), False)  # fmt: skip


def test_yaw_is_kept_accepted_and_projected():
    sup = Supervisor(SPEC.envelope(), SupervisorParams(intervention="project"))
    d = sup.update(0.0, st(0.0), Setpoint(vel_ned=np.array([1.0, 0, 0]), yaw=0.7, yaw_rate=0.1))
    assert d.mode is Mode.AI and d.command.yaw == 0.7 and d.command.yaw_rate == 0.1
    # a too-sharp step is projected: the velocity changes, the heading stays the AI's
    d = sup.update(0.02, st(0.02), Setpoint(vel_ned=np.array([0.0, 6.0, 0]), yaw=-1.2))
    assert d.severity is Severity.PROJECTED and d.command.yaw == -1.2
    assert not np.allclose(d.command.vel_ned, [0, 6, 0])


def test_non_finite_yaw_is_a_bad_action():
    sup = Supervisor(SPEC.envelope())
    d = sup.update(0.0, st(0.0), Setpoint(vel_ned=np.zeros(3), yaw=math.nan))
    assert d.mode is Mode.FALLBACK and d.reason == "non-finite action (yaw nan)"


def test_position_setpoint_is_certified_by_the_motion_it_implies():
    sup = Supervisor(SPEC.envelope())
    # 1 m ahead: implied 0.95 m/s north, inside: flown as the AI's position setpoint
    sp = Setpoint(pos_ned=np.array([1.0, 0, -20]), vel_ned=np.zeros(3), yaw=0.3)
    d = sup.update(0.0, st(0.0), sp)
    assert (
        d.mode is Mode.AI and np.allclose(d.command.pos_ned, [1, 0, -20]) and d.command.yaw == 0.3
    )
    assert np.allclose(sup.last_u, [0.95, 0, 0])
    # a far target implies the autopilot's 12 m/s: beyond the 8 m/s envelope → fallback
    d = sup.update(0.02, st(0.02), Setpoint(pos_ned=np.array([60.0, 0, -20])))
    assert d.mode is Mode.FALLBACK and np.allclose(sup.last_u, [12.0, 0, 0])


def test_fixedwing_position_setpoint_implies_a_bank_limited_turn():
    sup = Supervisor(FW.envelope())
    s = st(0.0, (0.0, 0.0, -100.0), (24.0, 0.0, 0.0))
    u = sup.implied_velocity(s, Setpoint(pos_ned=np.array([-800.0, 0.0, -100.0])))
    # the loiter centre is behind: the course turns by at most tau g tan(bank) / V
    step = 3.0 * GRAVITY * math.tan(0.40) / 24.0
    assert math.isclose(abs(math.atan2(u[1], u[0])), step, rel_tol=1e-6)
    assert math.isclose(float(np.hypot(u[0], u[1])), 24.0)


def test_decision_record_has_the_layout_fields():
    sup = Supervisor(SPEC.envelope())
    d = sup.update(1.0, st(1.0, (74, 0, -20), (3, 0, 0)), Setpoint(vel_ned=np.array([3.0, 0, 0])))
    rec = d.record(
        vehicle="uav0", pilot="policy", phi=np.zeros(8), autopilot_mode=FlightMode.OFFBOARD
    )
    assert set(rec) == {"t", "vehicle", "pilot", "phi", "proposed", "certified", "verdict",
                        "reason", "mode", "autopilot_mode"}  # fmt: skip
    assert rec["verdict"] == "fallback" and rec["reason"] == "field edge 2" and rec["t"] == 1.0
    assert rec["proposed"]["vel_ned"] == [3.0, 0.0, 0.0] and rec["certified"]["vel_ned"] == [
        0,
        0,
        0,
    ]
    json.dumps(rec, allow_nan=False)  # valid JSON
    d = sup.update(1.02, st(1.02), Setpoint(vel_ned=np.array([math.nan, 0, 0])))
    json.dumps(d.record(), allow_nan=False)


def test_health_tracker_from_arrivals():
    h = HealthTracker()
    assert (h.camera_t, h.link_t) == (None, None)
    h.message(1.0, "HEARTBEAT")
    assert h.link_t == 1.0  # telemetry not yet: as old as the first arrival
    for k in range(20):
        h.message(1.0 + 0.1 * k, "LOCAL_POSITION_NED")
    h.message(2.0, "HEARTBEAT")
    assert h.link_t == 2.0  # the older of heartbeat (2.0) and telemetry (2.9)
    h.frame(2.5, stamp_t=2.45)
    h.frame(2.6, stamp_t=1.0)  # a frame captured 1.6 s before it arrived: stale
    h.message(float("nan"), "HEARTBEAT")
    h.message(1.5, "HEARTBEAT")  # backwards
    assert h.camera_t == 2.5 and h.stale_frames == 1 and h.rejected == 2
    sup = Supervisor(SPEC.envelope())
    d = sup.update(4.0, st(4.0), Setpoint(vel_ned=np.zeros(3)), Health(h.camera_t, h.link_t))
    assert d.mode is Mode.FALLBACK and d.reason == "MAVLink link lost (2.0 s)"


DEFAULTS = {p.name: p.default for p in MULTIROTOR_PARAMS}


def test_parameter_sabotage_is_refused_with_the_reason():
    assert check_params(SPEC, DEFAULTS) == {}
    sink = []
    g = ParamGuard(SPEC, events=type("S", (), {"write": lambda self, r: sink.append(r)})())
    assert g.load(0.0, DEFAULTS) == "" and g.handover() == (True, "")
    fault = g.update(12.0, "COM_OF_LOSS_T", 3.0)
    assert "COM_OF_LOSS_T = 3 s" in fault and "21.8 m" in fault and "<= 0.53 s" in fault
    assert g.handover()[0] is False
    sup = Supervisor(SPEC.envelope())
    d = sup.update(12.0, st(12.0), Setpoint(vel_ned=np.zeros(3)), Health(params_fault=fault))
    assert d.mode is Mode.FALLBACK and d.reason.startswith("autopilot parameters: COM_OF_LOSS_T")
    assert g.update(20.0, "COM_OF_LOSS_T", 0.5) == ""
    assert [r["consistent"] for r in sink] == [False, True]
    bad = check_params(SPEC, {**DEFAULTS, "MPC_TILTMAX_AIR": 10.0, "MPC_XY_VEL_MAX": 20.0})
    assert set(bad) == {"MPC_TILTMAX_AIR", "MPC_XY_VEL_MAX"}
    ardu = check_params(SPEC, {"GUID_TIMEOUT": 3.0, "ANGLE_MAX": 4500, "WPNAV_SPEED": 500})
    assert set(ardu) == {"GUID_TIMEOUT"}
    fw = check_params(FW, {"COM_OF_LOSS_T": 0.5, "NAV_LOITER_RAD": 400.0, "FW_R_LIM": 20.0})
    assert set(fw) == {"NAV_LOITER_RAD", "FW_R_LIM"}


def test_gps_glitch_toward_the_inside_is_a_position_fault():
    sup = Supervisor(SPEC.envelope(), SupervisorParams(gps_jump_m=3.0))
    t, p = 0.0, np.array([50.0, 0.0, -20.0])
    for _ in range(50):
        d = sup.update(t, st(t, p, (2, 0, 0)), Setpoint(vel_ned=np.array([2.0, 0, 0])))
        t, p = t + 0.02, p + [0.04, 0, 0]
    assert d.mode is Mode.AI
    d = sup.update(t, st(t, p - [20.0, 0, 0], (2, 0, 0)), Setpoint(vel_ned=np.array([2.0, 0, 0])))
    assert d.mode is Mode.FALLBACK and d.reason.startswith("position jumped 20.0 m")
    for _ in range(200):  # still glitched: the fault lasts
        t, p = t + 0.02, p
        d = sup.update(t, st(t, p - [20.0, 0, 0]), Setpoint(vel_ned=np.zeros(3)))
    assert d.mode is not Mode.AI and sup.position_suspect


@pytest.mark.parametrize(
    "patch, msg",
    [
        ("react_s = 0.3", "react_s = 0.0"),
        ("margin_m = 2.0", "margin_m = -1.0"),
        ("speed_h_mps = 8.0", "speed_h_mps = 800.0"),
        ("margin_m = 2.0", "margin_m = 90.0"),
        ("tau_s = 0.5", "tau_s = 0.001"),
    ],
)
def test_envelope_values_are_validated_naming_the_key(tmp_path, patch, msg):
    text = default_envelope_path("quadrotor").read_text().replace(patch, msg, 1)
    f = tmp_path / "bad.toml"
    f.write_text(text)
    with pytest.raises(EnvelopeFileError) as e:
        load_envelope(f)
    key = msg.split(" =")[0]
    line = str(e.value)
    assert "\n" not in line and key in line and str(f) in line


def test_load_net_uses_the_gps_guard_of_the_file():
    assert load_net("quadrotor").p.gps_jump_m > 0 and load_net("fixedwing").p.gps_jump_m > 0
