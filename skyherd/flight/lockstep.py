"""Lockstep between the simulated vehicle and its companion, on the vehicle's MAVLink API link.

The vehicle marks every camera instant t_k with a TIMESYNC request (tc1 = 0, ts1 = t_k in ns,
the vehicle's clock). The companion takes frame k, cuts its telemetry at that mark (everything
before it, nothing after), decides, sends its commands and setpoints, and closes the tick with
a TIMESYNC answer carrying the same ts1 (tc1 = its own time = t_k). The simulator does not step
past t_k + L (L, the companion's declared compute latency) until that answer has arrived; then
every message the companion sent before its answer is handled at t_k + L, in arrival order.

So what the companion sees, and when its decisions act, depends only on simulation time: the
same seed gives the same flight at any speed-up and any machine load. Free-running (no gate)
is what a real autopilot gives; its lag is measured instead (`Lag`).

Wall time appears only as patience: while it waits, the gate re-sends the mark (and the caller
re-publishes the frame) every `resend_s`, so a companion that starts late or lost a datagram
still gets its tick; a reply that never comes within `timeout_s` ends the wait with
`LockstepTimeout` (the companion is stuck or gone).
"""

from __future__ import annotations

import select
import threading
import time
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import TYPE_CHECKING

from skyherd.runio.constants import LOCKSTEP_LATENCY_S

if TYPE_CHECKING:  # LockstepParams alone (world.setup's checks) needs no MAVLink stack
    from skyherd.flight.mavlink.link import Address, UdpLink

NS_PER_US = 1000


class LockstepTimeout(Exception):
    """The companion did not close a tick in time."""


@dataclass(frozen=True)
class LockstepParams:
    latency_s: float = (
        LOCKSTEP_LATENCY_S  # the companion's declared compute latency L [s of simulation time]
    )
    resend_s: float = 0.25  # re-send the mark / frame while waiting, every [s of wall time]
    beacon_s: float = 0.05  # before the hello: the vehicle's heartbeat, every [s of wall time]
    timeout_s: float = 60.0  # give up on a tick after [s of wall time]

    def __post_init__(self) -> None:
        if not self.latency_s >= 0.0:
            raise ValueError(f"latency_s must be >= 0, got {self.latency_s}")
        if not (self.resend_s > 0.0 and self.timeout_s > self.resend_s):
            raise ValueError("resend_s must be > 0 and timeout_s > resend_s")
        if not self.beacon_s > 0.0:
            raise ValueError(f"beacon_s must be > 0, got {self.beacon_s}")


def is_mark(msg, t_ns: int | None = None) -> bool:
    """A vehicle's tick mark (TIMESYNC request), optionally for time t_ns."""
    return msg.get_type() == "TIMESYNC" and msg.tc1 == 0 and (t_ns is None or msg.ts1 == t_ns)


def is_close(msg, t_ns: int | None = None) -> bool:
    """A companion's tick close (TIMESYNC answer), optionally for time t_ns."""
    return msg.get_type() == "TIMESYNC" and msg.tc1 != 0 and (t_ns is None or msg.ts1 == t_ns)


@dataclass
class GateStats:
    ticks: int = 0
    resends: int = 0
    wait_wall_s: float = 0.0  # wall time spent waiting for the companion [s]
    stale_closes: int = 0  # answers for an older tick (a re-sent mark answered twice)
    batch_sizes: list[int] = field(default_factory=list, repr=False)


class LockstepGate:
    """The barrier on one UDP link of the vehicle's endpoint (which must not read it itself)."""

    def __init__(self, link: UdpLink, mav, params: LockstepParams = LockstepParams()):
        self.link, self.mav, self.p = link, mav, params
        self.stats = GateStats()
        self._carry: deque[tuple[object, Address]] = deque()
        self._batch: list[tuple[object, Address]] = []  # what arrived of the open tick so far
        self._next_beacon = 0.0  # wall time of the next heartbeat while waiting for a hello

    def mark(self, t_us: int, frame_seq: int | None = None) -> None:
        """Mark the camera instant t_us [µs] on the link (sent to the companion), announcing
        frame `frame_seq` first with CAMERA_IMAGE_CAPTURED when one was published for it (so a
        companion never waits for a frame a lost camera did not send). Both are the
        simulation's time sync, sent even while the link is cut."""
        if frame_seq is not None:
            self.link.send(self.mav.camera_image_captured_encode(
                t_us // 1000, 0, 0, 0, 0, 0, 0, [1.0, 0.0, 0.0, 0.0], frame_seq, 1, b""), force=True)  # fmt: skip
        self.link.send(self.mav.timesync_encode(0, t_us * NS_PER_US), force=True)
        self.link.flush()  # the tick's telemetry, the announcement and the mark: one datagram

    def poll_peer(self, beacon: Callable[[], None]) -> bool:
        """True once the companion's first datagram (its hello) has arrived; until then calls
        `beacon()` (the vehicle's heartbeat) every `beacon_s`, so a companion listening with
        `udpin` learns where the vehicle is (and the clock starts within `beacon_s` of its
        binding). Nothing else is sent before the hello, so nothing is lost to a companion that
        has not bound its socket yet; the hello is kept for the first batch. Never blocks:
        `world.sim.wait_for_peers` waits on the sockets of a whole fleet."""
        if self._carry:
            return True
        if time.monotonic() >= self._next_beacon:
            beacon()
            self.link.flush()
            self._next_beacon = time.monotonic() + self.p.beacon_s
        got = self.link.receive()
        if got:
            self._carry.extend(got)
            return True
        return False

    def collect(
        self,
        t_us: int,
        stop: threading.Event | None = None,
        on_wait: Callable[[], None] | None = None,
    ) -> list[tuple[object, Address]] | None:
        """Block until the companion closed tick t_us; return what it sent before the close.

        `on_wait()` runs every `resend_s` of waiting (after the mark is re-sent); returns None
        when `stop` is set. Raises LockstepTimeout after `timeout_s`."""
        stopped = (lambda: stop.is_set()) if stop is not None else (lambda: False)
        got = collect_closes([(self, t_us, on_wait)], stopped)
        return None if got is None else got[0]

    def poll_close(self, t_us: int) -> list[tuple[object, Address]] | None:
        """Never blocks: once the companion's close of tick t_us has arrived, what it sent
        before it (in arrival order); None until then (what came so far is kept)."""
        t_ns = t_us * NS_PER_US
        while True:
            while self._carry:
                msg, addr = self._carry.popleft()
                if is_close(msg, t_ns):
                    batch, self._batch = self._batch, []
                    return batch
                if is_close(msg):
                    self.stats.stale_closes += 1
                    continue
                self._batch.append((msg, addr))
            got = self.link.receive()
            if not got:
                return None
            self._carry.extend(got)

    def resend_mark(self, t_us: int) -> None:
        """The mark of tick t_us again (the companion started late or lost a datagram)."""
        self.link.send(self.mav.timesync_encode(0, t_us * NS_PER_US), force=True)
        self.link.flush()
        self.stats.resends += 1

    def _finish(self, batch: list, wall0: float) -> None:
        self.stats.ticks += 1
        self.stats.wait_wall_s += time.monotonic() - wall0
        self.stats.batch_sizes.append(len(batch))


Wait = tuple[LockstepGate, int, Callable[[], None] | None]  # gate, tick [µs], on_wait


def collect_closes(waits: list[Wait], stopped: Callable[[], bool]) -> list[list] | None:
    """Block until every gate's companion closed its tick; each tick's batch, in order. One
    `select` waits on all the sockets still open, so a fleet (or a companion flying several
    vehicles) that answers in a burst wakes this process once, not once per vehicle.

    While waiting, each gate re-sends its mark and runs its `on_wait` every `resend_s`; None
    once `stopped()`; LockstepTimeout when a gate waited longer than its `timeout_s`."""
    out: list[list | None] = [None] * len(waits)
    wall0 = time.monotonic()
    resend_s = min(g.p.resend_s for g, _, _ in waits)
    next_resend = wall0 + resend_s
    pending = list(range(len(waits)))
    look = pending  # the gates to read now: at first all, then those whose socket woke us
    while True:
        still = []
        for i in pending:
            if i not in look:
                still.append(i)
                continue
            gate, t_us, _ = waits[i]
            batch = gate.poll_close(t_us)
            if batch is None:
                still.append(i)
            else:
                gate._finish(batch, wall0)
                out[i] = batch
        pending = still
        if not pending:
            return out  # type: ignore[return-value]
        if stopped():
            return None
        now = time.monotonic()
        for i in pending:
            gate, t_us, _ = waits[i]
            if now - wall0 > gate.p.timeout_s:
                raise LockstepTimeout(
                    f"the companion did not close the tick at t = {t_us / 1e6:.3f} s within "
                    f"{gate.p.timeout_s:.0f} s of wall time (stuck, or not running)"
                )
        if now >= next_resend:
            for i in pending:
                gate, t_us, on_wait = waits[i]
                gate.resend_mark(t_us)
                if on_wait is not None:
                    on_wait()
            next_resend = now + resend_s
        socks = {waits[i][0].link.sock: i for i in pending}
        readable, _, _ = select.select(list(socks), [], [], min(0.05, max(0.0, next_resend - now)))
        look = {socks[s] for s in readable}
