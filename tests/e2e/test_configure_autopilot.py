"""`--configure-autopilot` (mission/configure.py, safety.consistency.required_values): the values
that make stock parameters agree with the envelope, and through `skyherd fly` on the built-in
vehicle: refused without the flag (naming the parameter, the value and the flag), set, read back,
recorded and flown with it. Real stock PX4 / ArduCopter: tests/e2e/test_autopilots_real.py (opt-in)."""

import json

import pytest

from skyherd.safety.consistency import check_params, required_values
from skyherd.safety.net import load_net
from skyherd.scripts.cli import main

STOCK = {  # the values that break a rule of the ground-air / orbit envelopes
    "px4": {"COM_OF_LOSS_T": 1.0, "MPC_XY_VEL_MAX": 20.0, "MPC_TILTMAX_AIR": 10.0, "MPC_ACC_HOR": 1.0},
    "arducopter": {"GUID_TIMEOUT": 3.0, "WPNAV_SPEED": 2000.0, "ANGLE_MAX": 1000.0,
                   "LOIT_BRK_ACCEL": 100.0},
    "arduplane": {"TECS_CLMB_MAX": 5.0, "TECS_SINK_MAX": 5.0, "ROLL_LIMIT_DEG": 65.0,
                  "WP_LOITER_RAD": 400.0},
}  # fmt: skip


@pytest.mark.parametrize("autopilot", sorted(STOCK))
def test_the_required_values_make_every_checked_parameter_agree(autopilot):
    net = load_net("fixedwing" if autopilot == "arduplane" else "quadrotor")
    spec, vmax = net.envelope.spec, net.p.pos_speed_max_mps
    params = STOCK[autopilot]
    assert set(check_params(spec, params, vmax)) == set(params)  # each one breaks a rule
    fix = required_values(spec, params, vmax)
    assert set(fix) == set(params)
    assert check_params(spec, {**params, **fix}, vmax) == {}
    assert required_values(spec, {**params, **fix}, vmax) == {}  # nothing more to set
    for name, value in fix.items():  # rounded to the safe side, never past the limit it reads
        if name in ("COM_OF_LOSS_T", "GUID_TIMEOUT"):
            assert value <= 0.53 and check_params(spec, {name: value + 0.01}, vmax)


def test_a_nan_or_an_int32_parameter_is_left_to_the_operator():
    spec = load_net("quadrotor").envelope.spec
    params = {"COM_OF_LOSS_T": float("nan"), "COM_OBL_RC_ACT": 1.0}
    assert set(check_params(spec, params)) == set(params)
    assert required_values(spec, params) == {}


@pytest.mark.slow
def test_fly_refuses_stock_parameters_and_configures_them_when_asked(tmp_path):
    base = ["fly", "--speedup", "0", "--duration", "10", "--param", "COM_OF_LOSS_T=1",
            "--param", "MPC_XY_VEL_MAX=20", "--instance", "35", "--zenoh-port", "7435"]  # fmt: skip
    assert main([*base, "--runs-dir", str(tmp_path / "a")]) == 1
    (run,) = (tmp_path / "a").iterdir()
    comp = json.loads((run / "companion.json").read_text())
    assert comp["outcome"] == "aborted" and comp["decisions"] == 0 and comp["configured"] == []
    assert "COM_OF_LOSS_T <= 0.53 s" in comp["reason"] and "--configure-autopilot" in comp["reason"]
    assert main([*base, "--configure-autopilot", "--runs-dir", str(tmp_path / "b")]) == 0
    (run,) = (tmp_path / "b").iterdir()
    comp = json.loads((run / "companion.json").read_text())
    got = {c["name"]: (c["before"], c["after"]) for c in comp["configured"]}
    assert got == {"COM_OF_LOSS_T": (1.0, 0.53), "MPC_XY_VEL_MAX": (20.0, 12.0)}
    assert comp["outcome"] == "completed" and comp["decisions"] >= 15
    summary = (run / "summary.md").read_text()
    assert "Autopilot parameters set (--configure-autopilot" in summary
    assert "| COM_OF_LOSS_T  | 1      | 0.53  |" in summary
    events = [json.loads(x) for x in (run / "events.jsonl").read_text().splitlines()]
    params = [e for e in events if e.get("event") == "params"]
    assert params and params[-1]["consistent"]  # the guard saw the echoes and agreed
