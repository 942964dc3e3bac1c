"""One UDP link of the endpoint: a non-blocking socket with a default peer.

Outgoing frames go to the link's default remote address (CONVENTIONS.md) and also to
whoever last sent us a valid frame on this socket, so clients that bind elsewhere
(`udpout:` in pymavlink, a second ground station) are answered too.

A link made with `watch_remote` also learns whether anything listens at its default remote:
a datagram sent to a loopback or LAN port nobody has bound comes back as ICMP port
unreachable, which Linux queues on the sender's socket with IP_RECVERR (read with
MSG_ERRQUEUE; loopback answers inside the sendto itself). `nobody_listens()` says so, and the
endpoint then streams only heartbeats there until one is no longer refused.
"""

from __future__ import annotations

import errno
import socket
import struct
import sys
from collections.abc import Callable

from skyherd.flight.mavlink.codec import Codec, MAVLinkMessage
from skyherd.flight.mavlink.payload import Payload
from skyherd.flight.mavlink.signing import Signing

Address = tuple[str, int]
MAX_DATAGRAM = 65535
PACKED_DATAGRAM = 1400  # coalesced frames per datagram, at most [bytes] (fits a 1500 B MTU)
# Linux's IP_RECVERR (netinet/in.h; the socket module does not name it): ICMP errors of an
# unconnected UDP socket are queued for MSG_ERRQUEUE instead of dropped. None elsewhere.
IP_RECVERR = getattr(socket, "IP_RECVERR", 11 if sys.platform.startswith("linux") else None)
_EE_ERRNO = struct.Struct("=I")  # struct sock_extended_err's first field, ee_errno


class UdpLink:
    """A named UDP link bound to `bind`, sending to `remote` and to the last sender."""

    def __init__(
        self,
        name: str,
        bind: Address,
        remote: Address,
        system_id: int,
        component_id: int,
        on_frame: Callable[[str, bytes], None] | None = None,
        signing: Signing | None = None,
        link_id: int = 0,
        watch_remote: bool = False,
    ):
        self.name = name
        self.bind_addr = bind
        self.remote = remote
        self.peer: Address | None = None
        self.codec = Codec(system_id, component_id, signing, link_id)
        self._on_frame = on_frame  # tlog hook: (direction "in"/"out", one frame's bytes)
        self.muted = False  # a simulated link cut (world.sim): send nothing
        self.stats_muted = 0
        self.sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        try:
            self.sock.bind(bind)
        except OSError as e:
            self.sock.close()
            raise OSError(f"{name} link cannot bind UDP {bind[0]}:{bind[1]}: {e.strerror}") from e
        self.sock.setblocking(False)
        try:  # room for bursts (parameter lists, mission uploads); the kernel may cap it
            self.sock.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 1 << 20)
        except OSError:
            pass
        self.send_errors = 0
        self.rx_datagrams = 0
        self.coalesce = False  # hold frames for the default peers until `flush()` (the endpoint:
        # until the end of its step; a lockstep gate: until the tick's mark)
        self._held: list[bytes] = []
        self.watch_remote = watch_remote and IP_RECVERR is not None and self._recverr_on()
        self.remote_refuses = False  # the last datagrams sent to `remote` came back refused
        self._sent_remote = False  # something went to `remote` since nobody_listens() last looked

    def receive(self, max_datagrams: int = 256) -> list[tuple[MAVLinkMessage, Address]]:
        """Drain up to `max_datagrams` waiting datagrams; returns decoded messages with senders."""
        out: list[tuple[MAVLinkMessage, Address]] = []
        for _ in range(max_datagrams):
            try:
                data, addr = self.sock.recvfrom(MAX_DATAGRAM)
            except (BlockingIOError, InterruptedError):
                break
            except OSError:  # e.g. ICMP port unreachable reported on a later call
                continue
            self.rx_datagrams += 1
            msgs = self.codec.parse(data)
            if not msgs:
                continue
            sender = (addr[0], addr[1])
            if self.codec.authentic(msgs):  # never an unsigned sender on a signed link
                self.peer = sender
            if self._on_frame is not None:  # each parsed frame, never the raw datagram
                for m in msgs:
                    self._on_frame("in", bytes(m.get_msgbuf()))
            out.extend((m, sender) for m in msgs)
        return out

    def send(self, msg: MAVLinkMessage, to: Address | None = None, force: bool = False) -> None:
        """Send one message to `to`, or to the default remote and the last sender. While `muted`
        (a simulated link cut) nothing leaves unless `force` (the lockstep's own time sync)."""
        if self.muted and not force:
            self.stats_muted += 1
            return
        buf = self.codec.pack(msg)
        if self._on_frame is not None:
            self._on_frame("out", buf)
        if to is not None:
            self.flush()  # what was held goes first: frames leave in the order they were sent
            self._sendto(buf, to)
        elif self.coalesce:
            self._held.append(buf)
        else:
            self._send_default(buf)

    def send_payloads(self, payloads: list[Payload]) -> None:
        """`send` of each telemetry payload to the default peers, framed and signed as one
        batch (a stream instant's messages)."""
        if self.muted:
            self.stats_muted += len(payloads)
            return
        frames = self.codec.pack_payloads(payloads)
        if self._on_frame is not None:
            for buf in frames:
                self._on_frame("out", buf)
        if self.coalesce:
            self._held += frames
        else:
            for buf in frames:
                self._send_default(buf)

    @property
    def has_held(self) -> bool:
        """Frames wait for `flush()`."""
        return bool(self._held)

    def flush(self) -> None:
        """Send the held frames, packed whole into as few datagrams as fit PACKED_DATAGRAM: a
        step's telemetry costs one system call, a lockstep tick's telemetry and its mark wake
        the companion once. Frame order is kept; every MAVLink parser reads several frames from
        one datagram (PX4 itself sends one frame per datagram)."""
        if not self._held:
            return
        held, self._held = self._held, []
        if sum(map(len, held)) <= PACKED_DATAGRAM:  # the common case: one datagram
            self._send_default(b"".join(held))
            return
        chunk = b""
        for buf in held:
            if chunk and len(chunk) + len(buf) > PACKED_DATAGRAM:
                self._send_default(chunk)
                chunk = b""
            chunk += buf
        if chunk:
            self._send_default(chunk)

    def _send_default(self, buf: bytes) -> None:
        self._sendto(buf, self.remote)
        self._sent_remote = True
        if self.peer is not None and self.peer != self.remote:
            self._sendto(buf, self.peer)

    def _sendto(self, buf: bytes, addr: Address) -> None:
        try:
            self.sock.sendto(buf, addr)
        except ConnectionRefusedError:  # an earlier datagram's refusal (IP_RECVERR), not this
            try:  # one's: the kernel reports it once, on the next call; send again
                self.sock.sendto(buf, addr)
            except OSError:
                self.send_errors += 1
        except OSError:  # nobody listening, buffer full: UDP drops, so do we
            self.send_errors += 1

    def nobody_listens(self) -> bool:
        """True while this link's frames reach no one: it watches its remote, no client has
        spoken on it (a `peer` is answered whatever the remote does), and the datagrams sent
        to the remote since the last look were refused (ICMP port unreachable). False as soon
        as one is sent there and not refused. Never True on a link without `watch_remote`, nor
        where no ICMP comes back (a firewall): there it streams as any PX4 link does."""
        if not self.watch_remote or self.peer is not None:
            return False
        if self.remote_refuses and not self._sent_remote:
            return True  # nothing went there since it refused (no system call: the common case)
        if self._take_refusals():
            self.remote_refuses = True
        elif self._sent_remote:
            self.remote_refuses = False
        self._sent_remote = False
        return self.remote_refuses

    def _recverr_on(self) -> bool:
        try:
            self.sock.setsockopt(socket.IPPROTO_IP, IP_RECVERR, 1)
            return True
        except OSError:
            return False

    def _take_refusals(self) -> bool:
        """Drain the socket's error queue; whether it held a refusal from `remote`."""
        refused = False
        while True:
            try:
                _, anc, _, dest = self.sock.recvmsg(1, 512, socket.MSG_ERRQUEUE)
            except OSError:  # BlockingIOError: the queue is empty
                return refused
            if dest is None or tuple(dest[:2]) != self.remote:
                continue  # a peer's refusal: the peer is answered anyway
            for _level, _type, data in anc:  # struct sock_extended_err
                if len(data) >= _EE_ERRNO.size:
                    refused |= _EE_ERRNO.unpack_from(data)[0] == errno.ECONNREFUSED

    def close(self) -> None:
        self.flush()
        self.sock.close()
