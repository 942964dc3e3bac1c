"""Issue 27: a default `skyherd fly` is signed, and a hostile local process without the key
(tests/attacker.py, a real process on loopback) cannot end, disarm, mislead or lock the
flight. Each attack runs twice: against the default flight (no effect) and against the same
flight with `--no-signing` (the attack works: so each test can fail).

The attacker repeats its attack from before the flight starts until the flight has ended, so
what it reaches does not depend on timing or load; the flights are short and lockstep
(--speedup 0)."""

from __future__ import annotations

import csv
import json
import re
import signal
import subprocess
import sys
from pathlib import Path

import pytest

HERE = Path(__file__).resolve().parents[1]  # tests/: attacker.py
ROOT = HERE.parent
ARM_DISARM = 400  # MAV_CMD_COMPONENT_ARM_DISARM
INSTANCE, ZENOH_PORT = 91, 7491  # signing helper: instances 91-95, ports 7491-7495


def attacked_flight(tmp_path: Path, attack: str, *fly_args: str, instance: int = INSTANCE,
                    zenoh_port: int = ZENOH_PORT, attacker_args=(),
                    target: int | None = None, record: bool = False) -> tuple[int, Path, dict]:  # fmt: skip
    """(exit code of `skyherd fly`, its run folder, the attacker's report). The attacker aims
    at vehicle instance `target` (default: the flight's `instance`); `record`: flight.mcap too."""
    runs = tmp_path / "runs"
    target = instance if target is None else target
    attacker = subprocess.Popen(
        [sys.executable, str(HERE / "attacker.py"), attack, "--instance", str(target),
         "--zenoh-port", str(zenoh_port), *attacker_args],
        stdout=subprocess.PIPE, text=True, cwd=ROOT,
    )  # fmt: skip
    try:
        fly = subprocess.run(
            [sys.executable, "-m", "skyherd.scripts.cli", "fly", "--duration", "4", "--speedup", "0",
             "--instance", str(instance), "--zenoh-port", str(zenoh_port),
             *(() if record else ("--no-record",)), "--runs-dir", str(runs), "--timeout", "900",
             *fly_args],
            cwd=ROOT, capture_output=True, text=True, timeout=1200,
        )  # fmt: skip
    finally:
        attacker.send_signal(signal.SIGTERM)
        try:
            out, _ = attacker.communicate(timeout=120)
        except subprocess.TimeoutExpired:
            attacker.kill()
            raise
    (run,) = runs.iterdir()
    report = json.loads(out.strip().splitlines()[-1])
    assert report["sent"] > 0, report
    return fly.returncode, run, report


def _json(path: Path) -> dict:
    return json.loads(path.read_text())


def judged_all_pass(run: Path) -> bool:
    summary = (run / "summary.md").read_text()
    judged = re.findall(r"^\| (\w+) +\| (pass|FAIL) +\|", summary, re.M)
    return bool(judged) and {r for _, r in judged} == {"pass"}


def assert_per_run_key(rc: int, run: Path) -> str:
    """Exit 0, and the run's own key, said in config.json and summary.md; the summary."""
    summary = (run / "summary.md").read_text()
    assert rc == 0, summary
    assert "MAVLink signing: on (per-run key)." in summary
    assert _json(run / "config.json")["signing"] == "on (per-run key)"
    key = run / "signing.key"
    assert key.stat().st_size == 32 and key.stat().st_mode & 0o777 == 0o600
    return summary


def assert_signed_and_untouched(rc: int, run: Path) -> None:
    """The default flight: signed with its per-run key, completed, every judge's check passed."""
    summary = assert_per_run_key(rc, run)
    assert judged_all_pass(run), summary
    comp = _json(run / "companion.json")
    assert comp["outcome"] == "completed" and comp["yielded"] is None
    assert comp["mavlink"]["signed"] is True
    assert _json(run / "sim_stats.json")["mavlink_signing"]["on"] is True


def assert_unsigned(run: Path) -> None:
    assert _json(run / "config.json")["signing"] == "off (--no-signing)"
    assert "MAVLink signing: off (--no-signing)." in (run / "summary.md").read_text()
    assert not (run / "signing.key").exists()


@pytest.mark.timeout(2400)
@pytest.mark.slow
def test_spoofed_heartbeat_auto_land_ends_only_an_unsigned_flight(tmp_path):
    rc, run, _ = attacked_flight(tmp_path / "signed", "heartbeat")
    assert_signed_and_untouched(rc, run)
    assert _json(run / "companion.json")["mavlink"]["rejected"] > 0  # it came, it was refused
    rc, run, _ = attacked_flight(tmp_path / "unsigned", "heartbeat", "--no-signing")
    assert_unsigned(run)
    comp = _json(run / "companion.json")
    assert comp["mavlink"] == {"signed": False, "rejected": 0}
    assert rc != 0 or comp["yielded"] is not None, comp  # the companion believed the AUTO.LAND


@pytest.mark.timeout(2400)
@pytest.mark.slow
def test_forced_disarm_on_the_ground_station_port_works_only_unsigned(tmp_path):
    rc, run, report = attacked_flight(tmp_path / "signed", "disarm")
    assert_signed_and_untouched(rc, run)
    assert not any(k.startswith("COMMAND_ACK") for k in report["replies"]), report
    assert _json(run / "sim_stats.json")["mavlink_signing"]["rejected_unsigned"] > 0
    rc, run, report = attacked_flight(tmp_path / "unsigned", "disarm", "--no-signing")
    assert_unsigned(run)
    comp = _json(run / "companion.json")
    assert rc != 0 and not judged_all_pass(run), comp
    assert report["replies"].get(f"COMMAND_ACK:{ARM_DISARM}:0", 0) > 0, (report, comp)  # done


@pytest.mark.timeout(2400)
@pytest.mark.slow
def test_spoofed_local_position_reaches_only_an_unsigned_companion(tmp_path):
    def spoofed_rows(run: Path) -> int:
        with open(run / "metrics.csv", newline="") as f:
            return sum(abs(float(r["north"]) - 1234.5) < 1e-3 for r in csv.DictReader(f))

    rc, run, _ = attacked_flight(tmp_path / "signed", "position")
    assert_signed_and_untouched(rc, run)
    assert spoofed_rows(run) == 0
    assert _json(run / "companion.json")["mavlink"]["rejected"] > 0
    rc, run, _ = attacked_flight(tmp_path / "unsigned", "position", "--no-signing")
    assert_unsigned(run)
    assert spoofed_rows(run) > 0


@pytest.mark.timeout(2400)
@pytest.mark.slow
def test_mission_count_lock_is_taken_only_on_an_unsigned_vehicle(tmp_path):
    def answered(report: dict) -> int:  # the vehicle began the attacker's fence upload
        return sum(n for k, n in report["replies"].items() if k.startswith("MISSION_REQUEST"))

    fast = ("--period", "0.25")  # the lock re-taken often: a short flight sees it many times
    rc, run, report = attacked_flight(tmp_path / "signed", "mission-count", attacker_args=fast)
    assert_signed_and_untouched(rc, run)
    assert answered(report) == 0, report
    assert _json(run / "sim_stats.json")["mavlink_signing"]["rejected_unsigned"] > 0
    rc, run, report = attacked_flight(tmp_path / "unsigned", "mission-count", "--no-signing",
                                      attacker_args=fast)  # fmt: skip
    assert_unsigned(run)
    assert answered(report) > 0, report
