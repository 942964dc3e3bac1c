"""The vehicle's MAVLink 2 endpoint: telemetry streams, commands, parameters, missions, offboard.

Speaks to MAVSDK, QGroundControl, MAVProxy and pymavlink over real UDP sockets in the PX4
SITL port layout (CONVENTIONS.md). It translates messages into `flight.autopilot_api.Autopilot`
calls and never touches dynamics. Single-threaded: the SITL runner calls `update()` once per
autopilot step, so every MAVLink timeout runs on the simulation clock.
"""

from flight.mavlink.endpoint import EndpointConfig, MavlinkEndpoint
from flight.mavlink.modes import Personality

__all__ = ["EndpointConfig", "MavlinkEndpoint", "Personality"]
