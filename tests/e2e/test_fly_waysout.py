"""Every way out of `skyherd fly` is safe (issue 26, item 6), through the real programs.

Each scenario runs in its own mount and network namespaces (tests/waysout_rig.py, as root):
`fly` on the built-in quadrotor, lockstep, as fast as possible; at simulation time t >= 20 s,
with the vehicle airborne in OFFBOARD (read from world.csv), one thing happens: SIGTERM or
SIGHUP or kill -9 to `fly`, kill -9 to the companion or the simulator, another process fills
the runs folder's disk; or the runs folder is a 700 KiB tmpfs, or read-only, from the start. Each test asserts that no
process of the flight is left (scanned in /proc by the run folder in its argv), where the
vehicle ended (landed and disarmed, or in the autopilot's failsafe), and the line that says
why. The trigger is a simulation time; how long after it the action lands does not change
what is asserted (the hand-over, the failsafe and the landing are all in simulation time).
"""

from __future__ import annotations

import json
import re
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from skyherd.scripts.cli import main

RIG = Path(__file__).resolve().parents[1] / "waysout_rig.py"
CLI = Path(__file__).resolve().parents[2] / "skyherd" / "scripts" / "cli.py"
FLY = ["--duration", "40", "--speedup", "0", "--instance", "23", "--zenoh-port", "7483",
       "--no-record"]  # fmt: skip


def _can_unshare() -> bool:
    if shutil.which("unshare") is None:
        return False
    return subprocess.run(["unshare", "-m", "-n", "true"], capture_output=True).returncode == 0


needs_namespaces = pytest.mark.skipif(
    not _can_unshare(), reason="needs `unshare -m -n` (root): mounts and a private network"
)


def way_out(tmp_path: Path, do: str, mount: str = "", fly: list[str] = FLY, t: float = 20.0,
            **more) -> dict:  # fmt: skip
    tmp_path.mkdir(parents=True, exist_ok=True)
    spec = {"runs": str(tmp_path / "runs"), "out": str(tmp_path), "fly": fly, "t": t,
            "do": do, "mount": mount, **more}  # fmt: skip
    p = subprocess.run(["unshare", "-m", "-n", sys.executable, str(RIG), json.dumps(spec)],
                       capture_output=True, text=True, timeout=600)  # fmt: skip
    assert p.returncode == 0, p.stderr[-3000:]
    res = json.loads(p.stdout)
    assert res["left"] == [], res["left"]  # no process of the flight is left
    if do:
        assert res["trigger_t"] is not None and res["trigger_t"] >= t, res["stderr"][-2000:]
    return res


def landed(res: dict) -> None:
    """world.csv ends with the vehicle on the ground, disarmed."""
    row = res["world_last"]
    assert row["armed"] == "0" and abs(float(row["down"])) < 0.3, row


def ending(res: dict) -> str:
    """The "How it ended" section (in summary.md, or on stdout when it could not be written)."""
    text = res["summary.md"] or ""
    assert "## How it ended" in text, text
    return text.split("## How it ended", 1)[1]


@needs_namespaces
@pytest.mark.slow
@pytest.mark.parametrize("sig,rc", [("SIGTERM", 143), ("SIGHUP", 129), ("SIGINT", 130)])
def test_a_signal_to_fly_hands_over_and_lands(tmp_path, sig, rc):
    """SIGTERM / SIGHUP / SIGINT to `fly` at t >= 20 s in OFFBOARD: the companion hands the
    vehicle to the autopilot (LAND), the simulator steps on alone until it has disarmed on the
    ground; fly exits 128 + signum and summary.md says why."""
    res = way_out(tmp_path, f"fly:{sig}")
    assert res["rc"] == rc, res["stderr"][-2000:]
    landed(res)
    why = "Ctrl-C" if sig == "SIGINT" else sig
    assert f"**Why it ended:** interrupted ({why})" in res["summary.md"]
    end = ending(res)
    assert "handed to the autopilot: LAND" in end
    stats = json.loads(res["sim_stats.json"])["after_companion"]
    assert stats["ended"] == "disarmed" and stats["mode"] == "LAND" and not stats["armed"]


CTRL_C_AFTER_S = (0.05, 0.2, 0.4, 0.6, 0.8, 1.0, 1.3, 1.6, 2.0, 2.5, 3.0, 4.0, 5.0, 6.5, 8.0)
"""Moments of wall time after `fly` starts: its interpreter's imports, its checks, the run
folder, the children's start, the recorder's Zenoh session, the go, the take-off, the flight
(which of them each one hits depends on the machine's load: all must end the same way)."""


@needs_namespaces
@pytest.mark.slow
@pytest.mark.parametrize("after_s", CTRL_C_AFTER_S)
def test_ctrl_c_at_any_moment_is_interrupted_exit_130_and_leaves_nothing(tmp_path, after_s):
    """SIGINT to `fly`'s process group (a terminal's Ctrl-C) at a moment of wall time: exit
    130, "INTERRUPTED" said, never "ABORTED" (a child's end is not the flight's reason when
    the user stopped it); with a run folder, summary.md says INTERRUPTED and how it ended, and
    the plot is drawn from what was recorded; no process of the flight is left."""
    fly = ["--duration", "30", "--speedup", "2", "--instance", "61"]
    spec = {"runs": str(tmp_path / "runs"), "out": str(tmp_path), "fly": fly, "t": 0,
            "do": "group:SIGINT", "after_s": after_s}  # fmt: skip
    p = subprocess.run(["unshare", "-m", "-n", sys.executable, str(RIG), json.dumps(spec)],
                       capture_output=True, text=True, timeout=600)  # fmt: skip
    assert p.returncode == 0, p.stderr[-3000:]
    res = json.loads(p.stdout)
    said = (res["stdout"] or "") + (res["stderr"] or "")
    assert res["left"] == [], res["left"]
    assert res["fly_running_at_trigger"], said[-2000:]  # the flight had not ended by itself
    ran = re.findall(r'/skyherd/([\w/]+)\.py", line (\d+)', said)  # skyherd's own frames
    if res["rc"] in (1, -2) and res["run_dir"] == "None" and "INTERRUPTED" not in said:
        # the interpreter's own start-up (its site module, runpy, the editable install's
        # import finder) or the package's __init__ files and scripts/cli.py's own `import
        # signal`, before the line that keeps signals could run: Python's KeyboardInterrupt,
        # exit 1 or by SIGINT (a shell's $? is then 130); nothing of skyherd ran, nothing was
        # made (seen at 0.05 s with two busy processes, and at 0.05/0.2 s at a load of 20)
        # (killed by SIGINT's default before the interpreter set its handler: nothing said)
        assert "KeyboardInterrupt" in said or (res["rc"] == -2 and not said.strip()), said
        keeps = next(i for i, ln in enumerate(CLI.read_text().splitlines(), 1)
                     if "signal.signal(_sig, _keep_early)" in ln)  # fmt: skip
        before = {"__init__", "scripts/__init__"}
        assert all(f in before or (f == "scripts/cli" and int(n) < keeps) for f, n in ran), said
        return
    assert res["rc"] == 130, said[-3000:]
    assert "INTERRUPTED: interrupted (Ctrl-C)" in said and "ABORTED" not in said, said[-3000:]
    assert "Traceback" not in said, said[-3000:]
    if res["run_dir"] != "None":  # the folder was made: it says how the flight ended
        assert res["summary.md"].startswith("# skyherd fly: INTERRUPTED"), res["summary.md"]
        assert "**Why it ended:** interrupted (Ctrl-C)" in res["summary.md"]
        assert "## How it ended" in res["summary.md"]
        assert "groundair.png" in res["files"], res["files"]
    else:
        assert "nothing was" in said, said[-2000:]


@needs_namespaces
@pytest.mark.slow
def test_sigterm_to_a_formation_hands_every_vehicle_over(tmp_path):
    """The formation (K = 4 vehicles in 2 simulator processes, one companion): SIGTERM to `fly`
    at t >= 15 s in OFFBOARD; the companion hands every vehicle to its autopilot, both
    simulators step on alone until their vehicles have disarmed."""
    fly = ["--mission", "formation", "--agents", "4", "--sims", "2", "--speedup", "0",
           "--instance", "124"]  # fmt: skip
    spec = {"world": "uav0/world.csv", "read": [f"uav{k}/sim_stats.json" for k in range(4)]}
    res = way_out(tmp_path, "fly:SIGTERM", fly=fly, t=15.0, **spec)
    assert res["rc"] == 143, res["stderr"][-2000:]
    end = ending(res)
    for k in range(4):
        assert f"uav{k}: handed to the autopilot: LAND" in end
        a = json.loads(res[f"uav{k}/sim_stats.json"])["after_companion"]
        assert a["ended"] == "disarmed" and abs(a["altitude_m"]) < 0.3, a


@needs_namespaces
@pytest.mark.slow
def test_kill_9_of_fly_leaves_no_process_and_the_vehicle_landed(tmp_path):
    """kill -9 of `fly`: its children get their parent-death signal SIGUSR1 (the companion
    hands over; the simulator steps on alone until disarmed) and end; the simulator writes how the
    flight ended into summary.md. Then the same instance flies again, undisturbed."""
    res = way_out(tmp_path, "fly:SIGKILL")
    assert res["rc"] == -9
    landed(res)
    end = ending(res)
    assert "`skyherd fly` died" in end and "its parent died" in end
    assert "handed to the autopilot: LAND" in end
    again = way_out(tmp_path / "again", "", fly=[*FLY[:1], "5", *FLY[2:]])
    assert again["rc"] == 0, again["stderr"][-2000:]
    assert "completed" in again["summary.md"]
    landed(again)


_PDEATH_CHILD = """
import os, sys, time
from pathlib import Path
from skyherd.mission.handover import StopRequest
from skyherd.runio.run import Interrupted
from skyherd.mission.handover import stop_on_signals
out, parent = Path(sys.argv[1]), os.getppid()
stop = StopRequest()
(out / "pid").write_text(str(os.getpid()))
try:
    with stop_on_signals(stop):
        os.replace(out / "pid", out / "ready")  # whole (the parent acts when it is there)
        time.sleep(60)  # the flight's loop, waiting for its next tick
except Interrupted:
    pass
(out / "loop_ended").write_text(str(stop.signum))
while os.getppid() == parent:  # writing its records when the parent's last thread exits
    time.sleep(0.01)
time.sleep(0.2)  # that thread's repeat of the signal has arrived
(out / "records").write_text("written")
"""

_PDEATH_PARENT = """
import os, sys, threading, time
from pathlib import Path
from skyherd.runio.launch import PARENT_DEATH, start
out = Path(sys.argv[1])
def until(name):
    while not (out / name).exists():
        time.sleep(0.01)
def spawn():  # this thread forks the child, then exits: the first parent-death signal
    start("companion", [sys.executable, "-c", sys.argv[2], str(out)], None,
          parent_death=PARENT_DEATH)
    until("ready")
t = threading.Thread(target=spawn)
t.start()
t.join()
until("loop_ended")
os._exit(0)  # the last thread: the signal again, after the companion's loop has ended
"""


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="PR_SET_PDEATHSIG is Linux's")
def test_a_repeated_parent_death_signal_after_the_loop_does_not_end_the_companion(tmp_path):
    """The kernel sends a parent-death signal once per thread of the dying parent (a thread
    that exits hands its children to the next one and signals them again); under load the
    last one comes after the companion's loop has ended, while it writes companion.json (seen
    in test_kill_9_of_fly: the companion ended by it, no companion.json). Here a thread of the
    parent forks the companion-like child and exits (the first signal: the loop ends), then
    the parent's last thread exits (the second): the child lives on and writes its records."""
    r = subprocess.run([sys.executable, "-c", _PDEATH_PARENT, str(tmp_path), _PDEATH_CHILD],
                       capture_output=True, text=True, timeout=120)  # fmt: skip
    assert r.returncode == 0, r.stderr
    pid = int((tmp_path / "ready").read_text())
    for _ in range(6000):  # until the child has ended (60 s of wall time at most)
        if not Path(f"/proc/{pid}").exists() or "Z" in _state(pid):
            break
        time.sleep(0.01)
    assert (tmp_path / "loop_ended").read_text() == str(int(signal.SIGUSR1))
    assert (tmp_path / "records").read_text() == "written"


def _state(pid: int) -> str:
    try:
        return Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[0]
    except (OSError, IndexError):
        return "X"


@needs_namespaces
@pytest.mark.slow
def test_kill_9_of_the_companion_leaves_the_vehicle_in_its_failsafe(tmp_path):
    """kill -9 of the companion: `fly` sees it gone and sends the simulator SIGUSR1; the vehicle
    steps on alone, the autopilot's offboard-loss failsafe (COM_OF_LOSS_T 0.5 s → HOLD) acts,
    and after alone_s (30 s of simulation time) the simulator stops and reports it."""
    res = way_out(tmp_path, "companion:SIGKILL")
    assert res["rc"] == 1
    a = json.loads(res["sim_stats.json"])["after_companion"]
    modes = [m["mode"] for m in a["modes"]]
    assert modes[:2] == ["OFFBOARD", "HOLD"] and a["modes"][1]["t"] - a["t_gone_s"] <= 1.0, a
    assert a["mode"] == "HOLD" and a["armed"] and a["altitude_m"] > 10 and a["span_s"] == 30.0
    row = res["world_last"]
    assert row["mode"] == "HOLD" and row["armed"] == "1"
    assert abs(float(row["t"]) - (a["t_gone_s"] + a["span_s"])) < 1e-3  # world.csv ends there
    assert "the companion exited with code -9 (killed by SIGKILL)" in res["summary.md"]
    assert "at the end HOLD, armed" in ending(res)


@needs_namespaces
@pytest.mark.slow
def test_kill_9_of_the_simulator_ends_the_companion_and_says_where_the_vehicle_was(tmp_path):
    """kill -9 of the simulator: the vehicle is gone with it. `fly` stops the companion (it
    finds no tick within 3 s of wall time and exits), and the summary says which process died
    and where the vehicle was when it did (world.csv's last row)."""
    res = way_out(tmp_path, "sim:SIGKILL")
    assert res["rc"] == 1
    assert "the simulator sim exited with code -9 (killed by SIGKILL)" in res["summary.md"]
    end = ending(res)
    assert "world.csv ends at t = " in end and "no tick from the vehicle" in end


@needs_namespaces
@pytest.mark.slow
def test_a_full_disk_cuts_the_records_and_the_vehicle_lands(tmp_path):
    """A 700 KiB runs folder (tmpfs): the streams stop when 256 KiB are left (kept for the end
    files), each says so once on stderr; the flight goes on and lands; the summary lists what
    was cut, with the reason and the records dropped. The judge cannot see what the cut
    records lost (world.csv, the truth): the flight cannot pass, exit 1 naming the records."""
    res = way_out(tmp_path, "", mount="tmpfs:700k", fly=FLY[:-1])  # with flight.mcap
    assert res["rc"] == 1, res["stderr"][-2000:]
    out = res["stdout"]
    assert "first failed check: records: " in out and "world.csv (sim) cut" in out
    assert "records cut" in res["stderr"] and "No space left on device" in res["stderr"]
    a = json.loads(res["sim_stats.json"])["after_companion"]
    assert not a["armed"] and abs(a["altitude_m"]) < 0.3  # landed (world.csv itself was cut)
    end = ending(res)
    cut = [ln for ln in end.splitlines() if ln.startswith("- records cut: ")]
    for name in ("flight.mcap (fly)", "metrics.csv (companion)", "world.csv (sim)"):
        assert any(name in ln for ln in cut), (name, cut)
    assert all("No space left on device" in ln for ln in cut)
    comp = json.loads(res["companion.json"])
    assert comp["outcome"] == "completed" and comp["records_cut"]
    written = res["decisions.jsonl"].splitlines()  # what was written before the cut is whole
    assert written and all(json.loads(ln)["t"] > 0 for ln in written)


@needs_namespaces
@pytest.mark.slow
def test_a_disk_filled_by_another_process_mid_flight_cuts_everything_and_the_vehicle_lands(
    tmp_path,
):
    """Another process fills the runs folder's disk at t >= 20 s, the reserve included: every
    stream is cut (ENOSPC), the flight goes on and lands; summary.md cannot be written, so
    `fly` says how the flight ended on stdout and why the summary is missing on stderr (the
    simulator's final stats come from its output, which `fly` keeps in memory), and exits 1:
    a run whose report is lost is not a passed test."""
    res = way_out(tmp_path, "fill", mount="tmpfs:4m")
    assert res["rc"] == 1, res["stderr"][-2000:]  # flown and landed, but its report is lost
    assert "skyherd fly: the report was not written (OSError" in res["stderr"]
    assert "records cut" in res["stderr"]
    assert "summary.md: not written (No space left on device)" in res["stderr"]
    out = res["stdout"].split("How it ended:", 1)[1]
    assert (
        "at the end LAND, disarmed, altitude 0.0 m" in out
        or "disarmed when the companion ended" in out
    ), out
    assert "records cut: world.csv (sim)" in out, out


@needs_namespaces
@pytest.mark.slow
def test_a_read_only_runs_folder_is_refused_before_take_off(tmp_path):
    """A read-only runs folder (a read-only bind mount: root ignores chmod): exit 2 with one
    line saying what to do; nothing starts, nothing is left."""
    res = way_out(tmp_path, "", mount="ro")
    assert res["rc"] == 2
    err = res["stderr"].strip().splitlines()
    assert len(err) == 1 and "Read-only file system" in err[0] and "writable --runs-dir" in err[0]
    assert res["run_dir"] == "None"


def test_a_policy_of_the_wrong_shape_is_refused_before_take_off(tmp_path, capsys):
    """A policy file whose input or output size does not fit the ground-air task (14 inputs,
    7 actions): exit 2 with one line saying what to do; no run folder, no child started."""
    from skyherd.policy.dqn import MLPPolicy
    from skyherd.task.observation import OBS_DIM
    from skyherd.task.params import N_ACTIONS

    assert (OBS_DIM, N_ACTIONS) == (14, 7)
    rng = np.random.default_rng(0)
    for n_in, n_out in ((10, 7), (14, 5)):
        path = tmp_path / f"p{n_in}x{n_out}.npz"
        MLPPolicy([rng.normal(size=(16, n_in)), rng.normal(size=(n_out, 16))],
                  [np.zeros(16), np.zeros(n_out)], {"format": "skyherd-mlp-policy/1"}).save(path)  # fmt: skip
        runs = tmp_path / "runs"
        assert main(["fly", "--policy", str(path), "--runs-dir", str(runs)]) == 2
        err = capsys.readouterr().err.strip().splitlines()
        assert len(err) == 1, err
        assert f"takes {n_in} inputs and gives {n_out} actions" in err[0]
        assert "14 inputs and 7 actions" in err[0] and "skyherd train ab" in err[0]
        assert not runs.exists()


def test_a_runs_folder_that_cannot_be_written_is_refused_before_take_off(tmp_path, capsys):
    """A runs folder that is a file (or read-only, or nearly full): exit 2, one line."""
    blocker = tmp_path / "file"
    blocker.write_text("x")
    assert main(["fly", "--runs-dir", str(blocker / "runs")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "cannot make the run folder" in err[0] and "--runs-dir" in err[0]


_FSIZE_CHILD = """
import resource, signal, sys
from skyherd.runio import JsonlWriter
signal.signal(signal.SIGXFSZ, signal.SIG_IGN)  # a write past the limit fails with EFBIG instead
resource.setrlimit(resource.RLIMIT_FSIZE, (1000, 1000))
w = JsonlWriter(sys.argv[1])
for i in range(20):
    w.write({"i": i, "pad": "x" * 280})
print(w.appender.error, w.appender.dropped)
"""


def test_a_record_that_fails_half_way_is_cut_back_off_the_file(tmp_path):
    """A file that can take 1,000 bytes (RLIMIT_FSIZE, in a child process): the fourth record
    of ~300 bytes is written in part, then fails; the file is cut back to the three whole
    records, the stream says why and counts the 17 it dropped."""
    path = tmp_path / "events.jsonl"
    r = subprocess.run([sys.executable, "-c", _FSIZE_CHILD, str(path)], capture_output=True,
                       text=True, timeout=60)  # fmt: skip
    assert r.returncode == 0, r.stderr
    assert r.stdout.split()[-1] == "17" and "File too large" in r.stdout
    assert "records cut (File too large)" in r.stderr
    lines = path.read_text().splitlines()
    assert [json.loads(ln)["i"] for ln in lines] == [0, 1, 2]
    assert path.stat().st_size == sum(len(ln) + 1 for ln in lines) < 1000


def test_streams_stop_at_the_reserve_and_end_files_never_raise(tmp_path, capsys):
    """A stream stops when less than its reserve would be left free (here a reserve larger than
    any disk); the end files' writer reports a folder it cannot write instead of raising."""
    from skyherd.runio import try_write_text
    from skyherd.runio.space import Appender

    a = Appender(tmp_path / "x.csv", reserve=1 << 62)
    assert not a.active and a.error.startswith("No space left on device") and not a.write("t\n")
    assert a.dropped == 1 and not (tmp_path / "x.csv").read_bytes()
    assert "x.csv: records cut (No space left on device" in capsys.readouterr().err
    why = try_write_text(tmp_path / "missing" / "summary.md", "text")
    assert why is not None and "No such file or directory" in why
    assert try_write_text(tmp_path / "summary.md", "text") is None


_TIMED_FLY = """
import json, os, socket, subprocess, sys, threading, time
spec = json.loads(sys.argv[1])
subprocess.run(["ip", "link", "set", "lo", "up"], check=True)
if spec.get("listen"):  # another program on the port
    s = socket.socket()
    s.bind(("127.0.0.1", spec["listen"]))
    s.listen()
argv = [sys.executable, "-m", "skyherd.scripts.cli", "fly", "--runs-dir", spec["runs"], *spec["fly"]]
p = subprocess.Popen(argv, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
lines = []
def pump(f, tag):
    for ln in f:
        lines.append([time.time(), tag, ln.rstrip("\\n")])
ts = [threading.Thread(target=pump, args=(p.stdout, "out")),
      threading.Thread(target=pump, args=(p.stderr, "err"))]
for t in ts:
    t.start()
rc = p.wait(timeout=600)
for t in ts:
    t.join()
def left():
    out = []
    for d in os.listdir("/proc"):
        try:
            text = open(f"/proc/{d}/cmdline", "rb").read().replace(b"\\0", b" ").decode()
        except OSError:
            continue
        if d.isdigit() and int(d) != os.getpid() and "-m skyherd.scripts.cli" in text and spec["runs"] in text:
            out.append(text)
    return out
t_end = time.time()
while left() and time.time() - t_end < 60:
    time.sleep(0.05)
logs = {}
for d in os.listdir(spec["runs"]):
    for name in ("sim.log",):
        path = os.path.join(spec["runs"], d, name)
        if os.path.exists(path):
            logs[name] = [os.path.getmtime(path), open(path).read()]
print(json.dumps({"rc": rc, "lines": lines, "logs": logs, "left": left()}))
"""


def _timed_fly(tmp_path: Path, fly: list[str], listen: int | None = None) -> dict:
    """`fly` in a private network namespace (another program listening on `listen`), each line
    of its output with the wall time it arrived; sim.log's text and last change."""
    spec = {"runs": str(tmp_path / "runs"), "fly": fly, "listen": listen}
    (tmp_path / "runs").mkdir(parents=True)
    p = subprocess.run(["unshare", "-n", sys.executable, "-c", _TIMED_FLY, json.dumps(spec)],
                       capture_output=True, text=True, timeout=900,
                       cwd=Path(__file__).resolve().parents[2])  # fmt: skip
    assert p.returncode == 0, p.stderr[-3000:]
    return json.loads(p.stdout)


@needs_namespaces
@pytest.mark.slow
def test_a_simulator_that_dies_is_said_within_a_second_with_its_own_last_line_wallclock(tmp_path):
    """Another program listens on instance 62's Zenoh port (7447 + 62): the simulator exits 2
    with one line naming the port and what to do (no Rust source path); `fly` says so on
    stderr, with that line, within a second of wall time of the simulator's last line in
    sim.log (its relay writes the line as it comes), stops the companion and ends 1."""
    res = _timed_fly(tmp_path, ["--instance", "62", "--speedup", "2"], listen=7509)
    assert res["rc"] == 1 and res["left"] == [], res["left"]
    said = [ln for ln in res["lines"] if "skyherd fly: the simulator sim exited" in ln[2]]
    assert said, res["lines"]
    t_said, _, line = said[0]
    assert "code 2" in line and "Zenoh port 7509 on 127.0.0.1 is taken" in line, line
    assert "--instance" in line
    t_log, log = res["logs"]["sim.log"]
    assert log.strip().splitlines()[-1] in line
    assert t_said - t_log < 1.0, (t_said, t_log)
    text = "\n".join(ln[2] for ln in res["lines"])
    assert ".rs:" not in text and ".cargo" not in text and "Traceback" not in text, text


@needs_namespaces
@pytest.mark.slow
def test_nothing_listening_at_the_connect_address_says_so(tmp_path):
    """`fly --connect tcp:127.0.0.1:1` with nothing listening: the companion says nothing is
    listening there (not "another companion using that port"), and `fly` says at once that
    the companion ended, and ends 1 with no process left behind."""
    res = _timed_fly(tmp_path, ["--connect", "tcp:127.0.0.1:1", "--instance", "62"])
    assert res["rc"] == 1 and res["left"] == [], res["left"]
    err = [ln[2] for ln in res["lines"] if ln[1] == "err"]
    refused = [ln for ln in err if "nothing is listening at tcp:127.0.0.1:1" in ln]
    assert refused and "start the autopilot first" in refused[0], err
    assert not any("another companion" in ln for ln in err), err
    assert any("skyherd fly: the companion exited with code 2" in ln for ln in err), err
