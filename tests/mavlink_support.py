"""Test support for the MAVLink endpoint tests: an in-process SITL on a thread and a small
pymavlink client speaking to it over real UDP sockets on 127.0.0.1."""

from __future__ import annotations

import contextlib
import math
import socket
import time
from pathlib import Path

from pymavlink.dialects.v20 import ardupilotmega as M

from skyherd.flight.airframes_registry import make_autopilot
from skyherd.flight.clock import SimClock
from skyherd.flight.mavlink import EndpointConfig, Personality
from skyherd.flight.sitl import Sitl


@contextlib.contextmanager
def running_sitl(
    instance: int,
    speedup: float = 5.0,
    state_dir: Path | None = None,
    personality: Personality = Personality.PX4,
    airframe: str = "quadrotor",
    signing_key: Path | None = None,
):
    """A real MultirotorAutopilot + endpoint, stepping on a background thread (`signing_key`:
    MAVLink 2 signing on both links with that key file)."""
    ap = make_autopilot(airframe, clock=SimClock(), instance=instance)
    cfg = EndpointConfig(instance=instance, personality=personality, state_dir=state_dir,
                         signing_key=signing_key)  # fmt: skip
    sitl = Sitl(ap, cfg, speedup=speedup)
    try:
        sitl.start()
        yield sitl
    finally:
        sitl.close()


class V2Socket:
    """pymavlink's MAVLink 2 `ardupilotmega` codec on a plain UDP socket.

    `udpin:` binds `port` and answers whoever sent last; `udpout:` sends to `port`.
    (mavutil's connections start in MAVLink 1 unless a process-wide environment variable
    is set, and switch dialect on the fly; the tests use the codec directly instead.)
    """

    def __init__(self, mode: str, port: int, source_system: int = 255, source_component: int = 190):
        self.sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        # Room for telemetry that queues while a test is busy sending (capped by rmem_max).
        self.sock.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 4 << 20)
        if mode == "udpin":
            self.sock.bind(("127.0.0.1", port))
            self.peer = None
        else:
            self.sock.bind(("127.0.0.1", 0))
            self.peer = ("127.0.0.1", port)
        self.mav = M.MAVLink(self, srcSystem=source_system, srcComponent=source_component)
        self.mav.robust_parsing = True
        self._pending: list = []

    def write(self, buf: bytes) -> None:
        if self.peer is not None:
            self.sock.sendto(bytes(buf), self.peer)

    def recv_match(self, blocking: bool = True, timeout: float = 1.0):
        """Next decoded message (any type) or None."""
        deadline = time.monotonic() + (timeout if blocking else 0.0)
        while not self._pending:
            left = deadline - time.monotonic()
            if blocking and left <= 0:
                return None
            self.sock.settimeout(left if blocking else 0.0)
            try:
                data, addr = self.sock.recvfrom(65535)
            except (TimeoutError, BlockingIOError):
                return None
            self.peer = addr if self.peer is None or self.peer[1] != addr[1] else self.peer
            msgs = self.mav.parse_buffer(data) or []
            self._pending.extend(m for m in msgs if m.get_type() != "BAD_DATA")
        return self._pending.pop(0)

    def close(self) -> None:
        self.sock.close()


def v2_connection(address: str, source_system: int = 255) -> V2Socket:
    mode, _, port = address.rpartition(":")
    return V2Socket(mode.split(":")[0], int(port), source_system)


class Client:
    """A pymavlink ground station on the API link of instance N (udpin 14540+N)."""

    def __init__(
        self, instance: int, port: int | None = None, source_system: int = 255, mode: str = "udpin"
    ):
        port = 14540 + instance if port is None else port
        self.target = 1 + instance
        self.conn = V2Socket(mode, port, source_system)
        self.mav = self.conn.mav
        self.texts: list[str] = []  # every STATUSTEXT seen, in order

    def close(self) -> None:
        self.conn.close()

    def __enter__(self) -> Client:
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    def wait_heartbeat(self, timeout: float = 10.0):
        hb = self.recv("HEARTBEAT", timeout)
        assert hb is not None, "no HEARTBEAT from the vehicle"
        return hb

    def recv(self, types, timeout: float = 5.0, cond=None):
        """Next message of `types` (str or list) satisfying `cond`, or None after `timeout`."""
        types = [types] if isinstance(types, str) else list(types)
        deadline = time.monotonic() + timeout
        while True:
            left = deadline - time.monotonic()
            if left <= 0:
                return None
            m = self.conn.recv_match(blocking=True, timeout=left)
            if m is None:
                continue
            if m.get_srcSystem() != self.target:
                continue  # another vehicle (e.g. a GCS link sending to 14550)
            if m.get_type() == "STATUSTEXT":
                self.texts.append(m.text)
            if m.get_type() in types and (cond is None or cond(m)):
                return m

    def drain(self) -> None:
        while (m := self.conn.recv_match(blocking=False)) is not None:
            if m.get_type() == "STATUSTEXT":
                self.texts.append(m.text)

    def saw_text(self, part: str, timeout: float = 2.0) -> bool:
        """True once a STATUSTEXT containing `part` was seen (waiting up to `timeout`)."""
        deadline = time.monotonic() + timeout
        while not any(part in t for t in self.texts) and time.monotonic() < deadline:
            self.recv("STATUSTEXT", deadline - time.monotonic())
        return any(part in t for t in self.texts)

    def command(self, cmd: int, *params: float, confirmation: int = 0, timeout: float = 3.0):
        """COMMAND_LONG → its final COMMAND_ACK (IN_PROGRESS acks are skipped)."""
        p = list(params) + [0.0] * (7 - len(params))
        self.mav.command_long_send(self.target, 1, cmd, confirmation, *p)
        return self.recv(
            "COMMAND_ACK",
            timeout,
            lambda m: m.command == cmd and m.result != M.MAV_RESULT_IN_PROGRESS,
        )

    def command_int(self, cmd: int, frame: int, p1=0.0, p2=0.0, p3=0.0, p4=0.0, x=0, y=0, z=0.0):
        self.mav.command_int_send(self.target, 1, frame, cmd, 0, 0, p1, p2, p3, p4, x, y, z)
        return self.recv("COMMAND_ACK", 3.0, lambda m: m.command == cmd)

    # --- parameters -------------------------------------------------------------------------
    def param_list(self, timeout: float = 10.0) -> dict[str, tuple[float, int, int]]:
        """All parameters: name → (value, index, count)."""
        self.mav.param_request_list_send(self.target, 1)
        out: dict[str, tuple[float, int, int]] = {}
        count = None
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline and (count is None or len(out) < count):
            m = self.recv("PARAM_VALUE", deadline - time.monotonic())
            if m is None:
                break
            out[m.param_id] = (m.param_value, m.param_index, m.param_count)
            count = m.param_count
        return out

    def param_read(self, name: str, timeout: float = 3.0):
        self.mav.param_request_read_send(self.target, 1, name.encode(), -1)
        return self.recv("PARAM_VALUE", timeout, lambda m: m.param_id == name)

    def param_set(self, name: str, value: float, timeout: float = 3.0):
        self.mav.param_set_send(self.target, 1, name.encode(), value, M.MAV_PARAM_TYPE_REAL32)
        return self.recv("PARAM_VALUE", timeout, lambda m: m.param_id == name)

    # --- missions ---------------------------------------------------------------------------
    def mission_upload(self, items: list[tuple], mission_type: int = 0, timeout: float = 5.0):
        """Upload MISSION_ITEM_INT field tuples (frame, command, p1..p4, x, y, z); → MISSION_ACK."""
        self.mav.mission_count_send(self.target, 1, len(items), mission_type)
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            m = self.recv(
                ["MISSION_REQUEST_INT", "MISSION_REQUEST", "MISSION_ACK"],
                deadline - time.monotonic(),
            )
            if m is None:
                return None
            if m.get_type() == "MISSION_ACK":
                return m
            frame, command, p1, p2, p3, p4, x, y, z = items[m.seq]
            self.mav.mission_item_int_send(
                self.target, 1, m.seq, frame, command, 0, 1, p1, p2, p3, p4, x, y, z, mission_type
            )
        return None

    def mission_download(self, mission_type: int = 0, timeout: float = 5.0) -> list | None:
        self.mav.mission_request_list_send(self.target, 1, mission_type)
        cnt = self.recv("MISSION_COUNT", timeout, lambda m: m.mission_type == mission_type)
        if cnt is None:
            return None
        items = []
        for seq in range(cnt.count):
            self.mav.mission_request_int_send(self.target, 1, seq, mission_type)
            it = self.recv("MISSION_ITEM_INT", timeout, lambda m, s=seq: m.seq == s)
            if it is None:
                return None
            items.append(it)
        self.mav.mission_ack_send(self.target, 1, M.MAV_MISSION_ACCEPTED, mission_type)
        return items

    def mission_clear(self, mission_type: int = 0):
        self.mav.mission_clear_all_send(self.target, 1, mission_type)
        return self.recv("MISSION_ACK", 3.0)


def item_fields(m) -> tuple:
    """A downloaded MISSION_ITEM_INT as the tuple `mission_upload` takes."""
    return (m.frame, m.command, m.param1, m.param2, m.param3, m.param4, m.x, m.y, m.z)


def same_items(a: list[tuple], b: list[tuple]) -> bool:
    def eq(x, y):
        return x == y or (isinstance(x, float) and math.isnan(x) and math.isnan(y))

    return len(a) == len(b) and all(all(eq(x, y) for x, y in zip(p, q)) for p, q in zip(a, b))
