"""Issue 27 for the formation: `skyherd fly --mission formation` signs every MAVLink link of every
vehicle with the run's key (both links of each vehicle, each of the companion's K links), and a
hostile local process without the key (tests/attacker.py, a real process on loopback) cannot
take one vehicle of the fleet; with `--no-signing` the same attack works (so the test can fail).
The formation publishes nothing on Zenoh (its simulators run `--ugvs none`, its companion has no
camera): MAVLink is all there is to sign. Lockstep at speed-up 0: nothing depends on load."""

from __future__ import annotations

import json
import re
from pathlib import Path

import pytest

from skyherd.scripts.cli import main
from tests.e2e.test_attack_mavlink import assert_per_run_key, attacked_flight

INSTANCE, ZENOH_PORT = 100, 7547  # vehicles 100..103
PLAN = [[[1, 5], [2, 5], [2, 6]], [[1, 2], [2, 2], [2, 3]], [[2, 1], [3, 1], [4, 1]],
        [[5, 1], [6, 1], [6, 2]]]  # fmt: skip
SAME = ["decisions.jsonl", "events.jsonl", "metrics.csv"] + [f"uav{k}/world.csv" for k in range(4)]


def _plan(tmp_path: Path) -> str:
    f = tmp_path / "plan_K4.json"
    f.write_text(json.dumps(PLAN))
    return str(f)


def _formation(tmp_path: Path) -> tuple[str, ...]:
    return ("--mission", "formation", "--agents", "4", "--policy-file", _plan(tmp_path))


def _json(path: Path) -> dict:
    return json.loads(path.read_text())


def assert_signed_fleet(rc: int, run: Path) -> dict:
    """Completed, judged, and every link of every vehicle signed with the run's key."""
    summary = assert_per_run_key(rc, run)
    judged = re.findall(r"^\| uav\d +\| (\S+) +\|", summary, re.M)
    assert judged == ["completed"] * 4, summary  # safety/judge.py, each vehicle
    comp = _json(run / "companion.json")
    assert comp["outcome"] == "completed" and comp["yielded"] == {}
    assert comp["mavlink"]["signed"] is True
    for k in range(4):
        assert _json(run / f"uav{k}" / "sim_stats.json")["mavlink_signing"]["on"] is True
    return comp


@pytest.mark.slow
def test_a_spoofed_heartbeat_takes_one_vehicle_of_an_unsigned_formation_only(tmp_path):
    victim = INSTANCE + 1  # uav1: AUTO.LAND heartbeats to its companion port
    rc, run, _ = attacked_flight(tmp_path / "signed", "heartbeat", *_formation(tmp_path),
                                 instance=INSTANCE, zenoh_port=ZENOH_PORT, target=victim)  # fmt: skip
    comp = assert_signed_fleet(rc, run)
    assert comp["mavlink"]["rejected"]["uav1"] > 0  # it came, it was refused
    assert comp["mavlink"]["rejected"]["uav0"] == 0
    rc, run, _ = attacked_flight(tmp_path / "unsigned", "heartbeat", "--no-signing",
                                 *_formation(tmp_path), instance=INSTANCE,
                                 zenoh_port=ZENOH_PORT, target=victim)  # fmt: skip
    assert _json(run / "config.json")["signing"] == "off (--no-signing)"
    assert "MAVLink signing: off (--no-signing)." in (run / "summary.md").read_text()
    assert not (run / "signing.key").exists()
    comp = _json(run / "companion.json")
    assert comp["mavlink"]["signed"] is False
    # the forged autopilot took uav1's link (the companion believed its frames, and its
    # replies went to the attacker): the flight does not complete
    assert rc != 0 and comp["outcome"] != "completed", comp


@pytest.mark.slow
def test_a_forced_disarm_of_a_signed_formation_vehicle_changes_no_byte_of_the_flight(tmp_path):
    """The signed, attacked formation flies byte for byte as an unsigned one nobody attacks:
    signing changes nothing in the flight and the refused DISARMs reach nothing."""
    victim = INSTANCE + 2  # uav2: force-DISARM on its ground-station port
    rc, run, report = attacked_flight(tmp_path / "signed", "disarm", *_formation(tmp_path),
                                      instance=INSTANCE, zenoh_port=ZENOH_PORT, target=victim)  # fmt: skip
    assert_signed_fleet(rc, run)
    assert not any(k.startswith("COMMAND_ACK") for k in report["replies"]), report
    signing = _json(run / "uav2" / "sim_stats.json")["mavlink_signing"]
    assert signing["rejected_unsigned"] > 0, signing
    plain = tmp_path / "plain"
    assert main(["fly", *_formation(tmp_path), "--no-signing", "--speedup", "0", "--instance",
                 str(INSTANCE), "--timeout", "900", "--runs-dir", str(plain)]) == 0  # fmt: skip
    (other,) = plain.iterdir()
    for name in SAME:
        assert (run / name).read_bytes() == (other / name).read_bytes(), name
