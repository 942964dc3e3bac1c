"""Opt-in: real PX4 (`none_iris`) and real ArduCopter (`--model JSON`) flying on skyherd's
physics, flown by the production companion (`make test-autopilots`).

Three programs per flight, all real: `skyherd sim --autopilot px4|ardupilot` (the bridge:
skyherd's quadrotor is the autopilot's simulator, in the autopilot's lockstep; its world.csv is
the truth), the autopilot's own SITL binary (hil/autopilot_sitl.py), and `skyherd fly --connect
ADDRESS` — the companion behind the safety net, with the world (UGV team, camera) built around
the outside vehicle from its second MAVLink link — flying the ground-air mission. The test
asserts on the run folder the judge wrote (verdict, each check, landed), and on the bridge's
truth: the vehicle climbed to the mission's altitude and landed where the autopilot believes it
is (its estimate, the followed world's world.csv, against the truth).

Skipped unless the binaries are named by environment variables (and run inside a private
network namespace with only loopback up, as tests/e2e/test_autopilots_real.py):
  SKYHERD_PX4_BIN             build/px4_sitl_default/bin/px4
  SKYHERD_ARDUCOPTER_BIN      build/sitl/bin/arducopter
  SKYHERD_ARDUPILOT_DEFAULTS  a folder with copter.parm (default: the binary's source tree)
PX4 instance 78 (TCP 4638 to the bridge, onboard link 14549, ground station 14550), ArduCopter
instance 8 (UDP 9082 to the bridge, SERIAL0 TCP 5840, SERIAL1 5842). Free-running by nature: the
autopilot runs at 1× of its bridge's clock and the companion keeps up with it in wall time.
"""

from __future__ import annotations

import contextlib
import csv
import json
import subprocess
import sys
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pytest

from skyherd.hil import autopilot_sitl
from skyherd.safety.config import ENVELOPE_DIR, load_envelope
from skyherd.safety.judge import JudgeParams, Truth, clearances, fence_check
from tests.companion_flights import judge_checks
from tests.e2e.test_autopilots_real import _binary, _defaults

pytestmark = pytest.mark.autopilot

ROOT = Path(__file__).resolve().parents[2]
PX4_INSTANCE = 78
COPTER_INSTANCE = 8
DURATION_S = 30.0  # the AI phase of the ground-air mission [s]


def _skyherd(*args: str, log: Path) -> subprocess.Popen:
    return subprocess.Popen([sys.executable, "-m", "skyherd.scripts.cli", *args], cwd=ROOT,
                            stdout=open(log, "wb"), stderr=subprocess.STDOUT)  # fmt: skip


def _stop_bridge(proc: subprocess.Popen, log: Path) -> None:
    """SIGTERM: the bridged world stops and writes sim_stats.json."""
    if proc.poll() is None:
        proc.terminate()
    try:
        proc.wait(30)
    except subprocess.TimeoutExpired:
        proc.kill()
        proc.wait()
        pytest.fail(f"the bridge did not stop on SIGTERM; see {log}")


def _fly(
    address: str, tmp: Path, instance: int, zenoh_port: int, *extra: str
) -> tuple[int, str, Path]:
    """`skyherd fly --connect ADDRESS [EXTRA...]` as a user runs it: (exit code, the verdict
    line, run folder)."""
    runs = tmp / "runs"
    cmd = [sys.executable, "-m", "skyherd.scripts.cli", "fly", "--connect", address,
           "--duration", repr(DURATION_S), "--instance", str(instance),
           "--zenoh-port", str(zenoh_port), "--timeout", "1200", "--runs-dir", str(runs),
           *extra]  # fmt: skip
    proc = subprocess.run(cmd, cwd=ROOT, capture_output=True, text=True, timeout=1500)
    (tmp / "fly.out").write_text(proc.stdout + "\n--- stderr\n" + proc.stderr)
    (run,) = runs.iterdir()
    lines = [ln for ln in proc.stdout.splitlines() if ln.strip()]
    return proc.returncode, lines[-1] if lines else "", run


def _track(path: Path) -> np.ndarray:
    """world.csv → rows of (t, north, east, down)."""
    rows = []
    for r in csv.DictReader(open(path)):
        try:
            rows.append([float(r[k]) for k in ("t", "north", "east", "down")])
        except (TypeError, ValueError):
            continue  # the last row, cut by the stop
    return np.array(rows).reshape(-1, 4)


def _json(path: Path) -> dict:
    """A run's JSON record, {} when it was not written."""
    return json.loads(path.read_text()) if path.exists() else {}


def _takeoff_t(track: np.ndarray) -> float:
    """The first time the track is 1 m above its start."""
    up = np.nonzero(-track[:, 3] > -track[0, 3] + 1.0)[0]
    assert up.size, "never left the ground"
    return float(track[up[0], 0])


def check_flight(rc: int, verdict: str, run: Path, bridge_run: Path, autopilot: str) -> dict:
    """What the judge and the truth say; each figure printed (the test's record)."""
    summary = (run / "summary.md").read_text()
    checks = judge_checks(summary)
    comp, world = _json(run / "companion.json"), _json(run / "sim_stats.json")
    bridge = _json(bridge_run / "sim_stats.json")  # absent when the bridge ended on an error
    truth, est = _track(bridge_run / "world.csv"), _track(run / "world.csv")
    net = comp.get("net") or {}
    fig = {
        "verdict": verdict,
        "checks": {k: f"{v[0]}: {v[1]}" for k, v in checks.items()},
        "decisions": comp.get("decisions"),
        "switches": net.get("switches"),
        "modes": [m.get("mode") for m in map(json.loads, (run / "modes.jsonl").read_text().splitlines())]
        if (run / "modes.jsonl").exists() else None,
        "bridge": bridge,
    }  # fmt: skip
    print(autopilot, json.dumps(fig, indent=1))
    assert rc == 0 and verdict.startswith("skyherd fly: completed"), (verdict, summary)
    for name in ("fence", "armed", "modes", "camera", "end", "mission"):
        assert checks[name][0] == "pass", (name, checks[name], summary)
    assert comp["outcome"] == "completed" and comp["yielded"] is None and comp["decisions"] >= 50
    assert world["followed"] and world["autopilot"] == autopilot and comp["frames"]["ok"] > 200
    # the bridge flew the autopilot all along, frame by frame, and its truth agrees with the
    # autopilot's estimate: the same climb, and the landing where the autopilot believes it is
    assert bridge, (bridge_run / "sim.log").read_text()[-2000:]
    assert bridge["bridged"] and bridge["sim_s"] > DURATION_S
    t0_truth, t0_est = _takeoff_t(truth), _takeoff_t(est)
    top_truth, top_est = -truth[:, 3].min(), -est[:, 3].min()
    # the landing spot: the estimate's last armed sample (PX4 moves its local origin to where
    # it stands once disarmed) against the truth at that time
    armed = [
        float(r["t"]) for r in csv.DictReader(open(run / "world.csv")) if r.get("armed") == "1"
    ]
    t_land = armed[-1] if armed else est[-1, 0]
    at = lambda track: track[np.argmin(abs(track[:, 0] - t_land)), 1:3]  # noqa: E731
    landed = float(np.linalg.norm(at(truth) - at(est)))
    spec, _ = load_envelope(ENVELOPE_DIR / "quadrotor_groundair.toml")
    auth = comp.get("authority") or {}  # the AI phase, on the autopilot's clock = the bridge's
    window = (auth["t_start"], auth["t_end"]) if auth.get("t_end") is not None else None
    bridge_truth = Truth.from_rows(list(csv.DictReader(open(bridge_run / "world.csv"))))
    jp = JudgeParams()
    fence = fence_check(bridge_truth, spec, *clearances(bridge_truth, spec, window), jp)
    fig["truth"] = {"fence_on_the_bridge_truth": f"{'pass' if fence.ok else 'FAIL'}: {fence.figure}",
                    "top_truth_m": round(float(top_truth), 3), "top_estimate_m": round(float(top_est), 3),
                    "landing_truth_vs_estimate_m": round(landed, 3), "at_t": t_land,
                    "truth_end_alt_m": round(float(-truth[-1, 3]), 3),
                    "takeoff_t": (t0_truth, t0_est)}  # fmt: skip
    print(autopilot, "truth:", fig["truth"])
    assert fence.ok, fence  # the physics' truth, not only the autopilot's estimate, in the fence
    assert abs(top_truth - top_est) < 1.5
    assert -truth[-1, 3] < 0.3 and landed < 1.5
    return fig


@contextlib.contextmanager
def on_the_bridge(tmp: Path, autopilot: str, instance: int, zenoh_port: int, start):
    """The bridge (`skyherd sim --autopilot px4|ardupilot`) and the real autopilot on it
    (`start(work_dir, log)`); yields the bridge's run folder. Both are stopped on the way out,
    the bridge first (it writes its sim_stats.json; an autopilot gone first ends it with an
    error instead)."""
    bridge_run = tmp / "bridge"
    bridge_run.mkdir()
    log = bridge_run / "sim.log"
    bridge = _skyherd("sim", "--autopilot", autopilot, "--instance", str(instance), "--speedup", "1",
                      "--zenoh-port", str(zenoh_port), "--run-dir", str(bridge_run), log=log)  # fmt: skip
    work = tmp / autopilot
    work.mkdir()
    ap_log = open(work / "autopilot.log", "wb")
    proc = None
    try:
        proc = start(work, ap_log)
        yield bridge_run
    finally:
        _stop_bridge(bridge, log)
        if proc is not None:
            autopilot_sitl.stop(proc)
        ap_log.close()


@dataclass(frozen=True)
class Slots:
    """One flight's instance numbers and Zenoh ports: the autopilot's (and its bridge's), the
    companion's."""

    autopilot: int
    bridge_zenoh: int
    fly: int
    fly_zenoh: int


def fly_px4(tmp: Path, slots: Slots, *extra: str) -> tuple[int, str, Path, Path]:
    """PX4 `none_iris` on the bridge flown by `skyherd fly --connect` (+ `extra`), PX4 with
    COM_OF_LOSS_T 0.5 s at boot (the stock 1 s is refused before take-off by the parameter
    guard); the companion on its onboard link (14549 for every instance > 9), the world on its
    ground-station link. (exit code, verdict, run folder, bridge run folder)."""
    binary = _binary("SKYHERD_PX4_BIN")

    def start(work, log):
        return autopilot_sitl.start_px4(binary, slots.autopilot, work, log, {"COM_OF_LOSS_T": 0.5})

    wall = time.monotonic()
    with on_the_bridge(tmp, "px4", slots.autopilot, slots.bridge_zenoh, start) as bridge_run:
        rc, verdict, run = _fly("udpin:127.0.0.1:14549", tmp, slots.fly, slots.fly_zenoh, *extra)
    print("px4: wall time [s]", round(time.monotonic() - wall, 1))
    return rc, verdict, run, bridge_run


def fly_arducopter(tmp: Path, slots: Slots, *extra: str) -> tuple[int, str, Path, Path]:
    """ArduCopter `--model JSON` on the bridge flown by `skyherd fly --connect` (+ `extra`),
    on stock copter.parm + skyherd's frame + GUID_TIMEOUT 0.5 (an operator's file: the stock
    3 s is refused before take-off by the parameter guard); the companion on SERIAL0, the world
    on SERIAL1. (exit code, verdict, run folder, bridge run folder)."""
    binary = _binary("SKYHERD_ARDUCOPTER_BIN")
    parm = _defaults(binary, "copter.parm")

    def start(work, log):
        return autopilot_sitl.start_arducopter(binary, slots.autopilot, work, log,
                                               [parm] if parm else [], "GUID_TIMEOUT 0.5\n")  # fmt: skip

    wall = time.monotonic()
    address = f"tcp:127.0.0.1:{5760 + 10 * slots.autopilot}"
    with on_the_bridge(tmp, "ardupilot", slots.autopilot, slots.bridge_zenoh, start) as bridge_run:
        rc, verdict, run = _fly(address, tmp, slots.fly, slots.fly_zenoh, *extra)
    print("arducopter: wall time [s]", round(time.monotonic() - wall, 1))
    return rc, verdict, run, bridge_run


def test_px4_none_iris_on_skyherd_physics_flown_by_skyherd_fly_connect(tmp_path):
    check_flight(*fly_px4(tmp_path, Slots(PX4_INSTANCE, 7476, 79, 7477)), "PX4")


def test_arducopter_json_on_skyherd_physics_flown_by_skyherd_fly_connect(tmp_path):
    check_flight(*fly_arducopter(tmp_path, Slots(COPTER_INSTANCE, 7478, 9, 7479)), "ArduCopter")
