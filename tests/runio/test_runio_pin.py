"""runio.pin: the CPU of a lockstep pair chosen from the allowed CPUs and the instance, and applied
to a real thread (read back from /proc); a CPU the kernel refuses only warns."""

from __future__ import annotations

import os
import threading

import pytest

from skyherd.runio.pin import choose_cpu, cpu_list, pin_thread


def test_auto_spreads_instances_over_the_allowed_cpus():
    allowed = {0, 1, 2, 3}
    assert [choose_cpu("auto", n, allowed) for n in range(6)] == [0, 1, 2, 3, 0, 1]
    assert choose_cpu("auto", 86, {2, 5}) == 2 and choose_cpu("auto", 87, {5, 2}) == 5
    assert choose_cpu("AUTO ", 89, {0, 1, 2}) == 2  # 89 mod 3, in the CPUs' order


def test_one_allowed_cpu_or_off_pins_nothing():
    assert choose_cpu("auto", 86, {3}) is None
    assert choose_cpu("off", 86, {0, 1}) is None


def test_an_explicit_cpu_must_be_allowed():
    assert choose_cpu("1", 88, {0, 1}) == 1 and choose_cpu(0, 88, {0, 1}) == 0
    with pytest.raises(ValueError, match=r"^--pin-cpu 7: CPU 7 is not one this process may run on \(0-1\)$"):  # fmt: skip
        choose_cpu("7", 88, {0, 1})
    with pytest.raises(ValueError, match="give auto, off or a CPU number"):
        choose_cpu("fast", 88, {0, 1})


def test_the_default_allowed_set_is_this_thread_s():
    cpus = sorted(os.sched_getaffinity(0))
    expected = cpus[88 % len(cpus)] if len(cpus) > 1 else None
    assert choose_cpu("auto", 88) == expected
    with pytest.raises(ValueError):
        choose_cpu(str(max(cpus) + 1), 88)


def test_cpu_list_reads_as_the_kernel_writes_it():
    assert cpu_list([5, 0, 1, 2, 8, 7]) == "0-2,5,7-8" and cpu_list({3}) == "3"


def _allowed_list(tid: int) -> str:
    with open(f"/proc/self/task/{tid}/status") as f:
        return next(ln.split(":", 1)[1].strip() for ln in f if ln.startswith("Cpus_allowed_list"))


def test_pin_thread_pins_only_that_thread_and_gives_it_back():
    cpu = max(os.sched_getaffinity(0))
    everything = _allowed_list(threading.get_native_id())
    seen = {}

    def lockstep():
        tid = threading.get_native_id()
        before = pin_thread(cpu)
        seen["pinned"] = _allowed_list(tid)
        seen["main meanwhile"] = _allowed_list(threading.main_thread().native_id)
        pin_thread(before)
        seen["after"] = _allowed_list(tid)

    th = threading.Thread(target=lockstep)
    th.start()
    th.join(10)
    assert seen == {"pinned": str(cpu), "main meanwhile": everything, "after": everything}


def test_a_cpu_the_kernel_refuses_only_warns(capfd):
    tid = threading.get_native_id()
    before = _allowed_list(tid)
    assert pin_thread(4096) is None  # no such CPU here: EINVAL, as a container's cpuset gives
    lines = capfd.readouterr().err.splitlines()
    assert lines == [f"skyherd: warning: cannot pin thread {tid} to CPU 4096 (Invalid argument); "
                     "running unpinned"]  # fmt: skip
    assert _allowed_list(tid) == before
    said: list[str] = []
    assert pin_thread(0, tid=2**22 + 1, warn=said.append) is None  # no such thread: ESRCH
    assert len(said) == 1 and "running unpinned" in said[0]
