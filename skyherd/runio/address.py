"""One address syntax for every `--connect`-style option: pymavlink's.

    udpin:HOST:PORT   udpout:HOST:PORT   udp:HOST:PORT   tcp:HOST:PORT   tcpin:HOST:PORT
    /dev/ttyACM0[,BAUD]   COM3[,BAUD]

MAVLink options hand the text to pymavlink as it is. Zenoh options take the same text and
translate it into a Zenoh endpoint (`tcp:HOST:PORT` → `tcp/HOST:PORT`); Zenoh's own form
`tcp/HOST:PORT` is accepted too. Anything else raises AddressError with a one-line reason
(never a library's own error text).
"""

from __future__ import annotations

import os
import re
from dataclasses import dataclass

from skyherd.runio.constants import API_REMOTE_BASE, LOOPBACK

SCHEMES = ("udpin", "udpout", "udp", "tcp", "tcpin")
FORMS = "tcp:HOST:PORT, udpin:HOST:PORT, udpout:HOST:PORT or /dev/ttyX[,BAUD]"
_HOST = re.compile(r"^(\[[0-9a-fA-F:.]+\]|[A-Za-z0-9.\-]+)$")


class AddressError(ValueError):
    """An address that is not in the one syntax (one-line message)."""


@dataclass(frozen=True)
class Address:
    scheme: str  # udpin | udpout | udp | tcp | tcpin | serial
    host: str = ""
    port: int = 0
    device: str = ""
    baud: int = 0

    @property
    def mavlink(self) -> str:
        """The pymavlink connection string."""
        if self.scheme == "serial":
            return f"{self.device},{self.baud}" if self.baud else self.device
        return f"{self.scheme}:{self.host}:{self.port}"

    @property
    def zenoh(self) -> str:
        """The Zenoh endpoint (`tcp/HOST:PORT` or `udp/HOST:PORT`)."""
        if self.scheme == "serial":
            raise AddressError(
                f"{self.mavlink}: a serial device is not a Zenoh endpoint; give tcp:HOST:PORT"
            )
        proto = "tcp" if self.scheme.startswith("tcp") else "udp"
        return f"{proto}/{self.host}:{self.port}"

    def __str__(self) -> str:
        return self.mavlink


def parse_address(text: str) -> Address:
    """An address in the one syntax (module docstring); AddressError otherwise."""
    s = str(text).strip()
    if not s:
        raise AddressError(f"empty address; give {FORMS}")
    if s.startswith("/dev/") or re.match(r"^COM\d+", s, re.IGNORECASE):
        dev, _, baud = s.partition(",")
        if baud and not (baud.isdigit() and int(baud) > 0):
            raise AddressError(f"{s!r}: the baud rate after ',' must be a positive integer")
        return Address("serial", device=dev, baud=int(baud) if baud else 0)
    m = re.match(r"^([A-Za-z]+)([:/])(.*)$", s)
    if not m or m.group(1).lower() not in SCHEMES:
        raise AddressError(f"{s!r} is not an address; give {FORMS}")
    scheme, sep, rest = m.group(1).lower(), m.group(2), m.group(3)
    if sep == "/" and scheme not in ("tcp", "udp"):
        raise AddressError(f"{s!r}: Zenoh form is tcp/HOST:PORT or udp/HOST:PORT; or give {FORMS}")
    host, colon, port = rest.rpartition(":")
    if not colon or not host:
        raise AddressError(
            f"{s!r} needs HOST:PORT after '{scheme}{sep}'; e.g. {scheme}:{LOOPBACK}:{API_REMOTE_BASE}"
        )
    if not _HOST.match(host):
        raise AddressError(f"{s!r}: {host!r} is not a host name or IP address")
    if not (port.isdigit() and 0 < int(port) < 65536):
        raise AddressError(f"{s!r}: port must be 1..65535, got {port!r}")
    return Address(scheme, host, int(port))


def zenoh_endpoint(text: str) -> str:
    """`tcp:HOST:PORT` (or `tcp/HOST:PORT`) → the Zenoh endpoint `tcp/HOST:PORT`."""
    return parse_address(text).zenoh


def mavlink_address(text: str) -> str:
    """A checked pymavlink connection string (Zenoh's `tcp/HOST:PORT` translated too)."""
    return parse_address(text).mavlink


def zenoh_config_file(path: str) -> str:
    """The `--zenoh-config` file `path`, once it is a file; AddressError naming the option."""
    if not os.path.isfile(path):
        raise AddressError(f"--zenoh-config {path}: no such file; pass a Zenoh JSON5 file")
    return path
