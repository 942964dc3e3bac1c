"""One way out of `skyherd fly`, run for tests/e2e/test_fly_waysout.py inside its own mount and
network namespaces (`unshare -m -n`, as root): mount the runs folder (a small tmpfs, or a bind
mount that can be made read-only), start `fly`, wait until world.csv shows the vehicle airborne
in OFFBOARD at simulation time t >= T, then do one thing (a signal to `fly` or to a child, or
fill the disk), and report as JSON on stdout what is left: fly's exit code and
output, the processes of the flight still running (found by their argv, as `kill -9` of `fly`
reparents them), world.csv's last row, summary.md, companion.json and sim_stats.json (read
before the namespace and its tmpfs go).

    python tests/waysout_rig.py '{"runs": DIR, "fly": [...], "t": 20, "do": "fly:SIGTERM"}'

`after_s`: instead of waiting for world.csv, act this many seconds of wall time after `fly`
started, whatever it is doing then (starting its children, flying, ending); "group:SIG" sends
SIG to `fly`'s process group, as a terminal's Ctrl-C does (`fly` leads its own group here).
`world`: the world.csv watched (default world.csv; a formation's uav0/world.csv); `read`:
more files of the run folder to return. `do`: "fly:SIG", "companion:SIG", "sim:SIG", "fill" (another process fills the disk) or ""
(fly to the end); `mount`: "" (none), "tmpfs:SIZE", or "ro" (a read-only bind mount).
"""

from __future__ import annotations

import csv
import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
WALL_LIMIT_S = 400.0  # the whole scenario, a generous wall-clock bound
LEFT_WAIT_S = 150.0  # wall time for the children to end after `fly` did


def flight_pids(runs: str) -> dict[int, str]:
    """Processes of this flight: a `scripts.cli` command whose argv names the runs folder."""
    out = {}
    for d in os.listdir("/proc"):
        if not d.isdigit() or int(d) == os.getpid():
            continue
        try:
            argv = Path(f"/proc/{d}/cmdline").read_bytes().split(b"\0")
        except OSError:
            continue
        text = b" ".join(argv).decode(errors="replace")
        if "skyherd.scripts.cli" in text and runs in text:
            out[int(d)] = text
    return out


def fill(path: Path) -> None:
    """Write zeros to `path` until the file system is full."""
    block = bytes(64 * 1024)
    with open(path, "wb", buffering=0) as f:
        try:
            while True:
                f.write(block)
        except OSError:
            pass
        try:
            while True:
                f.write(b"\0")
        except OSError:
            pass


def last_row(path: Path) -> dict | None:
    try:
        with open(path, newline="") as f:
            rows = [r for r in csv.DictReader(f) if r.get("armed") in ("0", "1")]
    except OSError:
        return None
    return rows[-1] if rows else None


def read(path: Path) -> str | None:
    try:
        return path.read_text()
    except OSError:
        return None


def main(spec: dict) -> dict:
    runs = spec["runs"]
    Path(runs).mkdir(parents=True, exist_ok=True)
    subprocess.run(["ip", "link", "set", "lo", "up"], check=True)
    mount = spec.get("mount", "")
    if mount.startswith("tmpfs:"):
        subprocess.run(
            ["mount", "-t", "tmpfs", "-o", f"size={mount[6:]}", "tmpfs", runs], check=True
        )
    elif mount == "ro":  # a read-only bind mount of the folder on itself
        subprocess.run(["mount", "--bind", runs, runs], check=True)
        subprocess.run(["mount", "-o", "remount,ro,bind", runs], check=True)
    out_dir = Path(spec["out"])
    fly_out, fly_err = open(out_dir / "fly.out", "wb"), open(out_dir / "fly.err", "wb")
    argv = [sys.executable, "-m", "skyherd.scripts.cli", "fly", "--runs-dir", runs, *spec["fly"]]
    env = dict(os.environ, PYTHONPATH=str(ROOT))
    # SIGINT's default, as a terminal's foreground job has it: a rig started as a background
    # job of a non-interactive shell inherits SIGINT ignored, and a Ctrl-C before `fly`'s
    # interpreter set its own handler was then lost (the flight flew on to its end)
    kept = signal.signal(signal.SIGINT, signal.SIG_DFL)
    try:
        fly = subprocess.Popen(argv, stdout=fly_out, stderr=fly_err, cwd=ROOT, env=env,
                               process_group=0)  # fmt: skip
    finally:
        signal.signal(signal.SIGINT, kept)
    t0 = time.monotonic()
    res: dict = {"trigger_t": None}
    do = spec.get("do", "")
    run_dir = None
    if spec.get("after_s") is not None:  # a wall-clock moment, whatever `fly` is doing
        time.sleep(spec["after_s"])
        res["trigger_t"] = -1.0
        res["fly_running_at_trigger"] = fly.poll() is None
        do_wall = do
        do = ""  # skip the wait on world.csv
    while do and fly.poll() is None and time.monotonic() - t0 < WALL_LIMIT_S:
        found = sorted(Path(runs).glob(f"*/{spec.get('world', 'world.csv')}"))
        row = last_row(found[0]) if found else None
        if (
            row
            and float(row["t"]) >= spec["t"]
            and row["mode"] == "OFFBOARD"
            and float(row["down"]) < -5
        ):
            run_dir = Path(runs) / found[0].relative_to(runs).parts[0]
            res["trigger_t"] = float(row["t"])
            break
        time.sleep(0.01)
    if spec.get("after_s") is not None:
        do = do_wall
    if res["trigger_t"] is not None:
        target, _, sig = do.partition(":")
        if target == "group":
            os.killpg(fly.pid, getattr(signal, sig))
        elif target == "fill":  # another process fills the disk, the reserve included
            fill(Path(runs) / "filler")
        elif target == "fly":
            os.kill(fly.pid, getattr(signal, sig))
        else:
            for pid, text in flight_pids(runs).items():
                if f"skyherd.scripts.cli {target} " in text:
                    os.kill(pid, getattr(signal, sig))
    try:
        res["rc"] = fly.wait(max(1.0, WALL_LIMIT_S - (time.monotonic() - t0)))
    except subprocess.TimeoutExpired:
        fly.kill()
        res["rc"] = "timeout"
    t_end = time.monotonic()
    while flight_pids(runs) and time.monotonic() - t_end < LEFT_WAIT_S:
        time.sleep(0.05)
    left = flight_pids(runs)
    res["left"] = list(left.values())
    res["left_after_s"] = round(time.monotonic() - t_end, 2)
    for pid in left:  # leave nothing behind, whatever the test says
        try:
            os.kill(pid, signal.SIGKILL)
        except OSError:
            pass
    fly_out.close()
    fly_err.close()
    res["stdout"] = read(out_dir / "fly.out")
    res["stderr"] = read(out_dir / "fly.err")
    run_dir = run_dir or next(iter(sorted(Path(runs).glob("*-fly"))), None)
    res["run_dir"] = str(run_dir)
    if run_dir is not None:
        res["world_last"] = last_row(run_dir / spec.get("world", "world.csv"))
        names = ["summary.md", "companion.json", "sim_stats.json", "sim.log", "decisions.jsonl"]
        for name in names + spec.get("read", []):
            res[name] = read(run_dir / name)
        res["files"] = sorted(p.name for p in run_dir.iterdir())
    return res


if __name__ == "__main__":
    print(json.dumps(main(json.loads(sys.argv[1]))))
