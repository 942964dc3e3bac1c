"""Run folders that explain themselves (runio.run): one test per rule — how the run ended
(completed, failed, aborted with the error, interrupted by Ctrl-C, killed), no folder for a
usage error, config.json with the command line, code commit and input hashes, tables without
nan, decisions.jsonl."""

from __future__ import annotations

import hashlib
import json
import math
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from skyherd.runio import (
    DecisionLog,
    RunAborted,
    RunFolder,
    UsageError,
    envelope_facts,
    file_facts,
    markdown_table,
    read_decisions,
)

ROOT = Path(__file__).resolve().parents[2]
SKYHERD = str(Path(sys.executable).parent / "skyherd")


def _only_run(root: Path) -> Path:
    (run,) = list(root.iterdir())
    return run


def test_completed_run_summary_config_and_file_list(tmp_path):
    with RunFolder.open("demo", root=tmp_path, argv=["demo", "--x", "1"]) as run:
        m = run.metrics(["t", "v"])
        m.write({"t": 0.0, "v": 1.0})
        run.summary("| a | b |\n|---|---|\n| 1 | 2 |\n")
    folder = _only_run(tmp_path)
    text = (folder / "summary.md").read_text()
    assert "**Ended: completed**" in text and "| 1 | 2 |" in text
    assert "`metrics.csv`" in text and "`config.json`" in text  # the files, each explained
    cfg = json.loads((folder / "config.json").read_text())
    assert cfg["command_line"] == "skyherd demo --x 1"
    head = subprocess.run(
        ["git", "-C", str(ROOT), "rev-parse", "HEAD"], capture_output=True, text=True
    ).stdout.strip()
    assert cfg["code"]["git_commit"] == head and cfg["code"]["package_version"]
    assert run.outcome == "completed"


def test_aborted_run_states_the_error_and_still_makes_its_plots(tmp_path):
    made = []
    with pytest.raises(RunAborted, match="ConnectionError: no heartbeat from tcp:127.0.0.1:1"):
        with RunFolder.open("fly", root=tmp_path) as run:
            run.at_end(lambda: made.append(run.file("plot.png").write_bytes(b"png")), "plot")
            run.summary("before the error")
            raise ConnectionError("no heartbeat from tcp:127.0.0.1:1")
    folder = _only_run(tmp_path)
    text = (folder / "summary.md").read_text()
    assert "**Ended: aborted**: ConnectionError: no heartbeat from tcp:127.0.0.1:1" in text
    assert "before the error" in text and (folder / "plot.png").exists() and made
    assert "Traceback" in (folder / "error.txt").read_text()


def test_failed_run_and_a_broken_plot_are_reported_not_raised(tmp_path):
    with RunFolder.open("drill", root=tmp_path) as run:
        run.at_end(lambda: 1 / 0, "plots")
        run.path  # noqa: B018
        run.fail("2 of 10 drills breached the fence")
    text = (_only_run(tmp_path) / "summary.md").read_text()
    assert "**Ended: failed**: 2 of 10 drills breached the fence" in text
    assert "plots failed: ZeroDivisionError" in text


def test_ctrl_c_leaves_a_summary_and_closes_the_streams(tmp_path):
    with pytest.raises(KeyboardInterrupt):
        with RunFolder.open("watch", root=tmp_path) as run:
            ev = run.events()
            ev.write({"t": 1.0, "event": "x"})
            raise KeyboardInterrupt
    folder = _only_run(tmp_path)
    assert "**Ended: interrupted**: Ctrl-C" in (folder / "summary.md").read_text()
    assert not ev.appender.active and (folder / "events.jsonl").read_text().count("\n") == 1


def test_usage_error_leaves_no_run_folder(tmp_path):
    with pytest.raises(UsageError):
        with RunFolder.open("train-ab", root=tmp_path):
            raise UsageError("--seeds must be >= 1")
    with pytest.raises(UsageError):  # after config.json was written: removed too
        with RunFolder.open("train-ab", root=tmp_path) as run:
            run.config(x=1)
            run.path  # noqa: B018
            raise UsageError("bad envelope file")
    assert list(tmp_path.iterdir()) == []
    # a run that wrote nothing and ended well leaves nothing either
    with RunFolder.open("noop", root=tmp_path):
        pass
    assert list(tmp_path.iterdir()) == []


def test_cli_usage_errors_make_no_run_folder(tmp_path):
    from skyherd.scripts.cli import main

    assert main(["watch", "--frames", "0", "--runs-dir", str(tmp_path)]) == 2
    assert main(["watch", "--connect", "tcp:127.0.0.1", "--runs-dir", str(tmp_path)]) == 2
    assert main(["train", "ab", "--seeds", "0", "--runs-dir", str(tmp_path)]) == 2
    assert not tmp_path.exists() or list(tmp_path.iterdir()) == []


def test_a_killed_run_says_it_was_running(tmp_path):
    code = f"""
import sys, time
from skyherd.runio import RunFolder
with RunFolder.open("fly", root={str(tmp_path)!r}) as run:
    run.summary("half way")
    print(run.path, flush=True)
    time.sleep(600)
"""
    p = subprocess.Popen([sys.executable, "-c", code], cwd=ROOT, stdout=subprocess.PIPE, text=True)
    try:
        folder = Path(p.stdout.readline().strip())
    finally:
        p.send_signal(signal.SIGKILL)
        p.wait(timeout=60)
    text = (folder / "summary.md").read_text()
    assert "**Running** (still running, or the process was killed)" in text and "half way" in text


def test_skyherd_watch_interrupted_by_sigint_writes_its_summary_walltime(tmp_path):
    """A real Ctrl-C (SIGINT) to `skyherd watch` waiting for frames: exit 130, summary says so."""
    p = subprocess.Popen(
        [SKYHERD, "watch", "--connect", "tcp:127.0.0.1:7464", "--timeout", "300", "--runs-dir",
         str(tmp_path), "--no-show"], cwd=tmp_path, stdout=subprocess.PIPE, stderr=subprocess.PIPE,
    )  # fmt: skip
    try:
        deadline = time.monotonic() + 120
        while not list(tmp_path.glob("*/metrics.csv")):
            assert time.monotonic() < deadline and p.poll() is None, "watch did not start"
            time.sleep(0.05)
        p.send_signal(signal.SIGINT)
        out, err = p.communicate(timeout=120)
    finally:
        if p.poll() is None:
            p.kill()
    assert p.returncode == 130, err
    text = (_only_run(tmp_path) / "summary.md").read_text()
    assert "**Ended: interrupted**: Ctrl-C" in text and "| processed" in text
    assert b"interrupted" in err


@pytest.mark.parametrize(
    ("sigint", "moment", "after_s"),
    [("ignored", "config.json", 0.0), ("ignored", "metrics.csv", 0.0),
     ("ignored", "metrics.csv", 1.0), ("default", "config.json", 0.0)],
)  # fmt: skip
def test_skyherd_watch_interrupted_during_start_up_walltime(tmp_path, sigint, moment, after_s):
    """SIGINT to `skyherd watch` as soon as its run folder appears (start-up: the recorder
    subscribes, metrics.csv is made), as soon as metrics.csv does, or 1 s later (the frame
    loop), also when watch inherited SIGINT ignored, as a background job of a non-interactive
    shell does (`make test &`): exit 130, and summary.md says interrupted, with its table. The
    code before lost a SIGINT that came before its frame loop when it started ignored (it ran
    on to --timeout), and one that came before its summary was registered left no table."""
    disposition = signal.SIG_IGN if sigint == "ignored" else signal.SIG_DFL
    p = subprocess.Popen(
        [SKYHERD, "watch", "--connect", "tcp:127.0.0.1:7464", "--timeout", "300", "--runs-dir",
         str(tmp_path), "--no-show"], cwd=tmp_path, stdout=subprocess.PIPE, stderr=subprocess.PIPE,
        preexec_fn=lambda: signal.signal(signal.SIGINT, disposition),
    )  # fmt: skip
    try:
        deadline = time.monotonic() + 120
        while not list(tmp_path.glob(f"*/{moment}")):
            assert time.monotonic() < deadline and p.poll() is None, "watch did not start"
            time.sleep(0.001)
        time.sleep(after_s)
        p.send_signal(signal.SIGINT)
        out, err = p.communicate(timeout=60)
    finally:
        if p.poll() is None:
            p.kill()
            p.communicate()
    assert p.returncode == 130, err
    text = (_only_run(tmp_path) / "summary.md").read_text()
    assert "**Ended: interrupted**: Ctrl-C" in text and "| processed" in text
    assert b"interrupted" in err


def test_config_records_input_files_and_envelope_hashes(tmp_path):
    from skyherd.safety.config import default_envelope_path, load_envelope

    pol = tmp_path / "policy.npz"
    pol.write_bytes(b"weights")
    facts = file_facts(pol)
    assert facts["sha256"] == hashlib.sha256(b"weights").hexdigest() and facts["path"] == str(
        pol.resolve()
    )
    assert file_facts(tmp_path / "none.npz")["sha256"] is None
    path = default_envelope_path("quadrotor")
    spec, _ = load_envelope(path)
    env = envelope_facts(spec)
    assert env["version"] == spec.version and env["name"] == spec.name
    assert env["file"]["sha256"] == hashlib.sha256(path.read_bytes()).hexdigest()
    # a copy with one comment more: another file hash, the same contents hash
    other = tmp_path / "copy.toml"
    other.write_text("# a comment\n" + path.read_text())
    env2 = envelope_facts(load_envelope(other)[0])
    assert env2["file"]["sha256"] != env["file"]["sha256"]
    assert env2["content_sha256"] == env["content_sha256"] and env2["version"] == env["version"]
    with RunFolder.open("fly", root=tmp_path / "runs") as run:
        run.config(policy=facts, envelope=env)
        run.path  # noqa: B018
    cfg = json.loads((_only_run(tmp_path / "runs") / "config.json").read_text())
    assert cfg["policy"]["sha256"] == facts["sha256"] and cfg["envelope"]["version"] == spec.version


def test_tables_show_a_dash_and_say_why_instead_of_nan():
    t = markdown_table(["metric", "value"], [["decisions", 0], ["footprint", math.nan], ["end", None]],
                       missing="no decision was made: the flight aborted before the hand-over")  # fmt: skip
    assert "nan" not in t.lower() and "| footprint | —" in t
    assert t.rstrip().endswith("— = no decision was made: the flight aborted before the hand-over")
    assert "—" not in markdown_table(["a"], [[1.5]])


def test_decision_log_appends_strict_json_and_survives_a_cut_line(tmp_path):
    path = tmp_path / "decisions.jsonl"
    log = DecisionLog(path)
    rec = log.write({"t": 0.5, "vehicle": "uav0", "pilot": "policy", "phi": [0.1, math.nan],
                     "proposed": {"vel_ned": [4.0, 0, 0]}, "certified": {"vel_ned": [2.0, 0, 0]},
                     "verdict": "projected", "reason": "accel limit", "mode": "ai"})  # fmt: skip
    assert rec["phi"] == [0.1, None] and rec["proposed"] == {
        "pos_ned": None,
        "vel_ned": [4.0, 0, 0],
        "yaw": None,
    }
    assert rec["autopilot_mode"] is None
    log.write({"t": 0.6, "verdict": "accepted"})
    assert len(read_decisions(path)) == 2  # flushed per record: readable while open
    with pytest.raises(ValueError, match="verdict"):
        log.write({"t": 0.7, "verdict": "maybe"})
    with pytest.raises(ValueError, match="sim time"):
        log.write({"verdict": "accepted"})
    log.close()
    assert log.counts == {"projected": 1, "accepted": 1} and log.reasons == {"accel limit": 1}
    with open(path, "a") as f:
        f.write('{"t": 0.8, "verd')  # a kill mid-line
    got = read_decisions(path)
    assert [r["t"] for r in got] == [0.5, 0.6]
    assert all(json.loads(line) for line in path.read_text().splitlines()[:2])
    assert "NaN" not in path.read_text()


def test_run_streams_go_in_the_folder_lazily(tmp_path):
    with RunFolder.open("x", root=tmp_path) as run:
        assert not run.created
        d = run.decisions()
        assert run.created and os.path.exists(run.file("decisions.jsonl"))
        d.write({"t": 0.0, "verdict": "pid"})
    assert "`decisions.jsonl`" in (_only_run(tmp_path) / "summary.md").read_text()


def test_csv_writer_writes_the_header_columns_in_order_and_leaves_out_other_keys(tmp_path):
    import csv

    import numpy as np

    from skyherd.runio import CsvWriter

    cols = ["t", "north", "mode", "armed", "ref"]
    rows = [{"t": 0.1, "north": np.float64(1.0) / 3, "mode": "OFFBOARD", "armed": 1},
            {"t": np.float32(0.2), "north": np.nan, "mode": "HOLD", "armed": 0, "ref": ""}]  # fmt: skip
    w = CsvWriter(tmp_path / "m.csv", cols)
    w.write_rows(rows)
    w.write({"t": 0.3, "_tol": 1e-9})  # a private key of the caller's row: not a column
    w.close()
    with open(tmp_path / "ref.csv", "w", newline="", encoding="utf-8") as f:
        d = csv.DictWriter(f, fieldnames=cols)
        d.writeheader()
        for r in [*rows, {"t": 0.3}]:
            d.writerow({k: (v.item() if isinstance(v, np.generic) else v) for k, v in r.items()})
    assert (tmp_path / "m.csv").read_text() == (tmp_path / "ref.csv").read_text()
    assert (tmp_path / "m.csv").read_text().splitlines()[1] == "0.1,0.3333333333333333,OFFBOARD,1,"
