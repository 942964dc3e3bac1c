"""One address syntax (runio.address) and schema-checked configuration tables (runio.schema)."""

from __future__ import annotations

import dataclasses

import pytest

from skyherd.runio import AddressError, ConfigError, fill_dataclass, parse_address, validate_mapping


@pytest.mark.parametrize(
    "text, mavlink, zenoh",
    [
        ("tcp:127.0.0.1:7447", "tcp:127.0.0.1:7447", "tcp/127.0.0.1:7447"),
        ("tcp/127.0.0.1:7447", "tcp:127.0.0.1:7447", "tcp/127.0.0.1:7447"),
        ("udpin:127.0.0.1:14540", "udpin:127.0.0.1:14540", "udp/127.0.0.1:14540"),
        ("udpout:localhost:14550", "udpout:localhost:14550", "udp/localhost:14550"),
        ("tcpin:[::1]:5760", "tcpin:[::1]:5760", "tcp/[::1]:5760"),
    ],
)
def test_addresses_in_both_forms(text, mavlink, zenoh):
    a = parse_address(text)
    assert a.mavlink == mavlink and a.zenoh == zenoh


def test_serial_devices():
    a = parse_address("/dev/ttyACM0,57600")
    assert a.mavlink == "/dev/ttyACM0,57600" and a.baud == 57600
    with pytest.raises(AddressError, match="not a Zenoh endpoint"):
        _ = a.zenoh


@pytest.mark.parametrize(
    "text, words",
    [
        ("", "empty address"),
        ("127.0.0.1:7447", "is not an address"),
        ("tcp:127.0.0.1", "needs HOST:PORT"),
        ("tcp:127.0.0.1:0", "port must be 1..65535"),
        ("tcp:127.0.0.1:70000", "port must be 1..65535"),
        ("tcp:bad host:1", "not a host name"),
        ("udpin/127.0.0.1:1", "Zenoh form"),
        ("/dev/ttyUSB0,fast", "baud rate"),
    ],
)
def test_bad_addresses_say_why_on_one_line(text, words):
    with pytest.raises(AddressError) as e:
        parse_address(text)
    assert words in str(e.value) and "\n" not in str(e.value)


@dataclasses.dataclass(frozen=True)
class Table:
    speed_mps: float = 8.0
    sides: int = 16
    enabled: bool = False
    name: str = "x"
    offset_m: tuple[float, float, float] = (0.0, 0.0, 0.1)


def test_fill_dataclass_takes_good_tables():
    t = fill_dataclass(Table, {"speed_mps": 5, "offset_m": [1, 2, 3]}, "limits")
    assert t == Table(speed_mps=5.0, offset_m=(1.0, 2.0, 3.0))


@pytest.mark.parametrize(
    "table, words",
    [
        ({"sped_mps": 1.0}, "[limits] unknown key 'sped_mps'; known: enabled, name, offset_m"),
        ({"speed_mps": "fast"}, "[limits] speed_mps must be a finite number, got 'fast'"),
        ({"speed_mps": float("inf")}, "[limits] speed_mps must be a finite number, got inf"),
        ({"sides": 3.5}, "[limits] sides must be an integer, got 3.5"),
        ({"sides": True}, "[limits] sides must be an integer, got True"),
        ({"enabled": 1}, "[limits] enabled must be true/false, got 1"),
        ({"offset_m": [1, 2]}, "[limits] offset_m.2 is missing an element"),
    ],
)
def test_fill_dataclass_errors_name_the_key(table, words):
    with pytest.raises(ConfigError) as e:
        fill_dataclass(Table, table, "limits")
    assert str(e.value).startswith(words) and "\n" not in str(e.value)


def test_validate_mapping_and_the_files_that_use_it(tmp_path):
    assert validate_mapping({"A": 1}, float, ["A", "B"], "params") == {"A": 1.0}
    with pytest.raises(ConfigError, match=r"\[params\] unknown key 'C'"):
        validate_mapping({"C": 1.0}, float, ["A", "B"], "params")
    from skyherd.flight.multirotor.params import MULTIROTOR_PARAMS
    from skyherd.flight.params import ParamStore

    f = tmp_path / "p.toml"
    f.write_text('[params]\nMPC_XY_CRUISE = "fast"\n')
    with pytest.raises(
        ValueError, match=r"p.toml: \[params\] MPC_XY_CRUISE must be a finite number"
    ):
        ParamStore(MULTIROTOR_PARAMS).load_toml(f)
