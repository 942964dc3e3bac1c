"""runio.launch: a child of `fly` gets SIGINT only once it takes signals.

A Python interpreter interrupted while it starts (its site module, the editable install's
import finder) dies with "Fatal Python error: init_import_site" and a traceback on the
terminal: CI saw it in `fly`'s output after a Ctrl-C 0.6 s into a flight. Children started
with `says_ready` (the simulator, the companion) say on a pipe when their own handlers are in
place; `stop` waits for that.
"""

from __future__ import annotations

import contextlib
import os
import signal
import sys

from skyherd.runio.constants import READY_FD_ENV
from skyherd.runio.launch import start, stop
from skyherd.runio.signals import say_ready

# A child that starts slowly (a loaded machine), then takes SIGINT and says so, as
# runio.signals.say_ready does: its handler writes "handled" and it exits 0.
SLOW_START = f"""
import os, signal, sys, time
time.sleep(2.0)  # the interpreter and its imports, slowly: SIGINT now is a traceback
signal.signal(signal.SIGINT, lambda *_: (print("handled", flush=True), os._exit(0)))
fd = int(os.environ.pop("{READY_FD_ENV}"))
os.write(fd, b"1")
os.close(fd)
time.sleep(60)
"""


def test_sigint_waits_until_a_slow_starting_child_takes_signals(tmp_path):
    child = start("slow", [sys.executable, "-c", SLOW_START], tmp_path / "slow.log",
                  says_ready=True)  # fmt: skip
    assert stop(child, grace_s=60.0) == 0
    child.relay.join(10)  # its last lines on their way to the log
    said = (tmp_path / "slow.log").read_text()
    assert "handled" in said and "Traceback" not in said, said
    assert child.ready and child.ready_fd is None


def test_without_the_wait_the_same_child_dies_unhandled_walltime(tmp_path):
    """The counterpart: SIGINT at once (no `says_ready`) lands in the 2 s start-up (wall
    time: `stop` follows `start` by far less), killed by it or its KeyboardInterrupt."""
    child = start("slow", [sys.executable, "-c", SLOW_START], tmp_path / "slow.log")
    assert child.ready_fd is None
    rc = stop(child, grace_s=60.0)
    child.relay.join(10)
    said = (tmp_path / "slow.log").read_text()
    assert rc in (1, -2) and "handled" not in said, (rc, said)


def test_a_child_that_never_says_it_gets_sigint_when_its_pipe_closes(tmp_path):
    other = start("other", [sys.executable, "-c", "pass"], tmp_path / "other.log", says_ready=True)
    assert other.wait_ready(120.0) is False and other.proc.wait(120) == 0


def test_say_ready_writes_its_byte_and_hides_the_pipe_from_the_process_children(monkeypatch):
    r, w = os.pipe()
    monkeypatch.setenv(READY_FD_ENV, str(w))
    say_ready()
    assert READY_FD_ENV not in os.environ and os.read(r, 2) == b"1"  # written, and closed:
    assert os.read(r, 1) == b""  # end of file
    os.close(r)
    say_ready()  # nothing named: nothing done


def _says_ready_with_its_handlers_in_place(monkeypatch, enter) -> None:
    """`enter()` puts handlers in place and says so: when the byte is on the pipe, SIGINT and
    SIGTERM are no longer Python's defaults."""
    r, w = os.pipe()
    monkeypatch.setenv(READY_FD_ENV, str(w))
    before = {s: signal.getsignal(s) for s in (signal.SIGINT, signal.SIGTERM)}
    try:
        with enter():
            assert os.read(r, 1) == b"1"
            assert signal.getsignal(signal.SIGINT) is not signal.default_int_handler
            assert signal.getsignal(signal.SIGTERM) not in (signal.SIG_DFL, signal.SIG_IGN)
    finally:
        os.close(r)
        for s, h in before.items():
            signal.signal(s, h)


def test_the_companion_says_it_once_its_handlers_are_in_place(monkeypatch):
    from skyherd.mission.handover import StopRequest, stop_on_signals

    _says_ready_with_its_handlers_in_place(monkeypatch, lambda: stop_on_signals(StopRequest()))


def test_the_simulator_says_it_once_its_handlers_are_in_place(monkeypatch):
    from skyherd.world.serve import watch_signals

    @contextlib.contextmanager
    def watching():
        old = signal.getsignal(signal.SIGUSR1)
        watch_signals([], os.getpid())
        try:
            yield
        finally:
            signal.signal(signal.SIGUSR1, old)

    _says_ready_with_its_handlers_in_place(monkeypatch, watching)


SAY_BLAS = "import os; print('blas threads:', os.environ.get('OPENBLAS_NUM_THREADS'))"


def test_children_run_openblas_without_worker_threads_unless_told(tmp_path, monkeypatch):
    monkeypatch.delenv("OPENBLAS_NUM_THREADS", raising=False)
    child = start("plain", [sys.executable, "-c", SAY_BLAS], tmp_path / "plain.log")
    assert child.proc.wait(timeout=60) == 0
    child.relay.join(timeout=10)
    assert "blas threads: 1" in (tmp_path / "plain.log").read_text()
    monkeypatch.setenv("OPENBLAS_NUM_THREADS", "2")  # the user's value wins
    child = start("told", [sys.executable, "-c", SAY_BLAS], tmp_path / "told.log")
    assert child.proc.wait(timeout=60) == 0
    child.relay.join(timeout=10)
    assert "blas threads: 2" in (tmp_path / "told.log").read_text()
