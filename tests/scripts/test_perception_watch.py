"""`skyherd watch` against a real frame source process."""

import csv
import socket
import subprocess
import sys

import cv2

from skyherd.scripts.cli import main


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def test_watch_saves_annotated_frames_and_counts(tmp_path, capsys):
    port = free_port()
    src = subprocess.Popen(
        [sys.executable, "-m", "skyherd.scripts.cli", "camstream", "--port", str(port),
         "--frames", "120", "--rate", "50", "--wait-s", "10"],
        stderr=subprocess.DEVNULL,
    )  # fmt: skip
    try:
        code = main(
            ["watch", "--connect", f"tcp/127.0.0.1:{port}", "--frames", "40",
             "--runs-dir", str(tmp_path), "--timeout", "8", "--save-every", "5", "--no-show"]
        )  # fmt: skip
    finally:
        src.wait(timeout=30)
    assert code == 0
    (run,) = list(tmp_path.iterdir())
    for name in ("config.json", "metrics.csv", "summary.md", "strip.png"):
        assert (run / name).exists(), name
    rows = list(csv.DictReader(open(run / "metrics.csv")))
    assert len(rows) == 40
    # the camstream scene keeps all three UGVs in view at the start
    assert all(int(r["count"]) == 3 for r in rows[:10])
    assert all(0.0 <= float(r["spread"]) <= 1.0 for r in rows)
    pngs = sorted((run / "frames").glob("*.png"))
    assert len(pngs) == 8
    img = cv2.imread(str(pngs[0]))
    assert img.shape == (480, 640, 3)
    out = capsys.readouterr().out
    assert "processed" in out and "| lost " in out


def test_watch_without_source_fails_cleanly(tmp_path):
    port = free_port()
    code = main(
        ["watch", "--connect", f"tcp/127.0.0.1:{port}", "--frames", "5",
         "--out", str(tmp_path), "--timeout", "1", "--no-show"]
    )  # fmt: skip
    assert code == 1


def test_watch_bad_usage_is_exit_2(tmp_path, capsys):
    assert main(["watch", "--frames", "0", "--out", str(tmp_path)]) == 2
    assert main(["watch", "--zenoh-config", str(tmp_path / "none.json5")]) == 2
    assert main(["watch", "--connect", "not-an-endpoint", "--out", str(tmp_path)]) == 2
    err = capsys.readouterr().err
    assert "skyherd watch:" in err


def test_watch_instance_n_listens_where_fly_instance_n_publishes(tmp_path, capsys):
    """`--instance N`: the Zenoh port of runio.ports (7447+N), as `fly`/`sim --instance N`."""
    from skyherd.runio import ports

    n = 150
    src = subprocess.Popen(
        [sys.executable, "-m", "skyherd.scripts.cli", "camstream", "--port", str(ports.zenoh_port(n)),
         "--frames", "60", "--rate", "50", "--wait-s", "10"],
        stderr=subprocess.DEVNULL,
    )  # fmt: skip
    try:
        code = main(["watch", "--instance", str(n), "--frames", "10", "--runs-dir", str(tmp_path),
                     "--timeout", "8", "--no-show", "--no-mcap"])  # fmt: skip
    finally:
        src.wait(timeout=30)
    assert code == 0
    (run,) = list(tmp_path.iterdir())
    cfg = (run / "config.json").read_text()
    assert f"tcp/127.0.0.1:{7447 + n}" in cfg
    assert len(list(csv.DictReader(open(run / "metrics.csv")))) == 10


def test_watch_instance_bad_usage_is_one_line_exit_2(tmp_path, capsys):
    runs = tmp_path / "runs"
    assert main(["watch", "--instance", "201", "--runs-dir", str(runs)]) == 2
    err = capsys.readouterr().err
    assert "--instance 201: instance must be in [0, 200]" in err and err.count("\n") == 1
    assert main(["watch", "--instance", "3", "--connect", "tcp:127.0.0.1:7450",
                 "--runs-dir", str(runs)]) == 2  # fmt: skip
    err = capsys.readouterr().err
    assert "give one" in err and err.count("\n") == 1
    assert not runs.exists()
