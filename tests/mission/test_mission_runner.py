"""The companion's start and its links, without the command line: the go on standard input
(mission.runner.wait_go), the formation's plan read (load_formation) and why the autopilot's link
did not open, in words (mission.connect.link_error_text)."""

from __future__ import annotations

import errno
import json
import os

import pytest

from skyherd.mission.connect import link_error_text
from skyherd.mission.runner import load_formation, wait_go


def _pipe():
    r, w = os.pipe()
    return os.fdopen(r), os.fdopen(w, "w")


def test_the_go_is_a_line_and_a_closed_or_silent_input_ends_the_wait():
    r, w = _pipe()
    w.write("go\n")
    w.flush()
    wait_go(r, patience_s=5.0)  # returns at once
    w.close()
    with pytest.raises(EOFError, match="closed before the go"):
        wait_go(r, patience_s=5.0)
    r2, w2 = _pipe()
    with pytest.raises(TimeoutError, match="no go on standard input within 0 s"):
        wait_go(r2, patience_s=0.05)
    for f in (r, r2, w2):
        f.close()


def test_a_formation_plan_is_read_with_its_homes_and_a_bad_one_named(tmp_path):
    plan_file = tmp_path / "plan_K2.json"
    plan_file.write_text(json.dumps([[[1, 1], [2, 1]], [[1, 3], [1, 4]]]))
    plan, params, homes = load_formation(str(plan_file), 3.0)
    assert [p[0] for p in plan] == [(1, 1), (1, 3)] and params.cell_m == 3.0
    assert homes[0] != homes[1] and homes[0].alt_m == homes[1].alt_m
    with pytest.raises(ValueError, match=r"^plan: .*pass a plan_K<K>\.json"):
        load_formation(str(tmp_path / "missing.json"), 2.0)
    with pytest.raises(ValueError, match=r"^formation: .*cell_m"):
        load_formation(str(plan_file), 0.5)


def _failed(cause: BaseException | None) -> Exception:
    e = RuntimeError("cannot open the link")
    e.__cause__ = cause
    return e


def test_a_link_that_does_not_open_says_the_next_step():
    addr = "udpin:127.0.0.1:14651"
    assert "connection refused): start the autopilot" in link_error_text(
        _failed(ConnectionRefusedError()), addr, 71
    )
    assert "(timed out): is the autopilot there?" in link_error_text(
        _failed(TimeoutError()), addr, 71
    )
    taken = link_error_text(_failed(OSError(errno.EADDRINUSE, "in use")), addr, 71)
    assert taken.startswith(f"{addr}: the port is taken (another companion of instance 71")
    assert (
        link_error_text(ValueError("key is 3 bytes"), addr, 71) == "--signing-key: key is 3 bytes"
    )
    assert link_error_text(_failed(None), addr, 71) == "cannot open the link; check --connect"
