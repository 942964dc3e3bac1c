"""Opt-in: the production companion against REAL autopilot SITL binaries (`make test-autopilots`):
`skyherd fly --connect` (the ground-air mission, or the fixed-wing orbit, with the world built
around the autopilot), and the companion's own phases (mission.steps recipes, mission.authority's
mode mapping, mission.companion.run free-running; tests/companion_flights.py) twice in a row on
one running autopilot, the net's fallback and back in each.

Skipped unless the binaries are named by environment variables:
  SKYHERD_ARDUCOPTER_BIN  ArduCopter SITL (build/sitl/bin/arducopter)
  SKYHERD_ARDUPLANE_BIN   ArduPlane SITL (build/sitl/bin/arduplane)
  SKYHERD_PX4_BIN         PX4 SITL (build/px4_sitl_default/bin/px4), flown with SIH
  SKYHERD_ARDUPILOT_DEFAULTS  a folder with copter.parm / plane.parm (default: the binary's
                          source tree, Tools/autotest/default_params)
They must run in a private network namespace with only loopback up (their sockets are then
unreachable from anywhere else): run the suite inside `unshare -n sh -c 'ip link set lo up;
...'`; outside one these tests skip. ArduPilot instance 7 (TCP 5830), PX4 instance 74.
The copters fly two missions in a row on the same running autopilot and leave it disarmed.
"""

from __future__ import annotations

import contextlib
import os
import subprocess
import time
from pathlib import Path

import pytest

from skyherd.flight.autopilot_api import FlightMode
from skyherd.hil.autopilots import Step
from skyherd.hil.link import LinkError, MavlinkLink
from skyherd.mission.steps import recipe, wait_ready, wait_until
from skyherd.runio.constants import COMPANION_COMPONENT
from skyherd.scripts.cli import main
from tests.companion_flights import Steps, fly, judge_checks, missions

pytestmark = pytest.mark.autopilot

ARDUPILOT_INSTANCE = 7  # -I 7: SERIAL0 on TCP 5760 + 10·7
PX4_INSTANCE = 74
HOME = "-35.363261,149.165230,584,0"  # CONVENTIONS.md default home


def _private_netns() -> bool:
    """Only loopback in this network namespace (as inside `unshare -n` with lo up)."""
    import socket

    try:
        return [name for _, name in socket.if_nameindex()] == ["lo"]
    except OSError:
        return False


def _binary(var: str) -> Path:
    path = os.environ.get(var)
    if not path:
        pytest.skip(f"{var} is not set: no real autopilot binary to fly (make test-autopilots)")
    if not Path(path).is_file():
        pytest.fail(f"{var}={path} is not a file")
    if not _private_netns():
        pytest.skip("real autopilots run only in a private network namespace: "
                    "unshare -n sh -c 'ip link set lo up; make test-autopilots'")  # fmt: skip
    return Path(path)


def _defaults(binary: Path, name: str) -> Path | None:
    """copter.parm / plane.parm: SKYHERD_ARDUPILOT_DEFAULTS, else the binary's source tree
    (Tools/autotest/default_params, then Tools/autotest/models)."""
    root = os.environ.get("SKYHERD_ARDUPILOT_DEFAULTS")
    autotest = binary.resolve().parents[3] / "Tools/autotest"
    for folder in ([Path(root)] if root else []) + [
        autotest / "default_params",
        autotest / "models",
    ]:
        if (folder / name).is_file():
            return folder / name
    return None


def _stop(proc: subprocess.Popen, log) -> None:
    """Terminate the autopilot (kill it after 10 s) and close its log."""
    proc.terminate()
    try:
        proc.wait(10)
    except subprocess.TimeoutExpired:
        proc.kill()
        proc.wait()
    log.close()


@contextlib.contextmanager
def ardupilot(binary: Path, model: str, parm: str, cwd: Path):
    with ardupilot_listening(binary, model, parm, cwd) as proc:
        link = _connect(f"tcp:127.0.0.1:{5760 + 10 * ARDUPILOT_INSTANCE}", proc, cwd)
        try:
            yield link
        finally:
            link.close()


def _connect(address: str, proc: subprocess.Popen, cwd: Path) -> MavlinkLink:
    deadline = time.monotonic() + 60
    while True:
        try:
            return MavlinkLink.open(address, source_component=COMPANION_COMPONENT,
                                    tlog=cwd / "telemetry.tlog")  # fmt: skip
        except LinkError:
            if proc.poll() is not None or time.monotonic() > deadline:
                raise RuntimeError(f"no {address}; see {cwd}/autopilot.log") from None
            time.sleep(0.5)


def test_real_arducopter_flies_twice_and_is_left_disarmed(tmp_path):
    binary = _binary("SKYHERD_ARDUCOPTER_BIN")
    out: dict = {}
    with ardupilot(binary, "+", "copter.parm", tmp_path) as link:
        v = fly(link, Steps(), missions(10.0, [15.0, 10.0, -10.0], 3.0, 2, out), patience_s=60.0)
    assert out == {"yielded_0": None, "armed_0": False, "yielded_1": None, "armed_1": False}
    names = [n for _, n in v.tel.modes]
    assert {"GUIDED", "BRAKE", "LAND"} <= set(names) and "LOITER" not in names


def test_real_arduplane_takes_off_in_takeoff_mode_and_loiters(tmp_path):
    binary = _binary("SKYHERD_ARDUPLANE_BIN")
    out: dict = {}
    with ardupilot(binary, "plane", "plane.parm", tmp_path) as link:
        v = fly(link, Steps(), missions(40.0, [300.0, 0.0, -50.0], 110.0, 1, out), patience_s=60.0)
    names = [n for _, n in v.tel.modes]
    assert {"TAKEOFF", "GUIDED", "LOITER", "RTL"} <= set(names)
    assert v.profile.name == "ArduPlane" and v.tel.mode is FlightMode.RTL
    assert out["yielded_0"] is None


def _fly_connect(address: str, tmp_path: Path, instance: int, zenoh_port: int) -> tuple[int, Path]:
    runs = tmp_path / f"runs-{instance}"
    rc = main(["fly", "--connect", address, "--duration", "30", "--instance", str(instance),
               "--zenoh-port", str(zenoh_port), "--timeout", "900", "--runs-dir", str(runs)])  # fmt: skip
    (run,) = runs.iterdir()
    return rc, run


def _judged(rc: int, run: Path, autopilot: str) -> dict:
    """The judge's checks of summary.md, printed with the flight's figures (the test's record);
    asserts that every check passed."""
    import json

    summary = (run / "summary.md").read_text()
    checks = judge_checks(summary)
    comp = json.loads((run / "companion.json").read_text())
    modes = [
        json.loads(line).get("mode") for line in (run / "modes.jsonl").read_text().splitlines()
    ]
    print(autopilot, "exit", rc, json.dumps({"checks": {k: f"{r}: {f}" for k, (r, f) in checks.items()},
          "decisions": comp.get("decisions"), "switches": (comp.get("net") or {}).get("switches"),
          "modes": modes}, indent=1))  # fmt: skip
    assert rc == 0, summary
    assert checks and all(r == "pass" for r, _ in checks.values()), summary
    return comp


def _assert_fly_completed(rc: int, run: Path, autopilot: str) -> None:
    import json

    comp = _judged(rc, run, autopilot)
    world = json.loads((run / "sim_stats.json").read_text())
    assert comp["outcome"] == "completed" and comp["yielded"] is None and comp["decisions"] >= 50
    assert world["followed"] and world["autopilot"] == autopilot and comp["frames"]["ok"] > 200
    for name in ("fence", "armed", "modes", "camera", "end", "mission"):
        assert name in judge_checks((run / "summary.md").read_text()), name


def test_real_arducopter_flown_by_skyherd_fly_connect(tmp_path):
    """`skyherd fly --connect`: the ground-air mission behind the net, the world (UGV team,
    camera) following the autopilot on its SERIAL1, landed and disarmed. With GUID_TIMEOUT
    0.5 s: the stock 3 s is refused before take-off by the parameter guard (docs/autopilots.md)."""
    binary = _binary("SKYHERD_ARDUCOPTER_BIN")
    port = 5760 + 10 * ARDUPILOT_INSTANCE
    with ardupilot_listening(binary, "+", "copter.parm", tmp_path, "GUID_TIMEOUT 0.5\n"):
        rc, run = _fly_connect(f"tcp:127.0.0.1:{port}", tmp_path, 76, 7472)
    _assert_fly_completed(rc, run, "ArduCopter")


def _configured(
    tmp_path: Path, address: str, instance: int, zenoh_port: int, name: str, autopilot: str
) -> None:
    """On an autopilot with its stock parameters: `fly --connect` refuses before take-off naming
    `name` and the flag; `fly --connect --configure-autopilot` sets it, reads it back, records it
    and flies to the end."""
    import json

    runs = tmp_path / "refused"
    rc = main(["fly", "--connect", address, "--duration", "30", "--instance", str(instance),
               "--zenoh-port", str(zenoh_port), "--timeout", "900", "--runs-dir", str(runs)])  # fmt: skip
    (run,) = runs.iterdir()
    reason = json.loads((run / "companion.json").read_text())["reason"]
    assert rc == 1 and name in reason and "--configure-autopilot" in reason, reason
    runs = tmp_path / "configured"
    rc = main(["fly", "--connect", address, "--duration", "30", "--instance", str(instance),
               "--zenoh-port", str(zenoh_port), "--timeout", "900", "--runs-dir", str(runs),
               "--configure-autopilot"])  # fmt: skip
    (run,) = runs.iterdir()
    _assert_fly_completed(rc, run, autopilot)
    changes = {c["name"]: c for c in json.loads((run / "companion.json").read_text())["configured"]}
    print(autopilot, "configured", json.dumps(changes, indent=1))
    assert name in changes and changes[name]["after"] < changes[name]["before"]
    assert name in (run / "summary.md").read_text()


def test_real_arducopter_on_stock_parameters_configured_by_fly_connect(tmp_path):
    """Stock copter.parm (GUID_TIMEOUT 3 s): refused, then set by --configure-autopilot."""
    binary = _binary("SKYHERD_ARDUCOPTER_BIN")
    port = 5760 + 10 * ARDUPILOT_INSTANCE
    with ardupilot_listening(binary, "+", "copter.parm", tmp_path):
        _configured(tmp_path, f"tcp:127.0.0.1:{port}", 78, 7474, "GUID_TIMEOUT", "ArduCopter")


def test_real_px4_sih_on_stock_parameters_configured_by_fly_connect(tmp_path):
    """Stock PX4 SIH (COM_OF_LOSS_T 1 s): refused, then set by --configure-autopilot."""
    binary = _binary("SKYHERD_PX4_BIN")
    port = 14540 + PX4_INSTANCE if PX4_INSTANCE <= 9 else 14549
    with px4(binary, tmp_path, open_link=False):
        _configured(tmp_path, f"udpin:127.0.0.1:{port}", 79, 7475, "COM_OF_LOSS_T", "PX4")


@contextlib.contextmanager
def px4(binary: Path, cwd: Path, open_link: bool = True):
    """PX4 SITL with SIH (its own physics), instance PX4_INSTANCE, working files in `cwd`; the
    companion's link to it (None with `open_link` False: `fly` opens its own)."""
    etc = binary.resolve().parents[1] / "etc"
    env = dict(os.environ, PX4_SYS_AUTOSTART="10040", PX4_SIM_MODEL="sihsim_quadx")
    log = open(cwd / "autopilot.log", "wb")
    proc = subprocess.Popen([str(binary), "-d", "-i", str(PX4_INSTANCE), "-w", str(cwd), str(etc)],
                            cwd=cwd, env=env, stdout=log, stderr=subprocess.STDOUT)  # fmt: skip
    # its onboard link sends to 14540+N, to 14549 for N > 9 (px4-rc.mavlink)
    port = 14540 + PX4_INSTANCE if PX4_INSTANCE <= 9 else 14549
    link = None
    try:
        if open_link:
            link = MavlinkLink.open(f"udpin:127.0.0.1:{port}", source_component=COMPANION_COMPONENT,
                                    tlog=cwd / "telemetry.tlog")  # fmt: skip
        yield link
    finally:
        if link is not None:
            link.close()
        _stop(proc, log)


def test_real_px4_sih_flies_twice_and_is_left_disarmed(tmp_path):
    binary = _binary("SKYHERD_PX4_BIN")
    out: dict = {}
    with px4(binary, tmp_path) as link:
        v = fly(link, Steps(), missions(10.0, [15.0, 10.0, -10.0], 3.0, 2, out), patience_s=60.0)
    assert out == {"yielded_0": None, "armed_0": False, "yielded_1": None, "armed_1": False}
    assert v.tel.mode is FlightMode.HOLD  # PX4's end: Hold, ready to arm again
    names = [n for _, n in v.tel.modes]
    assert names.count("AUTO.TAKEOFF") == 2 and names.count("AUTO.LAND") == 2


def test_real_px4_sih_flown_by_skyherd_fly_connect(tmp_path):
    """`skyherd fly --connect` on PX4's onboard link (14540+N, 14549 for N > 9), the world
    following it on its ground-station link (14550). COM_OF_LOSS_T set to 0.5 s first, over
    the same link (the stock 1 s is refused before take-off by the parameter guard)."""
    binary = _binary("SKYHERD_PX4_BIN")

    def offboard_loss_half_a_second(v):
        yield from wait_ready(v)
        yield from recipe(v, (Step("set_param", params=(0.5,), what="COM_OF_LOSS_T"),))
        yield from wait_until(v, lambda: v.params.get("COM_OF_LOSS_T") == 0.5, 10.0, "its echo")

    port = 14540 + PX4_INSTANCE if PX4_INSTANCE <= 9 else 14549
    with px4(binary, tmp_path, open_link=False):
        fly(f"udpin:127.0.0.1:{port}", Steps(), offboard_loss_half_a_second, patience_s=60.0)
        rc, run = _fly_connect(f"udpin:127.0.0.1:{port}", tmp_path, 77, 7473)
    _assert_fly_completed(rc, run, "PX4")


@contextlib.contextmanager
def ardupilot_listening(binary: Path, model: str, parm: str, cwd: Path, extra: str = "",
                        instance: int = ARDUPILOT_INSTANCE):  # fmt: skip
    """The autopilot started, waiting on SERIAL0 for a client that is not ours (`fly`'s);
    `extra`: parameter lines added after the defaults file (as an operator's own file);
    `instance`: its -I N (SERIAL0 on TCP 5760 + 10·N)."""
    args = [str(binary), "--model", model, "--speedup", "1", "-I", str(instance),
            "--home", HOME, "-w"]  # fmt: skip
    files = [str(d)] if (d := _defaults(binary, parm)) is not None else []
    if extra:
        (cwd / "operator.parm").write_text(extra)
        files.append(str(cwd / "operator.parm"))
    if files:
        args += ["--defaults", ",".join(files)]
    log_path = cwd / "autopilot.log"
    log = open(log_path, "wb")
    proc = subprocess.Popen(args, cwd=cwd, stdout=log, stderr=subprocess.STDOUT)
    try:
        deadline = time.monotonic() + 60
        while b"Waiting for connection" not in log_path.read_bytes():
            if proc.poll() is not None or time.monotonic() > deadline:
                raise RuntimeError(f"{binary} did not listen; see {log_path}")
            time.sleep(0.2)
        yield proc
    finally:
        _stop(proc, log)


def test_real_arduplane_flies_the_fixed_wing_orbit_on_stock_parameters(tmp_path):
    """`skyherd fly --connect --airframe fixedwing` on stock plane.parm: the plan fits the
    camera on ROLL_LIMIT_DEG 65, TECS_CLMB_MAX / TECS_SINK_MAX are lowered to the envelope's,
    the orbit is established, flown for 60 s and ended in RTL; the world's gimballed camera
    saw the team (the ROI routed to it as the vehicle's gimbal)."""
    import json

    from skyherd.scripts.cli import main

    binary = _binary("SKYHERD_ARDUPLANE_BIN")
    port = 5760 + 10 * ARDUPILOT_INSTANCE
    with ardupilot_listening(binary, "plane", "plane.parm", tmp_path):
        rc = main(["fly", "--connect", f"tcp:127.0.0.1:{port}", "--airframe", "fixedwing",
                   "--orbit-duration", "60", "--instance", "75", "--zenoh-port", "7471",
                   "--timeout", "900", "--runs-dir", str(tmp_path / "runs")])  # fmt: skip
    (run,) = (tmp_path / "runs").iterdir()
    comp = _judged(rc, run, "ArduPlane")
    orbit = comp["orbit"]
    assert orbit["t_established"] is not None and orbit["plan"]["radius_m"] < 100.0
    assert orbit["t_orbit_end"] - orbit["t_established"] >= 60.0 - 0.5
    world = json.loads((run / "sim_stats.json").read_text())
    assert world["followed"] and world["autopilot"] == "ArduPlane" and world["roi_commands"] > 100
    events = [json.loads(line) for line in (run / "events.jsonl").read_text().splitlines()]
    said = [e["reason"] for e in events if e["event"] == "params"]
    assert "TECS_CLMB_MAX = 5 m/s" in said[0] and said[-1].startswith("autopilot")
