"""What `skyherd sim` runs (world.serve), whichever vehicle it has: one interface for the built-in
vehicle (world.sim.World), an outside autopilot it follows (world.follow.FollowWorld) and a real
autopilot on skyherd's physics (world.bridged.BridgedWorld). Each renders its camera through the
same world.scene.Scene, so every world honours every camera and team option."""

from __future__ import annotations

from typing import Protocol, runtime_checkable


@runtime_checkable
class SimWorld(Protocol):
    def run(self, duration_s: float | None = None) -> dict:
        """Step until `stop()` (or `duration_s` of simulation time); the run's stats."""
        ...

    def stop(self) -> None:
        """Ask `run` to return (safe from a signal handler or another thread)."""
        ...

    def companion_gone(self, why: str) -> None:
        """The companion exited (`skyherd fly`'s SIGUSR1): what the vehicle does alone is the
        autopilot's; `why` goes into sim_stats.json (safe from a signal handler)."""
        ...

    def parent_died(self, why: str) -> None:
        """`skyherd fly` died (the parent-death signal): the companion is handing over."""
        ...

    def close(self) -> None:
        """Every socket, session and file closed."""
        ...
