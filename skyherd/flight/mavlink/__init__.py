"""The vehicle's MAVLink 2 endpoint: telemetry streams, commands, parameters, missions, offboard.

Speaks to MAVSDK, QGroundControl, MAVProxy and pymavlink over real UDP sockets in the PX4
SITL port layout (CONVENTIONS.md). It translates messages into `flight.autopilot_api.Autopilot`
calls and never touches dynamics. Single-threaded: the SITL runner calls `update()` once per
autopilot step, so every MAVLink timeout runs on the simulation clock.
"""

__all__ = ["EndpointConfig", "MavlinkEndpoint", "Personality"]


def __getattr__(name: str):
    """The endpoint's names, imported when first asked for (PEP 562): a module of the package
    (`flight.mavlink.wire`, the frame layout) or the endpoint's configuration can be imported
    without the whole endpoint."""
    if name in ("EndpointConfig", "Personality"):  # the configuration alone (flight.mavlink.config)
        from skyherd.flight.mavlink import config

        return getattr(config, name)
    if name == "MavlinkEndpoint":
        from skyherd.flight.mavlink.endpoint import MavlinkEndpoint

        return MavlinkEndpoint
    raise AttributeError(f"module 'skyherd.flight.mavlink' has no attribute {name!r}")
