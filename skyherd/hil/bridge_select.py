"""One entry point for `skyherd sim --autopilot px4|ardupilot`: the bridge for an autopilot, and
`Bridge`, what both bridges are to the world that wraps them (world.bridged.BridgedWorld).
PX4 connects to the bridge (TCP): `serve` waits for it, or call its `accept(timeout_s)` first.
ArduPilot sends UDP packets: there is nothing to accept.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Protocol, runtime_checkable

from skyherd.flight.geo import DEFAULT_HOME, Home
from skyherd.flight.state import VehicleState
from skyherd.hil.ardupilot_json import ArduPilotJsonBridge
from skyherd.hil.px4_sim import Px4SimBridge

AUTOPILOTS = ("px4", "ardupilot")


@runtime_checkable
class Bridge(Protocol):
    """skyherd's physics as a real autopilot's simulator, in lockstep with it."""

    port: int  # the autopilot's simulator port (PX4: TCP 4560+N; ArduPilot: UDP 9002+10N)
    stats: object  # its counters (frames, answers, bad packets), for sim_stats.json

    @property
    def t(self) -> float:
        """Simulation time [s]."""
        ...

    @property
    def state(self) -> VehicleState:
        """The true vehicle state (the camera's and the UGV world's)."""
        ...

    def open_port(self) -> Bridge:
        """Bind / listen on the autopilot's port; returns the bridge."""
        ...

    def step_once(self, timeout_s: float | None = None) -> bool:
        """One lockstep frame; False if the autopilot did not ask or answer in time."""
        ...

    def serve(self, *, sim_duration_s: float | None = None,
              on_step: Callable[[Bridge], bool | None] | None = None) -> object:  # fmt: skip
        """Frames until `sim_duration_s` of simulation time, or until `on_step(bridge)` is True."""
        ...

    def close(self) -> None: ...


def make_bridge(
    autopilot: str,
    airframe: str = "quadrotor",
    instance: int = 0,
    seed: int = 0,
    home: Home = DEFAULT_HOME,
    speedup: float = 0.0,
    pin_cpu: str | int = "auto",
) -> Bridge:
    """The bridge of `autopilot` for `airframe` ("quadrotor"; ArduPilot also "fixedwing").

    speedup paces PX4 (0 = as fast as it answers); ArduPilot paces itself (--speedup).
    pin_cpu: the CPU of ArduPilot's lockstep thread (runio.pin.choose_cpu; ValueError if not
    allowed); PX4's bridge is not pinned (PX4 is many threads, not one lockstep partner).
    """
    if autopilot == "px4":
        return Px4SimBridge(airframe, instance, seed, home, speedup=speedup)
    if autopilot == "ardupilot":
        return ArduPilotJsonBridge(airframe, instance, seed, home, pin_cpu=pin_cpu)
    raise ValueError(f"autopilot {autopilot!r}: choose one of {AUTOPILOTS}")
