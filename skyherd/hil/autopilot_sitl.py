"""Start a real autopilot's SITL binary on skyherd's physics (the caller's binary: skyherd
builds none).

PX4 (`PX4_SIM_MODEL=none_iris`): its simulator_mavlink connects to the bridge on TCP 4560+N
(hil/px4_sim.py). ArduCopter (`--model JSON:127.0.0.1`): it sends its servo packets to the
bridge on UDP 9002+10N (hil/ardupilot_json.py) and waits on SERIAL0 (TCP 5760+10N) for a
client before it flies. Both open UDP/TCP ports: run them in a network namespace with only
loopback up (`unshare -n sh -c 'ip link set lo up; ...'`).

ArduCopter starts on the CPU its bridge's lockstep thread runs on (runio.pin.choose_cpu: the
same instance gives the same CPU), one core for the lockstep pair. PX4 is left unpinned: each of
its frames wakes six of its own threads in turn, not one process.
"""

from __future__ import annotations

import os
import signal
import subprocess
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

from skyherd.flight.geo import DEFAULT_HOME, Home
from skyherd.runio.pin import choose_cpu, pin_thread


@dataclass(frozen=True)
class CopterRates:
    """ArduCopter's physics frame rate (SIM_RATE_HZ: one JSON frame each) and its main loop
    (SCHED_LOOP_RATE) [Hz]. It arms only with the loop at most about 0.55 of the frame rate
    (400 → 222 seen); fewer frames per simulated second is what the lockstep's speed scales with."""

    sim_rate_hz: int = 400
    loop_rate_hz: int = 200


def copter_json_parm(rates: CopterRates = CopterRates()) -> str:
    """ArduCopter's parameters for skyherd's quadrotor: an X frame, its hover throttle and PWM
    range, and the physics / loop rates."""
    return (
        f"FRAME_CLASS 1\nFRAME_TYPE 1\nSIM_RATE_HZ {rates.sim_rate_hz}\n"
        f"SCHED_LOOP_RATE {rates.loop_rate_hz}\n"
        "MOT_THST_HOVER 0.46\nMOT_PWM_MIN 1000\nMOT_PWM_MAX 2000\n"
    )


def start_px4(
    binary: Path, instance: int, workdir: Path, log, params: dict[str, float] | None = None
) -> subprocess.Popen:
    """PX4 SITL as `none_iris` (airframe 10016), instance N, working files in `workdir`;
    `params` set at boot (PX4's PX4_PARAM_<NAME> environment variables)."""
    etc = Path(binary).resolve().parent.parent / "etc"  # .../build/px4_sitl_default/etc
    env = dict(os.environ, PX4_SIM_MODEL="none_iris", PX4_SYS_AUTOSTART="10016")
    env.update({f"PX4_PARAM_{k}": repr(float(v)) for k, v in (params or {}).items()})
    cmd = [str(binary), "-d", "-i", str(instance), "-w", str(workdir), str(etc)]
    return subprocess.Popen(cmd, cwd=workdir, env=env, stdout=log, stderr=subprocess.STDOUT,
                            stdin=subprocess.DEVNULL, start_new_session=True)  # fmt: skip


def start_arducopter(
    binary: Path,
    instance: int,
    workdir: Path,
    log,
    defaults: Sequence[Path] = (),
    extra_parm: str = "",
    speedup: float = 1.0,
    rates: CopterRates = CopterRates(),
    home: Home = DEFAULT_HOME,
    model: str = "JSON:127.0.0.1",
    pin_cpu: str | int = "auto",
) -> subprocess.Popen:
    """ArduCopter SITL with `--model JSON:127.0.0.1`, `-I instance`, parameters from
    `defaults` (e.g. ArduPilot's copter.parm), then skyherd's frame (copter_json_parm), then
    `extra_parm` (an operator's own lines). speedup 0 = as fast as the physics answers.
    `model`: another of ArduPilot's own physics models (e.g. "+") flies the same binary and
    parameters without skyherd's physics (bench/bench_bridges.py's yardstick). `pin_cpu`: its
    CPU as the bridge of `instance` chooses it (runio.pin.choose_cpu: auto, off or a number;
    ValueError if not allowed); the kernel refusing: a warning, and it starts unpinned."""
    parm = workdir / "skyherd-json.parm"
    parm.write_text(copter_json_parm(rates) + extra_parm)
    cmd = [str(binary), "--model", model, "--speedup", str(speedup or 1000),
           "-I", str(instance), "--home", f"{home.lat_deg},{home.lon_deg},{home.alt_m},0",
           "--defaults", ",".join(str(p) for p in [*defaults, parm]), "-w"]  # fmt: skip
    cpu = choose_cpu(pin_cpu, instance)
    # a child inherits the CPUs of the thread that starts it: this one, for the moment
    before = pin_thread(cpu) if cpu is not None else None
    try:
        return subprocess.Popen(cmd, cwd=workdir, stdout=log, stderr=subprocess.STDOUT,
                                stdin=subprocess.DEVNULL, start_new_session=True)  # fmt: skip
    finally:
        if before is not None:
            pin_thread(before)


def stop(proc: subprocess.Popen) -> int | None:
    """Kill the autopilot's process group (ArduCopter ignores SIGTERM once its physics is
    gone) and reap it; its exit code."""
    if proc.poll() is None:
        try:
            os.killpg(proc.pid, signal.SIGKILL)
        except ProcessLookupError:
            pass
    return proc.wait(10)
