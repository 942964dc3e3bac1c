"""`skyherd sim`'s worlds run to their end: the signals that stop them or leave the autopilot
alone, and one world or a fleet (world.fleet) stepped until then.

SIGTERM and SIGINT stop every world. SIGUSR1 comes from `skyherd fly` once its companion has
exited, or is the kernel's parent-death signal when `skyherd fly` died (runio.launch): then
the companion got its own and is handing over, and the built-in vehicle steps on alone."""

from __future__ import annotations

import json
import signal
from collections.abc import Callable

from skyherd.runio.process import parent_gone
from skyherd.runio.signals import say_ready
from skyherd.world.build import NoSession, WorldError, open_world, open_zenoh
from skyherd.world.protocol import SimWorld

COMPANION_GONE = "SIGUSR1: the companion is gone (it exited)"
"""Why the simulator steps on alone (world.sim.World.companion_gone): `skyherd fly` sends
SIGUSR1 once its companion has exited."""
FLY_DIED = "SIGUSR1: `skyherd fly` died (its parent-death signal)"
"""SIGUSR1 is also the simulator's parent-death signal: then the companion is handing over
(world.sim.World.parent_died)."""


def companion_signal(worlds: list[SimWorld], died: bool) -> None:
    """SIGUSR1 acted on: `died` (the parent `skyherd fly` is gone) or the companion exited."""
    for w in worlds:
        if died:
            w.parent_died(FLY_DIED)
        else:
            w.companion_gone(COMPANION_GONE)


def watch_signals(worlds: list[SimWorld], parent_pid: int) -> None:
    """SIGTERM / SIGINT stop every world; SIGUSR1 calls `companion_signal` (module docstring),
    `parent_pid` the process that started this one."""
    for sig in (signal.SIGTERM, signal.SIGINT):
        signal.signal(sig, lambda *_: [w.stop() for w in worlds])
    signal.signal(signal.SIGUSR1, lambda *_: companion_signal(worlds, parent_gone(parent_pid)))
    say_ready()  # `skyherd fly` may send its SIGINT now (runio.launch)


def serve(setup, run_dir, say: Callable[[str], None], parent_pid: int) -> int:
    """`skyherd sim`: the world(s) of a checked world.setup.SimSetup opened (WorldError if one
    cannot start), writing into `run_dir`, run to their end as `run_to_end` says, the signals
    watched (`parent_pid`: the process that started this one); its first line says how."""
    worlds, session, fleet = open_worlds(setup, run_dir)
    watch_signals(worlds, parent_pid)
    if fleet is not None:
        names = ", ".join(f"{v.name} (instance {v.instance})" for v in fleet)
        say(f"skyherd sim: fleet of {len(fleet)}: {names}; lockstep (latency {setup.latency:g} s), "
            f"speed-up {setup.speedup:g}; run folder {run_dir}")  # fmt: skip
    else:
        mode = "free-running" if setup.free_run else f"lockstep (latency {setup.latency:g} s)"
        if setup.autopilot != "builtin":
            mode = f"{setup.autopilot} on skyherd's physics (its own lockstep)"
        say(f"skyherd sim: instance {setup.instance}, {mode}, speed-up {setup.speedup:g}; "
            f"run folder {run_dir}")  # fmt: skip
    vehicles = [v.name for v in fleet] if fleet is not None else None
    return run_to_end(worlds, vehicles, setup.duration, say, session)


def open_worlds(setup, run_dir) -> tuple[list, object, list | None]:
    """(worlds, the Zenoh session, the fleet or None) of a checked SimSetup: a fleet's worlds
    (world.fleet), or the one vehicle's (world.build.open_world) with its autopilot's
    parameters set. WorldError; the session is closed then."""
    params, endpoint = setup.world_params()
    if setup.builtin:  # its kernels before the companion waits on this vehicle
        from skyherd.flight.airframes_registry import warm_up

        warm_up(params.airframe)
    if setup.fleet:
        from skyherd.world.fleet import open_fleet

        fleet = setup.read_fleet()
        try:
            return open_fleet(params, endpoint, fleet, run_dir, setup.faults), NoSession(), fleet
        except ValueError as e:
            raise WorldError(str(e)) from None
    from skyherd.flight.params import apply_assignments

    session = (
        NoSession() if setup.ugvs == "none" else open_zenoh(setup.zenoh_port, setup.zenoh_config)
    )
    try:
        world = open_world(params, endpoint, session, run_dir, setup.faults(), setup.autopilot,
                           setup.follow, setup.follow_system, setup.pin_cpu)  # fmt: skip
    except ValueError:
        session.close()
        raise
    if setup.builtin:
        try:
            apply_assignments(world.autopilot, setup.param)
        except ValueError as e:
            world.close()
            session.close()
            raise WorldError(str(e)) from None
    return [world], session, None


def run_to_end(worlds: list, names: list[str] | None, duration_s: float | None,
               say: Callable[[str], None], session=None) -> int:  # fmt: skip
    """Run one world (`names` None) or a fleet in lockstep (world.sim.run_worlds) for
    `duration_s` of simulation time or until stopped, close every world and then `session`,
    and say the final stats (a fleet: one `<name> {json}` line per vehicle); 1 if the run
    raised (said)."""
    try:
        if names is None:
            stats = [worlds[0].run(duration_s)]
        else:
            from skyherd.flight.clock import Pacer
            from skyherd.world.sim import run_worlds

            stats = run_worlds(worlds, Pacer(worlds[0].p.speedup), duration_s)
    except Exception as e:  # noqa: BLE001 - say what stopped the world, then close its sockets
        say(f"skyherd sim: stopped: {type(e).__name__}: {e}")
        return 1
    finally:
        for w in worlds:
            w.close()
        if session is not None:
            session.close()
    for i, st in enumerate(stats):
        say(json.dumps(st) if names is None else f"{names[i]} {json.dumps(st)}")
    return 0
