"""An in-process vehicle for the hostile-input and signing tests: the real autopilot and
endpoint on real UDP sockets (127.0.0.1), stepped by the test itself (no thread), so every
exchange is deterministic on the simulation clock: a datagram sent on loopback is in the
endpoint's socket before the next `step()`, and its answer in ours right after it."""

from __future__ import annotations

import socket

from pymavlink.dialects.v20 import ardupilotmega as M

from skyherd.flight.airframes_registry import make_autopilot
from skyherd.flight.clock import SimClock
from skyherd.flight.mavlink import EndpointConfig
from skyherd.flight.sitl import Sitl


class Peer:
    """A UDP socket speaking pymavlink's MAVLink 2 codec (encoder and a separate parser)."""

    def __init__(self, port: int = 0, system: int = 255, component: int = 190):
        self.sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self.sock.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 4 << 20)
        self.sock.bind(("127.0.0.1", port))
        self.sock.setblocking(False)
        self.mav = M.MAVLink(None, system, component)
        self.parser = M.MAVLink(None)
        self.parser.robust_parsing = True

    def send(self, msg_or_frame, to: tuple[str, int]) -> bytes:
        frame = (
            msg_or_frame if isinstance(msg_or_frame, bytes) else bytes(msg_or_frame.pack(self.mav))
        )
        self.sock.sendto(frame, to)
        return frame

    def recv(self) -> list:
        """Every message waiting (BAD_DATA included: a signing test wants to see them)."""
        out = []
        while True:
            try:
                data = self.sock.recv(65535)
            except BlockingIOError:
                return out
            out.extend(self.parser.parse_buffer(data) or [])

    def close(self) -> None:
        self.sock.close()


class Rig:
    """Quadrotor + endpoint of `instance`; `client` listens where the API link sends."""

    def __init__(self, instance: int, **config):
        self.instance = instance
        self.ap = make_autopilot("quadrotor", clock=SimClock(), instance=instance)
        self.config = EndpointConfig(instance=instance, **config)
        self.sitl = Sitl(self.ap, self.config, speedup=0.0)
        self.ep = self.sitl.endpoint
        self.sys = self.config.system_id
        self.api = self.config.api_bind
        self.client = Peer(14540 + instance)

    def step(self, sim_s: float = 0.0) -> None:
        """At least one lockstep iteration, then more until `sim_s` has passed."""
        t_end = self.ap.clock.t + sim_s
        self.sitl.step()
        while self.ap.clock.t < t_end - 1e-9:
            self.sitl.step()

    def exchange(self, msg, peer: Peer | None = None) -> list:
        """Send one message to the API link, step once, return what came back."""
        peer = peer or self.client
        peer.recv()  # forget what was waiting
        peer.send(msg, self.api)
        self.sitl.step()
        return peer.recv()

    def command(self, cmd: int, *p: float, peer: Peer | None = None):
        peer = peer or self.client
        params = list(p) + [0.0] * (7 - len(p))
        got = self.exchange(peer.mav.command_long_encode(self.sys, 1, cmd, 0, *params), peer)
        acks = [m for m in got if m.get_type() == "COMMAND_ACK" and m.command == cmd]
        return acks[-1] if acks else None

    def fly(self, altitude: float = 10.0) -> None:
        """Arm and take off in-process, then hover."""
        assert self.ap.arm().ok
        assert self.ap.takeoff(altitude).ok
        self.step(12.0)

    def close(self) -> None:
        self.client.close()
        self.sitl.close()

    def __enter__(self) -> Rig:
        return self

    def __exit__(self, *exc) -> None:
        self.close()


def texts(msgs) -> list[str]:
    return [m.text for m in msgs if m.get_type() == "STATUSTEXT"]
