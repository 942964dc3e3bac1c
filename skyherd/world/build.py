"""`skyherd sim`'s world built from its parameters: the built-in vehicle (world.sim `World`), a
real autopilot on skyherd's physics (world.bridged) or an outside vehicle followed over MAVLink
(world.follow); the Zenoh session it publishes on; the text forms of its home and its time
windows. Every refusal is a `WorldError` whose message names the option and says what to do."""

from __future__ import annotations

import math
from pathlib import Path

from skyherd.flight.geo import home_in_range

FOLLOW_CONNECT_WAIT_S = 60.0  # ArduPilot SITL opens SERIAL1 only once the companion is on SERIAL0
FOLLOW_SYSTEM, FOLLOW_COMPONENT = 255, 190  # the world's own ids on the followed vehicle's link


class WorldError(ValueError):
    """The world cannot be built as asked; the message says which option and what to do."""


def parse_home(text: str | None) -> tuple[float, float, float] | None:
    """`LAT,LON,ALT` (`--home`) → (deg, deg, m AMSL); None stays None (the default home)."""
    if text is None:
        return None
    try:
        lat, lon, alt = (float(x) for x in text.split(","))
    except ValueError:
        raise WorldError(
            f"--home {text!r}: expected LAT,LON,ALT, e.g. 47.397742,8.545594,488"
        ) from None
    if not home_in_range(lat, lon, alt):
        raise WorldError(f"--home {text!r}: latitude, longitude or altitude out of range")
    return lat, lon, alt


def parse_windows(items: list[str], flag: str) -> tuple[tuple[float, float], ...]:
    """`T:D` items (`--cut-link`, `--cut-camera`) → ((start, duration), ...) [s], the windows
    of WorldParams.link_cuts and camera_losses."""
    out = []
    for item in items:
        t, _, d = item.partition(":")
        try:
            w = (float(t), float(d))
        except ValueError:
            raise WorldError(f"{flag} {item!r}: expected T:D in seconds, e.g. 30:3") from None
        if not (math.isfinite(w[0]) and math.isfinite(w[1]) and w[0] >= 0 and w[1] > 0):
            raise WorldError(f"{flag} {item!r}: T must be >= 0 and D > 0")
        out.append(w)
    return tuple(out)


def open_zenoh(port: int, config_file: str | None):
    """The world's Zenoh session: a peer listening on 127.0.0.1:`port`, or `config_file`."""
    from skyherd.perception.transport import ZenohParams, open_session, publisher_params

    p = ZenohParams(config_file=config_file) if config_file else publisher_params(port)
    try:
        return open_session(p)
    except ValueError as e:
        if config_file is None and "in use" in str(e):
            raise WorldError(f"Zenoh port {port} on 127.0.0.1 is taken (another simulator, or "
                             "another program, listens there): pick another --instance or "
                             "--zenoh-port") from None  # fmt: skip
        raise WorldError(f"{e}; check --zenoh-port / --zenoh-config") from None


class NoSession:
    """The vehicle alone publishes nothing: no Zenoh session to open or close."""

    def close(self) -> None:
        pass


def open_world(params, endpoint, session, run_dir: Path, faults=None, autopilot: str = "builtin",
               follow: str | None = None, follow_system: int = 0,
               pin_cpu: str = "auto"):  # fmt: skip
    """The world of one vehicle (world.sim.WorldParams `params`, flight.mavlink.EndpointConfig
    `endpoint`, its signing key the flight key of the frames): a real autopilot on skyherd's
    physics (`autopilot` px4 | ardupilot: hil bridges; `pin_cpu`: the CPU of ArduPilot's
    lockstep, runio.pin), the outside vehicle at the MAVLink address `follow`, or the built-in
    vehicle with the fault plan `faults`. `session`: the caller's, to close."""
    from skyherd.flight.mavlink.signing import load_key

    key = lambda: load_key(endpoint.signing_key) if endpoint.signing_key else None  # noqa: E731
    try:
        if autopilot != "builtin":
            from skyherd.hil.bridge_select import make_bridge
            from skyherd.world.bridged import BridgedWorld

            bridge = make_bridge(autopilot, params.airframe, params.instance, params.seed,
                                 speedup=params.speedup, pin_cpu=pin_cpu)  # fmt: skip
            return BridgedWorld(bridge, params, session=session, run_dir=run_dir, key=key())
        if follow:
            from skyherd.world.follow import FollowWorld

            link = _follow_link(follow, endpoint.signing_key)
            return FollowWorld(link, params, session=session, run_dir=run_dir,
                               system_id=follow_system, key=key())  # fmt: skip
        from skyherd.world.sim import World

        return World(params, session=session if params.scenario != "none" else None,
                     run_dir=run_dir, endpoint_config=endpoint, faults=faults)  # fmt: skip
    except WorldError:
        raise
    except ValueError as e:  # flight.mavlink.signing.SigningError: a bad key file
        raise WorldError(f"--signing-key: {e}") from None
    except OSError as e:
        raise WorldError(f"{e}; is another vehicle using instance {params.instance}?") from None


def _follow_link(address: str, signing_key: str | None):
    """The MAVLink link the world follows an outside vehicle on (retried while it opens)."""
    from skyherd.hil.link import LinkError, MavlinkLink, link_address

    try:
        link_address(address)
        return MavlinkLink.open(address, connect_wait_s=FOLLOW_CONNECT_WAIT_S,
                                source_system=FOLLOW_SYSTEM, source_component=FOLLOW_COMPONENT,
                                signing_key=signing_key)  # fmt: skip
    except (ValueError, LinkError) as e:
        raise WorldError(f"--follow: {e}") from None
