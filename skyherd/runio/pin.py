"""One CPU for a lockstep pair: a simulator bridge's lockstep thread and the autopilot process it
answers frame by frame.

Lockstep runs one side at a time, so one core is enough for both; on two idle cores every frame
is two cross-core wake-ups, and in a VM each costs both sides CPU (docs/bridges.md: ArduCopter on
the JSON bridge ran at 0.35 of its native speed on two idle cores, 0.53 on one). `choose_cpu`
picks the CPU from the CPUs this process may run on and the vehicle instance (several vehicles on
one machine spread over the cores); `pin_thread` applies it to one thread. A refusal by the
kernel (a container's cpuset, EINVAL / EPERM) is a one-line warning: the pair runs unpinned.
"""

from __future__ import annotations

import os
import threading
from collections.abc import Callable, Iterable

from skyherd.runio.process import say

PIN_CHOICES = "auto|off|N"
PIN_HELP = (
    "the one CPU of the lockstep pair, the bridge's lockstep thread and the autopilot skyherd "
    "starts (default auto: of the allowed CPUs, number instance mod their count; none when one "
    "is allowed), off, or a CPU number. Lockstep runs one side at a time: on two cores every "
    "frame is two cross-core wake-ups, which cost both sides CPU (docs/bridges.md)"
)


def cpu_list(cpus: Iterable[int]) -> str:
    """CPUs as the kernel lists them (Cpus_allowed_list): '0-3,6'."""
    out: list[str] = []
    for c in sorted(cpus):
        if out and out[-1].split("-")[-1] == str(c - 1):
            out[-1] = f"{out[-1].split('-')[0]}-{c}"
        else:
            out.append(str(c))
    return ",".join(out)


def choose_cpu(pin: str | int, instance: int, allowed: Iterable[int] | None = None) -> int | None:
    """The CPU for vehicle `instance`'s lockstep pair, or None (not pinned).

    pin: "auto" — the allowed CPUs (`allowed`, default this thread's: os.sched_getaffinity(0))
    in order, number `instance` modulo their count; None when only one is allowed (nothing to
    gain). "off" — None. A CPU number — that CPU; ValueError if it is not allowed."""
    cpus = sorted(os.sched_getaffinity(0) if allowed is None else allowed)
    text = str(pin).strip().lower()
    if text == "off":
        return None
    if text == "auto":
        return cpus[instance % len(cpus)] if len(cpus) > 1 else None
    try:
        cpu = int(text)
    except ValueError:
        raise ValueError(f"--pin-cpu {pin}: give auto, off or a CPU number") from None
    if cpu not in cpus:
        raise ValueError(
            f"--pin-cpu {pin}: CPU {cpu} is not one this process may run on ({cpu_list(cpus)})"
        )
    return cpu


def pin_thread(
    cpus: int | Iterable[int], tid: int | None = None, warn: Callable[[str], None] = say
) -> frozenset[int] | None:
    """Keep thread `tid` (Linux thread id; default the calling thread) on `cpus` (one CPU or a
    set). Returns the thread's CPUs before, to put back with `pin_thread(before, tid)`; None
    when the kernel refuses (EINVAL, EPERM, the thread gone): `warn` gets one line and the
    thread runs as before. Threads and processes it starts afterwards inherit the setting."""
    want = {cpus} if isinstance(cpus, int) else set(cpus)
    tid = threading.get_native_id() if tid is None else tid
    try:
        before = frozenset(os.sched_getaffinity(tid))
        os.sched_setaffinity(tid, want)
    except OSError as e:
        warn(f"skyherd: warning: cannot pin thread {tid} to CPU {cpu_list(want)} "
             f"({e.strerror or e}); running unpinned")  # fmt: skip
        return None
    return before
