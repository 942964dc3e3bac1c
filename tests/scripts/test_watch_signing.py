"""`skyherd watch --signing-key FILE` (issue 27): the camera of the built-in vehicle run signed
(`skyherd sim --signing-key FILE`: its frames carry the flight key's MAC and pixel digest) is
watched with the key and every frame is taken; a watch with another key takes none (each is
refused, and the exit says so); a frame source without the key (`skyherd camstream`: plain
frames, as any process on the Zenoh network can publish) is refused by a watch with the key
too. A watch without a key shows whatever comes (it cannot check a signed frame's pixels)."""

import os
import subprocess
import sys

import pytest

from skyherd.flight.mavlink.signing import save_key
from skyherd.runio import ports
from skyherd.scripts.cli import main

INSTANCE = 103  # the built-in vehicle: Zenoh 7447+103, MAVLink 14643 / 14683 / 18673


def _watch(tmp_path, name: str, *extra: str) -> tuple[int, str]:
    """`skyherd watch --instance INSTANCE` for 10 frames: (exit code, summary.md)."""
    runs = tmp_path / name
    rc = main(["watch", "--instance", str(INSTANCE), "--frames", "10", "--timeout", "60",
               "--runs-dir", str(runs), "--no-show", "--no-mcap", *extra])  # fmt: skip
    (run,) = runs.iterdir()
    return rc, (run / "summary.md").read_text()


def _refused(summary: str) -> int:
    """The `refused` row of the link table."""
    row = next(line for line in summary.splitlines() if line.startswith("| refused "))
    return int(row.split("|")[2])


@pytest.mark.slow
def test_watch_takes_the_signed_vehicles_frames_with_its_key_only(tmp_path, capsys):
    key, other = tmp_path / "flight.key", tmp_path / "other.key"
    save_key(key, os.urandom(32))
    save_key(other, os.urandom(32))
    sim = subprocess.Popen([sys.executable, "-m", "skyherd.scripts.cli", "sim", "--free-run",
                            "--speedup", "2", "--duration", "600", "--instance", str(INSTANCE),
                            "--signing-key", str(key), "--runs-dir", str(tmp_path / "sim")],
                           stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)  # fmt: skip
    try:
        signed = _watch(tmp_path, "signed", "--signing-key", str(key))
        wrong = _watch(tmp_path, "wrong", "--signing-key", str(other), "--timeout", "5")
        unchecked = _watch(tmp_path, "unchecked")
    finally:
        sim.terminate()
        sim.wait(60)
    rc, summary = signed
    assert rc == 0 and f"authenticated with the flight key ({key})" in summary, summary
    assert "| processed " in summary and _refused(summary) == 0, summary
    rc, summary = wrong
    assert rc == 1 and _refused(summary) > 0, summary
    assert "refused as not signed with --signing-key" in capsys.readouterr().out
    rc, summary = unchecked
    assert rc == 0 and "not authenticated (no --signing-key)" in summary, summary


def test_watch_with_a_key_refuses_an_unsigned_frame_source(tmp_path):
    key = tmp_path / "flight.key"
    save_key(key, os.urandom(32))
    src = subprocess.Popen([sys.executable, "-m", "skyherd.scripts.cli", "camstream", "--port",
                            str(ports.zenoh_port(INSTANCE)), "--frames", "0", "--rate", "20",
                            "--wait-s", "20"], stderr=subprocess.DEVNULL)  # fmt: skip
    try:
        rc, summary = _watch(tmp_path, "plain", "--signing-key", str(key), "--timeout", "3")
    finally:
        src.terminate()
        src.wait(30)
    assert rc == 1 and _refused(summary) > 0, summary


def test_watch_with_a_bad_key_file_is_one_line_exit_2(tmp_path, capsys):
    bad = tmp_path / "short.key"
    bad.write_bytes(b"x" * 16)
    assert main(["watch", "--signing-key", str(bad), "--runs-dir", str(tmp_path / "r")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "--signing-key" in err[0], err
    assert not (tmp_path / "r").exists()
