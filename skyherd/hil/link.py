"""One MAVLink link for every tool: transports, framing and the tlog.

Addresses use pymavlink's forms (parsed by runio.address, the one parser):
    udpin:HOST:PORT     listen; replies go to whoever sent last
    udpout:HOST:PORT    send to HOST:PORT (and receive on the same socket)
    tcp:HOST:PORT       connect to a TCP server
    /dev/ttyACM0,57600  serial port with baud rate (default 57600)

MAVLink 2 framing is fixed at construction (no dialect chosen by environment variables);
MAVLink 1 frames are still parsed. Every frame sent or received (each parsed frame on its
own, never a raw datagram) can be recorded to a .tlog: 8-byte big-endian microseconds since
the Unix epoch, then the frame, appended and flushed per frame so a kill loses nothing already
written. A logging failure (full disk, read-only directory) is reported once on stderr and in
`tlog_error`; logging stops, the link goes on.

With `signing_key` (a 32-byte key file) the link signs what it sends and accepts only
correctly signed, fresh frames (plus RADIO_STATUS unsigned), as flight.mavlink.signing
describes. `StatustextAssembler` puts chunked STATUSTEXT back together.
"""

from __future__ import annotations

import math
import select
import socket
import threading
import time
from pathlib import Path
from typing import Protocol

from pymavlink.dialects.v20 import ardupilotmega as mavlink

from skyherd.flight.mavlink.codec import Codec, MAVLinkMessage
from skyherd.flight.mavlink.signing import Signing, load_key, now_units
from skyherd.flight.mavlink.statustext import StatustextAssembler
from skyherd.flight.mavlink.tlog import TlogWriter
from skyherd.hil.addresses import link_address, world_link
from skyherd.runio.address import Address

__all__ = [
    "LinkError",
    "MavlinkLink",
    "StatustextAssembler",
    "link_address",
    "world_link",
    "open_transport",
]

DEFAULT_BAUD = 57600


class LinkError(Exception):
    """The link cannot be opened or used; the message says what to check."""


class Transport(Protocol):
    def send(self, data: bytes) -> None: ...
    def recv(self, timeout: float) -> bytes:
        """Bytes received within `timeout` [s] (b'' if none)."""
        ...

    def close(self) -> None: ...


class UdpTransport:
    """UDP: `udpin` binds and answers the last sender; `udpout` sends to a fixed peer."""

    def __init__(self, addr: Address):
        self.sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self.peer: tuple[str, int] | None = None
        try:
            if addr.scheme in ("udpin", "udp"):  # udp: pymavlink's udpin
                self.sock.bind((addr.host, addr.port))
            else:
                self.peer = (addr.host, addr.port)
                self.sock.bind(("127.0.0.1" if addr.host.startswith("127.") else "", 0))
        except OSError as e:
            self.sock.close()
            raise LinkError(f"cannot bind UDP {addr.host}:{addr.port}: {e} (port in use?)") from e
        self.fixed_peer = addr.scheme == "udpout"
        self.last_sender: tuple[str, int] | None = None  # of the last datagram received

    def send(self, data: bytes) -> None:
        if self.peer is not None:
            try:
                self.sock.sendto(data, self.peer)
            except OSError:
                pass  # peer gone (ICMP unreachable): the link-loss logic notices silence

    def recv(self, timeout: float) -> bytes:
        r, _, _ = select.select([self.sock], [], [], max(0.0, timeout))
        if not r:
            return b""
        try:
            data, sender = self.sock.recvfrom(65535)
        except OSError:
            return b""
        self.last_sender = sender
        return data

    def accept_sender(self) -> None:
        """The last datagram held a valid (and, with signing, authentic) frame: `udpin`
        answers its sender from now on. Junk or forged datagrams never redirect replies."""
        if not self.fixed_peer and self.last_sender is not None:
            self.peer = self.last_sender

    def close(self) -> None:
        self.sock.close()


class TcpTransport:
    """A TCP client. `connect_wait_s` [s, wall]: keep retrying a refused connection this long
    (ArduPilot SITL listens on SERIAL1/2 only once a client has connected to SERIAL0)."""

    def __init__(self, addr: Address, connect_timeout: float = 5.0, connect_wait_s: float = 0.0):
        deadline = time.monotonic() + max(0.0, connect_wait_s)
        while True:
            try:
                self.sock = socket.create_connection(
                    (addr.host, addr.port), timeout=connect_timeout
                )
                break
            except ConnectionRefusedError as e:
                if time.monotonic() >= deadline:
                    raise LinkError(f"cannot connect TCP {addr.host}:{addr.port}: {e}") from e
                time.sleep(0.2)
            except OSError as e:
                raise LinkError(f"cannot connect TCP {addr.host}:{addr.port}: {e}") from e
        self.sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)

    def send(self, data: bytes) -> None:
        try:
            self.sock.sendall(data)
        except OSError:
            pass

    def recv(self, timeout: float) -> bytes:
        r, _, _ = select.select([self.sock], [], [], max(0.0, timeout))
        if not r:
            return b""
        try:
            return self.sock.recv(65535)
        except OSError:
            return b""

    def close(self) -> None:
        self.sock.close()


class SerialTransport:
    def __init__(self, addr: Address):
        import serial  # pyserial, only needed for serial links

        baud = addr.baud or DEFAULT_BAUD
        try:
            self.port = serial.Serial(addr.device, baud, timeout=0)
        except (serial.SerialException, OSError) as e:
            raise LinkError(f"cannot open {addr.device} at {baud} baud: {e}") from e

    def send(self, data: bytes) -> None:
        self.port.write(data)

    def recv(self, timeout: float) -> bytes:
        deadline = time.monotonic() + timeout
        while True:
            data = self.port.read(4096)
            if data or time.monotonic() >= deadline:
                return data
            time.sleep(0.001)

    def close(self) -> None:
        self.port.close()


def open_transport(address: str, connect_wait_s: float = 0.0) -> Transport:
    """The transport of a pymavlink-style address; `connect_wait_s`: see TcpTransport."""
    addr = link_address(address)
    if addr.scheme in ("udpin", "udpout", "udp"):
        return UdpTransport(addr)
    if addr.scheme == "tcp":
        return TcpTransport(addr, connect_wait_s=connect_wait_s)
    return SerialTransport(addr)


class MavlinkLink:
    """A MAVLink 2 speaker over one transport, thread-safe for sending.

    source_system/component: who we are (255/190 a ground station, or our companion at
    1+N/191 beside an autopilot). signing_key: a 32-byte key file, MAVLink 2 signing on
    (raises signing.SigningError for a bad file); link_id: our link id in the signatures.
    """

    def __init__(
        self,
        transport: Transport,
        source_system: int = 255,
        source_component: int = 190,
        tlog: Path | None = None,
        signing_key: Path | None = None,
        link_id: int = 0,
    ):
        self.signing = Signing(load_key(signing_key)) if signing_key is not None else None
        self.transport = transport
        self.codec = Codec(source_system, source_component, self.signing, link_id)
        self.mav = self.codec.mav
        self.tlog = TlogWriter(tlog) if tlog else None
        self.defer_log = False  # hold tlog records until `flush_log()` (a lockstep companion
        # writes them after its tick's close, off the simulation's critical path)
        self._unlogged: list[tuple[int, list]] = []  # (stamp [µs], frames or messages)
        self._send_lock = threading.Lock()
        self.datagrams = isinstance(transport, UdpTransport)
        self._stream = Codec(source_system, source_component).rx  # byte streams (TCP, serial)
        self._stream.robust_parsing = True

    @property
    def bad_packets(self) -> int:
        return self.codec.stats.rx_bad

    @property
    def rejected_packets(self) -> int:
        """Valid frames refused by signing (unsigned, wrongly signed, replayed)."""
        return self.codec.stats.rx_rejected

    @property
    def tlog_error(self) -> str | None:
        """Why the tlog stopped (a full disk...), None while it works or with no tlog."""
        return getattr(self.tlog, "error", None)

    def setup_signing(self, target_system: int, target_component: int = 1) -> None:
        """Send our key to a vehicle (SETUP_SIGNING; never written to the tlog). A vehicle
        without a key takes it; one already signing takes it only if we hold its current key."""
        if self.signing is None or self.signing.key is None:
            raise LinkError("setup_signing needs a link opened with signing_key")
        if getattr(self.transport, "peer", ()) is None:  # udpin that heard only unsigned frames
            self.transport.accept_sender()  # provisioning: the vehicle that spoke last
        self.send(self.mav.setup_signing_encode(
            target_system, target_component, list(self.signing.key), now_units()
        ))  # fmt: skip

    def provision_signing(self, patience_s: float = 30.0, resend_s: float = 1.0) -> int:
        """`--setup-signing`: send our key (SETUP_SIGNING, to system 0: whoever speaks here)
        until a frame signed with it comes back; returns how many were sent (0: the vehicle
        already signs with our key). LinkError after `patience_s` [s, wall: an outside
        autopilot's own pace] with the reason: nothing heard, or frames still refused (a
        vehicle that holds another key takes a new one only signed with its current key)."""
        if self.signing is None or self.signing.key is None:
            raise LinkError("--setup-signing needs a key: give --signing-key FILE")
        t_end = time.monotonic() + patience_s
        sent, t_sent, heard = 0, -math.inf, False
        while time.monotonic() < t_end:
            rejected = self.rejected_packets
            if self.recv(0.1):
                return sent  # a frame passed our signing: the vehicle signs with our key
            heard = heard or self.rejected_packets > rejected
            if heard and time.monotonic() - t_sent >= resend_s:
                self.setup_signing(0, 0)
                sent, t_sent = sent + 1, time.monotonic()
        why = ("nothing was heard on the link" if not heard else
               f"its frames are still refused after {sent} SETUP_SIGNING (does it hold another "
               "key? then give that one)")  # fmt: skip
        raise LinkError(f"--setup-signing: the vehicle did not start signing with our key in "
                        f"{patience_s:.0f} s: {why}")  # fmt: skip

    @staticmethod
    def open(address: str, connect_wait_s: float = 0.0, **kwargs) -> MavlinkLink:
        """`MavlinkLink.open("udpin:HOST:PORT", signing_key=Path("uav.key"), tlog=...)`;
        `connect_wait_s` [s]: how long a refused TCP connection is retried (default: not)."""
        signing_key = kwargs.get("signing_key")
        if signing_key is not None:
            load_key(signing_key)  # a bad key file fails before any socket is opened
        return MavlinkLink(open_transport(address, connect_wait_s), **kwargs)

    def send(self, msg: MAVLinkMessage) -> None:
        self.send_many([msg])

    def send_many(self, msgs: list[MAVLinkMessage]) -> None:
        """Send messages in order, as one write (one UDP datagram of whole frames): a lockstep
        tick's setpoints and its close wake the vehicle once."""
        with self._send_lock:
            frames = [self.codec.pack(m) for m in msgs]
            self.transport.send(b"".join(frames))
        if self.tlog:
            self._log(frames)

    def recv(self, timeout: float = 0.1) -> list[MAVLinkMessage]:
        """Messages decoded from whatever arrives within `timeout` [s]. Bad bytes are skipped."""
        data = self.transport.recv(timeout)
        if not data:
            return []
        if self.datagrams:  # a UDP datagram carries whole frames: parse each on its own
            msgs = self.codec.parse(data)
            if msgs and self.codec.authentic(msgs):
                self.transport.accept_sender()
        else:  # a byte stream: frames may span reads
            msgs = [m for m in (self._stream.parse_buffer(data) or [])
                    if not isinstance(m, mavlink.MAVLink_bad_data | mavlink.MAVLink_unknown)
                    and self.codec.accept(m)]  # fmt: skip
        if self.tlog and msgs:
            self._log(msgs)
        return msgs

    def _log(self, items: list) -> None:
        """Frames sent or messages received, to the tlog now or (`defer_log`) at `flush_log`,
        stamped now either way."""
        if self.defer_log:
            self._unlogged.append((self.tlog.stamp_us(), items))
        else:
            self.tlog.write_many(_frames(items))

    def flush_log(self) -> None:
        """Write the tlog records `defer_log` held, in the order they were sent and received."""
        held, self._unlogged = self._unlogged, []
        if held:
            self.tlog.write_stamped([(stamp_us, _frames(items)) for stamp_us, items in held])

    def close(self) -> None:
        self.transport.close()
        if self.tlog:
            self.flush_log()
            self.tlog.close()


def _frames(items: list) -> list:
    """The frames: sent frames are bytes already, a received message gives its buffer."""
    return [m if isinstance(m, bytes) else m.get_msgbuf() for m in items]
