"""`FlightLog`: the calls a flight makes to be recorded or watched live.

    log.frame(t, image=..., vehicle=...)      camera frame (RGB array, or JPEG bytes as received)
    log.pose(t, pos_ned, quat_wxyz)           vehicle pose (and its transform)
    log.decision(t, record)                   per-decision record; also φ(s) and the setpoints
    log.phi(t, values)                        φ(s) alone (when there is no decision record)
    log.event(t, record)                      safety-net event (JSON and a log line)
    log.ugvs(t, states)                       UGV states (list of dicts or a UGVStates)
    log.ugv_entities(t, entities)             the same, from entities already drawn
                                              (messages.ugv_entity: the Zenoh recorder)
    log.geometry(t, spec_or_polylines)        fence and envelope as lines
    log.clock(t)                              simulation time
    log.advertise(vehicle)                    open every channel now (a live view shows them all
                                              before the flight's first message)

Every time t is simulation time [s]. A FlightLog writes to one or more sinks (an MCAP file, a
Foxglove WebSocket server): anything with `channel(spec) -> handle` and
`write(handle, t_ns, data)` and `close()`. A sink that fails is counted and skipped, so a
recorder can never stop a flight.
"""

from __future__ import annotations

import collections
import math
import threading
from typing import Any, Protocol

import numpy as np
from foxglove.messages import SceneUpdate

from skyherd.record import messages as m


class Sink(Protocol):
    def channel(self, spec: m.ChannelSpec) -> Any: ...
    def write(self, handle: Any, t_ns: int, data: bytes) -> None: ...
    def close(self) -> None: ...


def _feature_names(n: int) -> tuple[str, ...]:
    from skyherd.perception.features import FEATURE_NAMES

    return FEATURE_NAMES if len(FEATURE_NAMES) == n else tuple(f"phi{i}" for i in range(n))


def ugv_records(states: Any) -> list[dict]:
    """UGV states as records ({id, pos_ned, heading_rad, camouflaged}) from a list of the
    Zenoh records (groundsim.transport) or a groundsim UGVStates."""
    if isinstance(states, list | tuple):
        return [dict(s) for s in states]
    pos = np.asarray(states.pos_ne, dtype=float)
    head = np.asarray(states.heading, dtype=float)
    cam = np.asarray(getattr(states, "camouflaged", np.zeros(len(pos), bool)))
    return [
        {"id": i, "pos_ned": [pos[i, 0], pos[i, 1], 0.0], "heading_rad": float(head[i]),
         "camouflaged": bool(cam[i])}
        for i in range(len(pos))
    ]  # fmt: skip


class FlightLog:
    """Builds the messages of `record.messages` and hands them to every sink."""

    def __init__(self, *sinks: Sink):
        self.sinks = list(sinks)
        self.counts: dict[str, int] = {}  # topic → messages written
        self.errors = 0  # sink writes that raised (counted, skipped)
        self._handles: dict[tuple[int, str], Any] = {}
        self._specs: dict[tuple[str, str], m.ChannelSpec] = {}  # (kind, vehicle) → its channel
        # vehicle → its newest poses' (time, position): a decision is drawn from its own time's
        self._poses: dict[str, collections.deque] = {}
        self._lock = threading.Lock()  # Zenoh callbacks arrive on several threads
        self.closed = False
        self._events: dict[str, int] = {}  # vehicle → safety events so far

    def advertise(self, vehicle: str = "uav0") -> None:
        """Open every channel of `vehicle` and the shared ones now on every sink that serves
        clients (`advertise_all`: a live view), so a client sees (and can subscribe to) all of
        them before the flight's first message; a file gets a channel with its first message."""
        kinds = [(k, vehicle) for k in m.VEHICLE_KINDS] + [(k, "") for k in m.SHARED_KINDS]
        with self._lock:
            for kind, v in kinds:
                spec = m.channel(kind, v or "uav0")
                for i, s in enumerate(self.sinks):
                    if (i, spec.topic) in self._handles or not getattr(s, "advertise_all", False):
                        continue
                    try:
                        self._handles[(i, spec.topic)] = s.channel(spec)
                    except Exception:  # noqa: BLE001 - a recorder never stops a flight
                        self.errors += 1

    POSES = 64  # poses kept per vehicle for `_position` (6.4 s of 10 Hz camera frames)

    def _position(self, vehicle: str, t: float):
        """The vehicle's position at time t: its newest pose not later than t (a decision is
        drawn from the pose it was made from, also when the next frame's pose came first: the
        Zenoh recorder's keys race), else the newest; None before any pose."""
        poses = self._poses.get(vehicle)
        if not poses:
            return None
        for tp, p in reversed(poses):
            if tp <= t:
                return p
        return poses[-1][1]

    # -- plumbing ---------------------------------------------------------------------
    def _emit(self, kind: str, vehicle: str, t: float, data: bytes) -> None:
        spec = self._specs.get((kind, vehicle))
        if spec is None:  # made once per channel (a schema each time costs ~1.5 µs a message)
            spec = self._specs[(kind, vehicle)] = m.channel(kind, vehicle)
        t_ns = m.ns(t)
        with self._lock:
            if self.closed:
                return
            for i, s in enumerate(self.sinks):
                try:
                    h = self._handles.get((i, spec.topic))
                    if h is None:
                        h = self._handles[(i, spec.topic)] = s.channel(spec)
                    s.write(h, t_ns, data)
                except Exception:  # noqa: BLE001 - a recorder never stops a flight
                    self.errors += 1
            self.counts[spec.topic] = self.counts.get(spec.topic, 0) + 1

    # -- the calls ----------------------------------------------------------------------
    def frame(self, t: float, image: np.ndarray | None = None, *, jpeg: bytes | None = None,
              vehicle: str = "uav0", jpeg_quality: int = 85) -> None:  # fmt: skip
        """A camera frame: `image` (H, W, 3) uint8 RGB, or `jpeg` bytes as they arrived."""
        if jpeg is None:
            if image is None:
                raise ValueError("frame needs an image or jpeg bytes")
            from skyherd.perception.transport import JPEG, encode_pixels

            jpeg = encode_pixels(image, JPEG, jpeg_quality)
        self._emit("frame", vehicle, t, m.compressed_image(t, jpeg, vehicle).encode())

    def pose(self, t: float, pos_ned, quat_wxyz=(1.0, 0.0, 0.0, 0.0), *,
             vehicle: str = "uav0") -> None:  # fmt: skip
        """Vehicle position [m] NED and attitude (w, x, y, z) body → NED."""
        p = m.finite3(pos_ned)
        if p is None:  # not three finite numbers: nothing to show
            return
        self._poses.setdefault(vehicle, collections.deque(maxlen=self.POSES)).append((t, p))
        pose, tf = m.pose_and_transforms(t, p, quat_wxyz, vehicle)
        self._emit("pose", vehicle, t, pose.encode())
        self._emit("tf", vehicle, t, tf.encode())

    def phi(self, t: float, values, *, vehicle: str = "uav0", names=None) -> None:
        v = [float(x) for x in values]
        names = tuple(names) if names is not None else _feature_names(len(v))
        rec = {"t": t, "features": dict(zip(names, v)), "values": v}
        self._emit("phi", vehicle, t, m.json_bytes(rec))

    def decision(self, t: float, record: dict[str, Any], *, vehicle: str | None = None) -> None:
        """The per-decision record (LAYOUT.md) as JSON, with φ(s) on its own channel and the
        proposed / certified setpoints drawn from the vehicle's last pose."""
        vehicle = vehicle or str(record.get("vehicle", "uav0"))
        self._emit("decision", vehicle, t, m.json_bytes(record))
        if record.get("phi") is not None:
            self.phi(t, record["phi"], vehicle=vehicle)
        prop, cert = record.get("proposed"), record.get("certified")
        scene = m.setpoint_scene(t, self._position(vehicle, t), prop, cert, vehicle)
        self._emit("setpoint", vehicle, t, scene.encode())
        pos = (cert or {}).get("pos_ned")
        if pos is not None and np.all(np.isfinite(np.asarray(pos, dtype=float))):
            yaw = (cert or {}).get("yaw")
            q = (1.0, 0.0, 0.0, 0.0)
            if yaw is not None and math.isfinite(yaw):
                q = (math.cos(yaw / 2), 0.0, 0.0, math.sin(yaw / 2))
            self._emit("setpoint_pose", vehicle, t, m.pose_in_frame(t, pos, q).encode())

    def event(self, t: float, record: dict[str, Any], *, vehicle: str = "uav0") -> None:
        """A safety-net event: the event, its log line, and the net's latched state (the
        newest event, re-sent to a live client that subscribes later)."""
        self._emit("event", vehicle, t, m.json_bytes(record))
        self._emit("log", vehicle, t, m.log_line(t, record, vehicle).encode())
        n = self._events[vehicle] = self._events.get(vehicle, 0) + 1
        self._emit(
            "net_state", vehicle, t, m.json_bytes({"t": t, "events": n, "last_event": record})
        )

    def ugvs(self, t: float, states: Any) -> None:
        self._emit("ugvs", "", t, m.ugv_scene(t, ugv_records(states)).encode())

    def ugv_entities(self, t: float, entities: list) -> None:
        """UGVs already drawn (messages.ugv_entity, stamped t) as one /ugvs scene."""
        self._emit("ugvs", "", t, SceneUpdate(entities=entities).encode())

    def geometry(self, t: float, spec: Any = None, *, polylines=None, entity: str = "fence",
                 rgba=m.GREEN) -> None:  # fmt: skip
        """The fence and envelope: an EnvelopeSpec (its inclusion zones green and exclusion
        zones red, each as a prism from floor to ceiling), or explicit (N, 3) NED polylines."""
        if polylines is not None:
            self._emit("geometry", "", t, m.line_scene(t, entity, polylines, rgba).encode())
            return
        lim = spec.limits
        for kind, zones, colour in (("inclusion", spec.inclusions, m.GREEN),
                                    ("exclusion", spec.exclusions, m.RED)):  # fmt: skip
            for z in zones:
                lines = m.prism(z.points, lim.floor_m, lim.ceiling_m)
                scene = m.line_scene(t, f"fence/{kind}/{z.name}", lines, colour)
                self._emit("geometry", "", t, scene.encode())
        if lim.home_radius_m > 0:
            a = np.linspace(0, 2 * np.pi, 64, endpoint=False)
            ring = lim.home_radius_m * np.column_stack([np.cos(a), np.sin(a)])
            scene = m.line_scene(t, "envelope/home_radius",
                                 m.prism(ring, lim.floor_m, lim.ceiling_m), m.ORANGE)  # fmt: skip
            self._emit("geometry", "", t, scene.encode())

    def clock(self, t: float) -> None:
        self._emit("clock", "", t, m.json_bytes({"t_sim": t}))

    def close(self) -> None:
        with self._lock:
            if self.closed:
                return
            self.closed = True
            for s in self.sinks:
                try:
                    s.close()
                except Exception:  # noqa: BLE001
                    self.errors += 1

    def __enter__(self):
        return self

    def __exit__(self, *exc) -> None:
        self.close()
