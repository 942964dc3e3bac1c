"""The addresses of a MAVLink link (hil.link), checked without opening one: `link_address`
(a link hil.link.MavlinkLink opens) and `world_link` (the second link of an outside autopilot
that the world follows). Apart from the link so that what only checks an address (`skyherd fly`
and `skyherd companion`'s checks) imports neither the link nor pymavlink.
"""

from __future__ import annotations

from skyherd.runio.address import Address, AddressError, parse_address
from skyherd.runio.ports import GCS_STREAM

LINK_SCHEMES = ("udpin", "udpout", "udp", "tcp", "serial")  # what hil.link opens (no tcpin)


def link_address(text: str) -> Address:
    """`text` parsed by the one address parser (runio.address) and checked to be a link
    hil.link opens; AddressError (a ValueError, one line) otherwise."""
    addr = parse_address(text)
    if addr.scheme not in LINK_SCHEMES:
        raise AddressError(
            f"{text!r}: a MAVLink link connects (udpin:, udpout:, udp:, tcp: or a serial "
            f"device), it does not listen on {addr.scheme}:"
        )
    return addr


def world_link(connect: str, given: str | None = None) -> str:
    """The MAVLink link the world follows the outside autopilot at `connect` on: `given`
    (`--world-link`, checked), else tcp:HOST:PORT+2 for tcp:HOST:PORT (ArduPilot's SERIAL1) or
    the autopilot's ground-station stream for a udp address; AddressError (one line) otherwise."""
    if given:
        try:
            link_address(given)
        except AddressError as e:
            raise AddressError(f"--world-link: {e}") from None
        return given
    a = link_address(connect)
    if a.scheme == "tcp":
        return f"tcp:{a.host}:{a.port + 2}"
    if a.scheme in ("udpin", "udpout", "udp"):
        return GCS_STREAM
    raise AddressError(
        "the ground-air mission around a serial autopilot needs --world-link ADDRESS"
    )
