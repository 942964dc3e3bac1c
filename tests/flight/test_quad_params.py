"""The typed parameter store (flight/params.py) and the multirotor's parameter set."""

import pytest

from skyherd.flight.multirotor import MultirotorAutopilot
from skyherd.flight.multirotor.params import MULTIROTOR_PARAMS
from skyherd.flight.params import ParamSpec, ParamStore


def test_store_ranges_order_and_revision():
    store = ParamStore([ParamSpec("A_P", 1.0, 0.0, 2.0, "a"), ParamSpec("B_P", 5.0, 1.0, 9.0, "b")])
    assert store.names() == ["A_P", "B_P"] and store["A_P"] == 1.0
    rev = store.revision
    assert store.set("A_P", 1.5).ok and store.get("A_P") == 1.5 and store.revision == rev + 1
    for bad in (2.5, float("nan"), float("inf"), "x", None):
        r = store.set("A_P", bad)
        assert not r.ok and r.reason
    assert store.get("A_P") == 1.5 and store.revision == rev + 1
    assert store.get("NOPE") is None and not store.set("NOPE", 1).ok
    with pytest.raises(ValueError):
        ParamSpec("THIS_NAME_IS_TOO_LONG", 0, 0, 1, "x")
    with pytest.raises(ValueError):
        ParamSpec("X", 3, 0, 1, "default outside range")
    with pytest.raises(ValueError):
        ParamStore([ParamSpec("X", 0, 0, 1, "x"), ParamSpec("X", 0, 0, 1, "x")])


def test_toml_round_trip_and_bad_files(tmp_path):
    store = ParamStore(MULTIROTOR_PARAMS)
    assert store.set("MPC_XY_CRUISE", 7.5).ok
    f = tmp_path / "p.toml"
    f.write_text(store.dumps_toml())
    other = ParamStore(MULTIROTOR_PARAMS)
    other.load_toml(f)
    assert other.as_dict() == store.as_dict()
    f.write_text("[params]\nMPC_XY_CRUISE = 1e9\nMPC_Z_P = 2.0\n")
    with pytest.raises(ValueError, match="MPC_XY_CRUISE"):
        other.load_toml(f)
    assert other["MPC_Z_P"] == store["MPC_Z_P"]  # nothing applied
    f.write_text("[params\n")
    with pytest.raises(ValueError, match="cannot read"):
        other.load_toml(f)


def test_autopilot_reads_params_file_and_live_changes(tmp_path):
    f = tmp_path / "ap.toml"
    f.write_text("[params]\nMIS_TAKEOFF_ALT = 4.0\nMPC_TKO_SPEED = 2.0\n")
    ap = MultirotorAutopilot(params_file=f)
    assert ap.get_param("MIS_TAKEOFF_ALT") == 4.0
    assert len(ap.param_names()) == len(MULTIROTOR_PARAMS)
    assert all(len(n) <= 16 for n in ap.param_names())
    ap.arm()
    ap.takeoff()
    vz = []
    for _ in range(750):
        ap.step()
        vz.append(ap.state.vel_ned[2])
    assert min(vz) == pytest.approx(-2.0, abs=0.15)  # climbs at MPC_TKO_SPEED
    assert ap.set_param("MPC_Z_VEL_MAX_UP", 1.0).ok
    for _ in range(3000):
        ap.step()
    assert ap.state.pos_ned[2] == pytest.approx(-4.0, abs=0.1)


def test_each_airframes_table_without_its_autopilot_and_the_close_names():
    """flight.airframes_registry.param_store: the table `skyherd sim --param` is checked against
    before any autopilot exists; close_names: its "did you mean"."""
    from skyherd.flight.airframes_registry import AirframeUnavailable, param_store
    from skyherd.flight.fixedwing.fw_params import FW_PARAM_SPECS

    quad = param_store("quadrotor")
    assert quad.names() == [s.name for s in MULTIROTOR_PARAMS]
    assert quad.as_dict() == ParamStore(MULTIROTOR_PARAMS).as_dict()  # at the defaults
    assert param_store("fixedwing").names() == [s.name for s in FW_PARAM_SPECS]
    with pytest.raises(AirframeUnavailable):
        param_store("blimp")
    assert quad.close_names("com_of_los_t")[0] == "COM_OF_LOSS_T"  # any case
    assert quad.close_names("ZZZZZZZZ") == []
