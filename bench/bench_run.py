"""`make run`'s job (`skyherd fly --speedup 0`) in CPU time, per process, A/B alternated.

    .venv/bin/python bench/bench_run.py [--runs 3] [--baseline DIR|GIT-REF] [--instance 70]

Runs the real command (`python -m skyherd.scripts.cli fly --speedup 0`) `--runs` times from
this tree and, with `--baseline` (another skyherd source tree, or a git ref of this repository,
e.g. `main`, unpacked by `git archive` into a temporary folder), as many times from that tree,
alternated (A B A B ...), so both see the same machine load. A warm start is measured: each
tree flies `--warmup` times first, uncounted (numba's cache and Python's bytecode written).
The children run as `make run` runs from an ordinary shell, with Python's bytecode cache: the
bench drops PYTHONDONTWRITEBYTECODE from their environment (set, every skyherd module is
compiled from source in each of the three processes; `--keep-env` keeps it). For each run:
the CPU time of the whole job (this process's RUSAGE_CHILDREN after the parent `fly` is
reaped: fly + sim + companion, exact) and of each of the three processes (user + system time
read from /proc/PID/stat every 20 ms while it runs: the last reading before the process ends,
so each may be up to ~20 ms short; the total is exact), and the wall time; beside each run,
the CPU of its groundair.png drawn again from the run folder in a fresh process (what the plot
costs: matplotlib's import and the drawing). Prints a table per run and the medians, and the
ratio this / baseline. Run it inside `unshare -n` (the flight's ports are the instance's).
"""

from __future__ import annotations

import argparse
import os
import resource
import statistics
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path

HERE = Path(__file__).resolve().parents[1]
CLK_TCK = os.sysconf("SC_CLK_TCK")


def _cpu_s(pid: int) -> tuple[float, str] | None:
    """(user + system CPU [s], argv) of a live process, None when it is gone."""
    try:
        stat = Path(f"/proc/{pid}/stat").read_text()
        argv = Path(f"/proc/{pid}/cmdline").read_bytes().split(b"\0")
    except OSError:
        return None
    f = stat[stat.rindex(")") + 2 :].split()
    return (int(f[11]) + int(f[12])) / CLK_TCK, " ".join(a.decode() for a in argv)


def _children(pid: int) -> list[int]:
    try:
        text = Path(f"/proc/{pid}/task/{pid}/children").read_text()
    except OSError:
        return []
    return [int(x) for x in text.split()]


def _role(argv: str) -> str:
    for role in ("companion", "sim", "fly"):
        if f"skyherd.scripts.cli {role}" in argv:
            return role
    return "other"


# groundair.png drawn again from a run folder in a fresh process: its CPU [s] (matplotlib's
# import and the drawing; the records are read before the clock starts)
REDRAW = """
import json, os, sys
from pathlib import Path
run, out = Path(sys.argv[1]), Path(sys.argv[2])
from skyherd.report import fly as r
args = (r._jsonl(run / "decisions.jsonl"), r._rows(run / "metrics.csv"), r._rows(run / "world.csv"),
        r._config(run).get("envelope"), json.loads((run / "companion.json").read_text())["authority"])
t = os.times()
from skyherd.report.plots_flight import plot_groundair
plot_groundair(out, *args)
u = os.times()
print(u.user + u.system - t.user - t.system)
"""


def plot_cpu_s(tree: Path, run: Path, env: dict) -> float:
    """CPU [s] of groundair.png made again from `run` by `tree`'s report in a fresh process,
    with OpenBLAS as `fly` runs it (scripts/cli.py: no worker threads; with them, matplotlib's
    import cost ~0.1 CPU s more on an idle machine, 0.26 against 0.15, less on a loaded one)."""
    out = Path(tempfile.mkdtemp(prefix="skyherd-benchplot-"))
    env = {"OPENBLAS_NUM_THREADS": "1", **env}
    text = subprocess.run([sys.executable, "-c", REDRAW, str(run), str(out)], cwd=tree, env=env,
                          capture_output=True, text=True, check=True).stdout  # fmt: skip
    return float(text.split()[-1])


def fly_once(
    tree: Path, instance: int, extra: list[str] = (), keep_env: bool = False
) -> dict[str, float]:
    """One `skyherd fly --speedup 0` from source tree `tree`: CPU [s] of fly, sim, companion,
    the job (exact), wall [s], and the CPU [s] of its groundair.png drawn again (plot_cpu_s)."""
    root = Path(tempfile.mkdtemp(prefix="skyherd-benchrun-"))
    env = dict(os.environ, PYTHONPATH=str(tree))
    if not keep_env:
        env.pop("PYTHONDONTWRITEBYTECODE", None)
    cmd = [sys.executable, "-m", "skyherd.scripts.cli", "fly", "--speedup", "0",
           "--instance", str(instance), "--runs-dir", str(root), *extra]  # fmt: skip
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    t0 = time.monotonic()
    proc = subprocess.Popen(cmd, cwd=tree, env=env, stdout=subprocess.DEVNULL,
                            stderr=subprocess.DEVNULL)  # fmt: skip
    seen: dict[int, tuple[float, str]] = {}
    done = threading.Event()

    def watch() -> None:
        while not done.is_set():
            for pid in [proc.pid, *_children(proc.pid)]:
                got = _cpu_s(pid)
                if got is not None:  # a zombie still has its CPU, no longer its argv
                    seen[pid] = (got[0], got[1] or seen.get(pid, (0.0, ""))[1])
            time.sleep(0.02)

    t = threading.Thread(target=watch, daemon=True)
    t.start()
    rc = proc.wait()
    done.set()
    t.join()
    wall = time.monotonic() - t0
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    job = (after.ru_utime + after.ru_stime) - (before.ru_utime + before.ru_stime)
    runs = sorted(root.glob("*-fly"))
    plot = plot_cpu_s(tree, runs[0], env) if rc == 0 and runs else float("nan")
    out = {"fly": 0.0, "sim": 0.0, "companion": 0.0, "job": job, "wall": wall, "rc": rc,
           "plot": plot}  # fmt: skip
    for cpu, argv in seen.values():
        role = _role(argv)
        if role in out:
            out[role] += cpu
    return out


def _tree(baseline: str) -> Path:
    """The baseline's source tree: a folder as given, or a git ref unpacked (git archive)."""
    if Path(baseline).is_dir():
        return Path(baseline).resolve()
    out = Path(tempfile.mkdtemp(prefix="skyherd-baseline-"))
    archive = subprocess.run(["git", "-C", str(HERE), "archive", baseline], check=True,
                             capture_output=True).stdout  # fmt: skip
    subprocess.run(["tar", "-x", "-C", str(out)], input=archive, check=True)
    return out


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawTextHelpFormatter)
    ap.add_argument("--runs", type=int, default=3, help="runs per tree")
    ap.add_argument("--baseline", default=None, help="a baseline source tree, or a git ref")
    ap.add_argument("--warmup", type=int, default=1, help="uncounted runs per tree first")
    ap.add_argument("--keep-env", action="store_true", help="keep PYTHONDONTWRITEBYTECODE")
    ap.add_argument("--instance", type=int, default=70)
    ap.add_argument("--fly-args", default="", help="more arguments for fly (one string)")
    a = ap.parse_args(argv)
    trees = [("this", HERE)] + ([("baseline", _tree(a.baseline))] if a.baseline else [])
    for _name, tree in trees:
        for _ in range(a.warmup):
            fly_once(tree, a.instance, a.fly_args.split(), a.keep_env)
    res: dict[str, list[dict]] = {name: [] for name, _ in trees}
    print("| tree | run | fly CPU s | sim CPU s | companion CPU s | job CPU s (exact) | wall s | "
          "exit | groundair.png CPU s (again) |")  # fmt: skip
    print("|---|---|---|---|---|---|---|---|---|")
    for k in range(a.runs):
        for name, tree in trees if k % 2 == 0 else trees[::-1]:
            r = fly_once(tree, a.instance, a.fly_args.split(), a.keep_env)
            res[name].append(r)
            print(f"| {name} | {k} | {r['fly']:.2f} | {r['sim']:.2f} | {r['companion']:.2f} | "
                  f"{r['job']:.2f} | {r['wall']:.1f} | {r['rc']} | {r['plot']:.2f} |", flush=True)  # fmt: skip
    print("\nmedians:\n")
    print("| tree | fly CPU s | sim CPU s | companion CPU s | job CPU s | wall s | "
          "groundair.png CPU s |")  # fmt: skip
    print("|---|---|---|---|---|---|---|")
    med = {}
    for name, rs in res.items():
        keys = ("fly", "sim", "companion", "job", "wall", "plot")
        med[name] = m = {k: statistics.median(r[k] for r in rs) for k in keys}
        print(f"| {name} | {m['fly']:.2f} | {m['sim']:.2f} | {m['companion']:.2f} | "
              f"{m['job']:.2f} | {m['wall']:.1f} | {m['plot']:.2f} |")  # fmt: skip
    if "baseline" in med:
        ratio = med["this"]["job"] / med["baseline"]["job"]
        print(f"\njob CPU this / baseline: {ratio:.2f} (medians)")
    cache = "as the environment says" if a.keep_env else "on (PYTHONDONTWRITEBYTECODE dropped)"
    print(f"bytecode cache: {cache}")
    print(f"load average at the end: {os.getloadavg()[0]:.2f} on {os.cpu_count()} CPUs")
    return 0 if all(r["rc"] == 0 for rs in res.values() for r in rs) else 1


if __name__ == "__main__":
    sys.exit(main())
