"""Opt-in (`make test-autopilots`, SKYHERD_ARDUCOPTER_BIN; tests/e2e/test_autopilots_real.py
says how): the signed ground-air flight against REAL ArduCopter SITL (issue 27).

ArduCopter starts with no key and waits on SERIAL0 (TCP 5760+10·N) before it opens any other
port. `skyherd fly --connect tcp:…:SERIAL0 --signing-key FILE --setup-signing` is that client:
it gives the autopilot the key over SERIAL0 (the port ArduPilot takes unsigned frames on by
design, hence the one a key can be set over while another is held), keeps SERIAL0 for the
companion, and the world follows on SERIAL1 (PORT+2), signed: its frames are rendered only
from telemetry that passed the key. SERIAL2 (PORT+3) is the protected port an intruder without
the key uses: from the autopilot's first signed frame on, it sends a DO_SET_MODE LAND and a
PARAM_REQUEST_READ, unsigned, every 50 ms of the flight; neither is ever answered and the
flight completes with every mode change the companion's. The control, after the flight: an
unsigned SETUP_SIGNING of 32 zero bytes on SERIAL0 turns signing off (SERIAL0 is not
protected: docs/mavlink.md), and the same PARAM_REQUEST_READ on SERIAL2 is answered at once.
Free-running at the autopilot's 1x: wall time by nature."""

from __future__ import annotations

import csv
import json
import os
import threading
import time

import pytest

from skyherd.flight.mavlink.signing import is_signed, save_key
from skyherd.hil.link import MavlinkLink
from skyherd.runio.constants import CAMERA_HZ
from skyherd.scripts.cli import main
from tests.companion_flights import judge_checks
from tests.e2e.test_attack_mavlink import judged_all_pass
from tests.e2e.test_autopilots_real import _binary, ardupilot_listening

pytestmark = pytest.mark.autopilot

AP_INSTANCE = 101  # -I 101: SERIAL0 TCP 6770 (companion), SERIAL1 6772 (world), SERIAL2 6773
SERIAL0 = 5760 + 10 * AP_INSTANCE
SERIAL2 = SERIAL0 + 3  # SITL's serial ports: tcp:0 (wait), tcp:2, tcp:3
FLY_INSTANCE, ZENOH_PORT = 102, 7602
DO_SET_MODE, COPTER_LAND = 176, 9
PROBE = "FRAME_CLASS"  # the parameter the intruder asks for (nobody sets it during a flight)
GRACE_S = 1.0  # [s wall] after the autopilot's signing changes: answers in flight not counted


class Intruder(threading.Thread):
    """A ground station without the key on SERIAL2: every event timed (wall) in `log` as
    (t, what): "signed" / "unsigned" when the autopilot's frames change, "land" and "ask" for
    what it sent, "ack" (a COMMAND_ACK to its DO_SET_MODE) and "value" (PROBE's PARAM_VALUE)
    for what came back. It sends LAND only while the autopilot signs and `land` is set."""

    def __init__(self) -> None:
        super().__init__(daemon=True)
        self.log: list[tuple[float, str]] = []
        self.land = True
        self.stop = threading.Event()
        self.link: MavlinkLink | None = None

    def run(self) -> None:
        # the port opens once SERIAL0 has its client: wait for it as long as a boot takes
        self.link = link = MavlinkLink.open(f"tcp:127.0.0.1:{SERIAL2}", connect_wait_s=300.0)
        signed, last = None, 0.0
        while not self.stop.is_set():
            for m in link.recv(0.01):
                if m.get_srcComponent() == 1 and (s := is_signed(m.get_msgbuf())) != signed:
                    signed = s
                    self.log.append((time.monotonic(), "signed" if s else "unsigned"))
                name = m.get_type()
                if name == "COMMAND_ACK" and m.command == DO_SET_MODE:
                    self.log.append((time.monotonic(), "ack"))
                elif name == "PARAM_VALUE" and m.param_id == PROBE:
                    self.log.append((time.monotonic(), "value"))
            now = time.monotonic()
            if signed is None or now - last < 0.05:
                continue
            last = now
            if signed and self.land:
                link.send(link.mav.command_long_encode(1, 1, DO_SET_MODE, 0, 1, COPTER_LAND,
                                                       0, 0, 0, 0, 0))  # fmt: skip
                self.log.append((now, "land"))
            link.send(link.mav.param_request_read_encode(1, 1, PROBE.encode(), -1))
            self.log.append((now, "ask"))
        link.close()

    def counts(self, t0: float, t1: float) -> dict[str, int]:
        """Events between t0 + GRACE_S and t1 [wall]."""
        out: dict[str, int] = {}
        for t, what in self.log:
            if t0 + GRACE_S <= t < t1:
                out[what] = out.get(what, 0) + 1
        return out

    def first(self, what: str, after: float = 0.0) -> float | None:
        return next((t for t, w in self.log if w == what and t > after), None)


def _signing_off_over_serial0() -> None:
    """An unsigned SETUP_SIGNING of zeros (key and timestamp) on SERIAL0: ArduPilot takes it."""
    link = MavlinkLink.open(f"tcp:127.0.0.1:{SERIAL0}", connect_wait_s=30.0)
    try:
        link.send(link.mav.setup_signing_encode(1, 0, [0] * 32, 0))
        time.sleep(0.5)
    finally:
        link.close()


def test_real_arducopter_flown_signed_refuses_an_unsigned_intruder_on_serial2(tmp_path):
    binary = _binary("SKYHERD_ARDUCOPTER_BIN")
    key = tmp_path / "flight.key"
    save_key(key, os.urandom(32))
    runs = tmp_path / "runs"
    intruder = Intruder()
    wall0 = time.monotonic()
    with ardupilot_listening(binary, "+", "copter.parm", tmp_path, "GUID_TIMEOUT 0.5\n",
                             instance=AP_INSTANCE):  # fmt: skip
        intruder.start()
        try:
            rc = main(["fly", "--connect", f"tcp:127.0.0.1:{SERIAL0}", "--signing-key", str(key),
                       "--setup-signing", "--duration", "30", "--instance", str(FLY_INSTANCE),
                       "--zenoh-port", str(ZENOH_PORT), "--timeout", "900", "--runs-dir", str(runs)])  # fmt: skip
            t_flown = time.monotonic()
            intruder.land = False
            (run,) = runs.iterdir()
            summary = (run / "summary.md").read_text()
            assert rc == 0 and judged_all_pass(run), summary  # every mode change the companion's
            _signing_off_over_serial0()
            deadline = time.monotonic() + 30.0
            while intruder.counts(t_flown, time.monotonic()).get("value", 0) < 3:
                assert time.monotonic() < deadline, intruder.log[-20:]
                time.sleep(0.2)
        finally:
            intruder.stop.set()
            intruder.join(10)
    wall = time.monotonic() - wall0
    comp = json.loads((run / "companion.json").read_text())
    world = json.loads((run / "sim_stats.json").read_text())
    rows = [float(r["t"]) for r in csv.DictReader(open(run / "world.csv")) if r.get("t")]
    expected = CAMERA_HZ * (rows[-1] - rows[0]) + 1  # one frame per camera instant followed
    t_signed = intruder.first("signed")
    assert t_signed is not None, intruder.log[:20]
    t_unsigned = intruder.first("unsigned", after=t_signed)  # signing turned off
    assert t_unsigned is not None, intruder.log[-20:]
    before = intruder.counts(-GRACE_S, t_signed)  # the same port before the key: answered
    during = intruder.counts(t_signed, t_flown)  # the intruder's unsigned commands, signed
    after = intruder.counts(t_unsigned, time.monotonic())  # and with signing turned off
    print("arducopter signed:", json.dumps({
        "exit": rc, "wall_s": round(wall, 1), "checks": judge_checks(summary),
        "world_frames": world["frames"], "expected_frames": round(expected),
        "companion_frames": comp["frames"], "companion_rejected": comp["mavlink"]["rejected"],
        "world_rejected": world["mavlink_signing"]["rejected"],
        "intruder_before_the_key": before, "intruder_signed": during,
        "intruder_after_signing_off": after}, indent=1))  # fmt: skip
    for name in ("fence", "armed", "modes", "camera", "end", "mission"):
        assert name in judge_checks(summary), name
    assert f"MAVLink signing: key file {key.resolve()}." in summary
    assert comp["outcome"] == "completed" and comp["yielded"] is None
    assert comp["mavlink"]["signed"] is True
    assert world["followed"] and world["autopilot"] == "ArduCopter"
    assert world["mavlink_signing"]["on"] is True, world  # the world's link (SERIAL1) signed
    assert 0.9 * expected <= world["frames"] <= expected + 1, (world["frames"], expected)
    # the companion takes frames from its first tick on (the world renders from the first
    # sample, before arming): 550 of 794 when measured, every AI-phase frame (the camera check)
    assert comp["frames"]["ok"] > 200 and comp["frames"]["corrupt"] == 0, comp["frames"]
    assert during.get("land", 0) > 500 and during.get("ask", 0) > 500, during
    assert "ack" not in during and "value" not in during, during  # never answered
    assert after.get("value", 0) >= 3, after  # the same request, unsigned link: answered
