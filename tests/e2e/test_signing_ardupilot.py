"""Issue 27: a signed flight against the built-in vehicle in its ArduCopter personality (real
ArduCopter: the opt-in tests/e2e/test_signing_arducopter.py, `make test-autopilots`):
`skyherd fly --connect ... --signing-key FILE`
with the vehicle holding the same key, while real attacker processes without the key
(tests/attacker.py, pymavlink) send unsigned commands to the vehicle's ground-station port.

The vehicle's endpoint applies ArduPilot's accepted-unsigned list on a signed link
(flight.mavlink.signing.ACCEPT_UNSIGNED: RADIO_STATUS only, as ArduPilot's GCS_Common
`accept_unsigned_callback`; its SERIAL0 exception is a port the built-in vehicle does not have):
the attacker's DO_SET_MODE LAND is refused and unanswered, its RADIO_STATUS is taken (counted)
but does not make the vehicle answer it. Unsigned, the same DO_SET_MODE lands the vehicle (so
the test can fail). Free-running on the vehicle's clock at 1x: wall time by nature
(test_fly_connect.py says why)."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from contextlib import contextmanager
from pathlib import Path

import pytest

from skyherd.flight.autopilot_api import FlightMode
from skyherd.flight.mavlink import Personality
from skyherd.flight.mavlink.signing import save_key
from skyherd.scripts.cli import main
from tests.e2e.test_attack_mavlink import judged_all_pass
from tests.mavlink_support import running_sitl

HERE = Path(__file__).resolve().parents[1]  # tests/: attacker.py
INSTANCE = 105  # the vehicle: API 14580+105 → companion 14645, ground station 18675 → 14550
DO_SET_MODE = 176


@contextmanager
def attackers(*attacks: str):
    """Attacker processes on the vehicle (one per attack); yields a dict filled with their
    reports when the block ends."""
    procs = {a: subprocess.Popen([sys.executable, str(HERE / "attacker.py"), a, "--instance",
                                  str(INSTANCE)], stdout=subprocess.PIPE, text=True, cwd=HERE.parent)
             for a in attacks}  # fmt: skip
    reports: dict[str, dict] = {}
    try:
        yield reports
    finally:
        for p in procs.values():
            p.send_signal(signal.SIGTERM)
        for a, p in procs.items():
            out, _ = p.communicate(timeout=120)
            reports[a] = json.loads(out.strip().splitlines()[-1])


@pytest.mark.slow
def test_a_signed_flight_on_the_ardupilot_personality_refuses_unsigned_commands_walltime(tmp_path):
    key = tmp_path / "flight.key"
    save_key(key, os.urandom(32))
    runs = tmp_path / "runs"
    with running_sitl(INSTANCE, speedup=1.0, personality=Personality.ARDUPILOT,
                      signing_key=key) as sitl:  # fmt: skip
        with attackers("ap-land", "radio-status") as reports:
            rc = main(["fly", "--connect", f"udpin:127.0.0.1:{14540 + INSTANCE}", "--signing-key",
                       str(key), "--altitude", "6", "--duration", "10", "--zenoh-port", "7551",
                       "--instance", "104", "--timeout", "600", "--runs-dir", str(runs)])  # fmt: skip
        stats = dict(sitl.endpoint.signing.stats)
        end_mode = sitl.autopilot.mode
    (run,) = runs.iterdir()
    summary = (run / "summary.md").read_text()
    assert rc == 0 and judged_all_pass(run), summary  # every mode change the companion's
    assert f"MAVLink signing: key file {key.resolve()}." in summary
    comp = json.loads((run / "companion.json").read_text())
    assert comp["outcome"] == "completed" and comp["yielded"] is None
    assert comp["mavlink"]["signed"] is True
    assert comp["frames"]["ok"] > 50  # the world's link (--follow) is signed too: it renders
    world = json.loads((run / "sim_stats.json").read_text())
    assert world["followed"] and world["mavlink_signing"]["on"] is True, world
    assert end_mode is FlightMode.LAND  # ArduCopter's end: the companion's LAND, disarmed
    assert reports["ap-land"]["sent"] > 100 and reports["radio-status"]["sent"] > 100, reports
    assert not any(k.startswith("COMMAND_ACK") for k in reports["ap-land"]["replies"]), reports
    assert reports["radio-status"]["replies"] == {}, reports  # taken, never answered
    assert stats["rejected_unsigned"] >= reports["ap-land"]["sent"] // 2, stats
    assert stats["unsigned_accepted"] >= reports["radio-status"]["sent"] // 2, stats


@pytest.mark.slow
def test_the_same_unsigned_command_lands_an_unsigned_ardupilot_personality_walltime():
    with running_sitl(INSTANCE, speedup=1.0, personality=Personality.ARDUPILOT) as sitl:
        assert sitl.autopilot.mode is not FlightMode.LAND
        with attackers("ap-land") as reports:
            deadline = time.monotonic() + 30.0
            while sitl.autopilot.mode is not FlightMode.LAND:
                assert time.monotonic() < deadline, sitl.autopilot.mode
                time.sleep(0.05)
    assert reports["ap-land"]["replies"].get(f"COMMAND_ACK:{DO_SET_MODE}:0", 0) > 0, reports
