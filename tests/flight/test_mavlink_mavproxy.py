"""MAVProxy 1.8.75 (its own venv, .venv-mavproxy: it pulls GUI packages otherwise) connects
to the vehicle's ground-station link on udpin:127.0.0.1:14550 and reports its mode and arming
state; with the ArduCopter personality it flies it (arm, takeoff, hover in GUIDED, LAND, disarm).

MAVProxy's `mode NAME` cannot set PX4 modes (it passes PX4's mode tuple where a number is
expected), so mode changes are driven with the ArduCopter personality, which is what
MAVProxy is written for; the PX4 personality is checked for mode and arming reports.
"""

from __future__ import annotations

import queue
import re
import subprocess
import threading
import time
from pathlib import Path

from mavlink_support import running_sitl

from skyherd.flight.autopilot_api import FlightMode
from skyherd.flight.mavlink import Personality

PROMPT = re.compile(r"^[A-Z_.]+> $")
MAVPROXY = Path(__file__).resolve().parents[2] / ".venv-mavproxy" / "bin" / "mavproxy.py"


class MavProxy:
    """MAVProxy as a subprocess: write commands to its stdin, wait for lines it prints."""

    def __init__(self, target_system: int, tmp: Path):
        assert MAVPROXY.exists(), f"{MAVPROXY} missing: run `make mavproxy` (see Makefile)"
        self.proc = subprocess.Popen(
            [
                str(MAVPROXY),
                "--master=udpin:127.0.0.1:14550",
                f"--target-system={target_system}",
                "--no-state",
                "--default-modules=arm,mode,cmdlong",
            ],  # fmt: skip
            stdin=subprocess.PIPE,
            stdout=subprocess.PIPE,
            stderr=subprocess.STDOUT,
            text=True,
            cwd=tmp,
        )
        self.t0 = time.monotonic()
        self.lines: queue.Queue[str] = queue.Queue()
        self.seen: list[str] = []
        threading.Thread(target=self._read, daemon=True).start()

    def _read(self) -> None:
        """Lines, plus the mode prompt ("LOITER> ") MAVProxy prints without a newline."""
        buf = ""
        while ch := self.proc.stdout.read(1):
            if ch == "\n":
                self.lines.put(buf)
                buf = ""
                continue
            buf += ch
            if buf.endswith("> ") and PROMPT.match(buf):
                self.lines.put(buf)
                buf = ""

    def expect(self, pattern: str, timeout: float = 15.0) -> str:
        rx = re.compile(pattern)
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            try:
                line = self.lines.get(timeout=0.2)
            except queue.Empty:
                continue
            self.seen.append(line)
            if rx.search(line):
                print(f"{time.monotonic() - self.t0:6.2f} s  {line}")
                return line
        raise AssertionError(
            f"MAVProxy never printed /{pattern}/; it printed:\n" + "\n".join(self.seen[-40:])
        )

    def send(self, command: str) -> None:
        self.proc.stdin.write(command + "\n")
        self.proc.stdin.flush()

    def close(self) -> None:
        try:
            self.send("exit")
            self.proc.stdin.close()
        except OSError:
            pass
        try:
            self.proc.wait(timeout=3)
            return
        except subprocess.TimeoutExpired:
            pass
        self.proc.terminate()
        try:
            self.proc.wait(timeout=5)
        except subprocess.TimeoutExpired:
            self.proc.kill()
            self.proc.wait()


def test_mavproxy_reports_px4_mode_and_arming(tmp_path):
    with running_sitl(instance=15, speedup=2.0) as sitl:
        mp = MavProxy(16, tmp_path)
        try:
            mp.expect(r"Detected vehicle 16:1")
            mp.expect(r"Mode LOITER")  # PX4 AUTO.LOITER decoded from custom_mode
            mp.send("arm throttle")
            mp.expect(r"COMPONENT_ARM_DISARM: ACCEPTED")
            mp.expect(r"^ARMED")
            assert sitl.autopilot.armed
            mp.send("disarm")
            mp.expect(r"^DISARMED")
            assert not sitl.autopilot.armed
        finally:
            mp.close()


def test_mavproxy_flies_the_ardupilot_personality(tmp_path):
    with running_sitl(instance=14, speedup=2.0, personality=Personality.ARDUPILOT) as sitl:
        mp = MavProxy(15, tmp_path)
        try:
            mp.expect(r"Detected vehicle 15:1")
            mp.expect(r"Mode BRAKE")  # its hold on the ground, shown as ArduCopter's BRAKE
            mp.send("arm throttle")
            mp.expect(r"^ARMED")
            mp.send("takeoff 4")
            mp.expect(r"NAV_TAKEOFF: ACCEPTED")
            mp.expect(
                r"Mode GUIDED|^GUIDED> "
            )  # taking off (MAVProxy shows the mode as its prompt)
            deadline = time.monotonic() + 30.0  # hovering at 4 m, still GUIDED as ArduCopter
            while sitl.autopilot.mode is not FlightMode.HOLD and time.monotonic() < deadline:
                time.sleep(0.1)
            assert abs(sitl.autopilot.state.altitude - 4.0) < 0.5
            assert sitl.endpoint.telemetry.custom_mode(FlightMode.HOLD) == 4  # GUIDED
            mp.send("mode LAND")
            mp.expect(r"Mode LAND|^LAND> ")
            mp.expect(r"^DISARMED", timeout=25.0)  # landed, auto-disarmed
            assert sitl.autopilot.mode == FlightMode.LAND and sitl.autopilot.state.on_ground
        finally:
            mp.close()
