"""How a flight is signed (flight.mavlink.signing.FlightSigning) and the autopilot's --param
items (flight.params), without a command line."""

from __future__ import annotations

import stat

import pytest

from skyherd.flight.airframes_registry import param_store
from skyherd.flight.mavlink.signing import KEY_LEN, FlightSigning, load_key
from skyherd.flight.params import check_assignments


def test_per_run_key_only_for_the_built_in_vehicle(tmp_path):
    key = FlightSigning().per_run_key(tmp_path)
    assert key == tmp_path / "signing.key" and len(load_key(key)) == KEY_LEN
    assert stat.S_IMODE(key.stat().st_mode) == 0o600
    assert FlightSigning().mode() == "on (per-run key)"
    assert FlightSigning(off=True).per_run_key(tmp_path / "a") is None
    assert FlightSigning(outside=True).per_run_key(tmp_path / "b") is None
    assert FlightSigning(key_file=str(key)).checked_key_file() == str(key.resolve())
    assert FlightSigning(key_file=str(key)).mode() == f"key file {key.resolve()}"


@pytest.mark.parametrize(
    "signing, said",
    [
        (FlightSigning(key_file="k", off=True), "contradict each other"),
        (FlightSigning(setup=True, key_file="k"), "--setup-signing gives an outside autopilot"),
        (FlightSigning(key_file="/nonexistent/k"), "--signing-key: cannot read signing key"),
    ],
)
def test_signing_refusals_name_the_option(signing, said):
    with pytest.raises(ValueError) as e:
        signing.checked_key_file()
    assert said in str(e.value)


def test_param_items_checked_against_the_table():
    store = param_store("quadrotor")
    check_assignments(store, ["COM_OF_LOSS_T=3"], "quadrotor")
    with pytest.raises(ValueError, match="expected NAME=VALUE"):
        check_assignments(store, ["COM_OF_LOSS_T"], "quadrotor")
    with pytest.raises(ValueError, match="'abc' is not a number"):
        check_assignments(store, ["COM_OF_LOSS_T=abc"], "quadrotor")
