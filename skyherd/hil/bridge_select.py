"""One entry point for `skyherd sim --autopilot px4|ardupilot`: the bridge for an autopilot.

Both bridges share a small API:
  bridge.open_port()          bind / listen on the autopilot's port (returns the bridge)
  bridge.step_once(timeout_s) one lockstep frame; False if the autopilot did not ask/answer
  bridge.serve(sim_duration_s=..., on_step=fn)   loop; fn(bridge) → True stops
  bridge.t, bridge.state      simulation time [s], true VehicleState (camera, UGV world)
  bridge.stats, bridge.port, bridge.close()
PX4 connects to us (TCP): `serve` waits for it, or call `accept(timeout_s)` first.
ArduPilot sends UDP packets: there is nothing to accept.
"""

from __future__ import annotations

from skyherd.flight.geo import DEFAULT_HOME, Home
from skyherd.hil.ardupilot_json import ArduPilotJsonBridge
from skyherd.hil.px4_sim import Px4SimBridge

AUTOPILOTS = ("px4", "ardupilot")


def make_bridge(
    autopilot: str,
    airframe: str = "quadrotor",
    instance: int = 0,
    seed: int = 0,
    home: Home = DEFAULT_HOME,
    speedup: float = 0.0,
) -> Px4SimBridge | ArduPilotJsonBridge:
    """The bridge of `autopilot` for `airframe` ("quadrotor"; ArduPilot also "fixedwing").

    speedup paces PX4 (0 = as fast as it answers); ArduPilot paces itself (--speedup).
    """
    if autopilot == "px4":
        return Px4SimBridge(airframe, instance, seed, home, speedup=speedup)
    if autopilot == "ardupilot":
        return ArduPilotJsonBridge(airframe, instance, seed, home)
    raise ValueError(f"autopilot {autopilot!r}: choose one of {AUTOPILOTS}")
