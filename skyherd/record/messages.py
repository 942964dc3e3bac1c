"""What a flight looks like as Foxglove messages: topics, schemas and message builders.

One module decides every channel of a recording (the MCAP file and the live view carry the
same ones). Well-known Foxglove schemas (protobuf, from `foxglove-sdk`) where one fits, JSON
with a JSON schema for skyherd's own records:

| topic | schema | what |
| --- | --- | --- |
| `/<vehicle>/camera/image` | foxglove.CompressedImage (jpeg) | downward camera frames |
| `/<vehicle>/pose` | foxglove.PoseInFrame, frame `ned` | vehicle position and attitude |
| `/tf` | foxglove.FrameTransforms | `world` → `ned` (static) and `ned` → `<vehicle>` |
| `/<vehicle>/setpoint` | foxglove.SceneUpdate | proposed (grey) and certified (green) velocity arrows, position setpoint sphere |
| `/<vehicle>/setpoint/pose` | foxglove.PoseInFrame | the certified position setpoint (when there is one) |
| `/ugvs` | foxglove.SceneUpdate | one entity per UGV (cube, heading arrow, id label) |
| `/<vehicle>/phi` | JSON | φ(s): the named features and their values |
| `/<vehicle>/decision` | JSON | the per-decision record (LAYOUT.md): proposed, certified, verdict, reason, mode |
| `/<vehicle>/safety/event` | JSON | safety-net events (switches with their reasons) |
| `/<vehicle>/log` | foxglove.Log | each safety event as one log line (Foxglove's Log panel) |
| `/geometry` | foxglove.SceneUpdate | fence and envelope as lines (LinePrimitive) |
| `/sim/clock` | JSON | simulation time as the simulator published it |

Frames: data stay in local NED (CONVENTIONS.md). `world` is north-west-up, so that Foxglove's
3D panel (z up) shows the scene upright: `world` → `ned` is a 180° rotation about north.
Log time of every message is the simulation time [ns]; message timestamps are the same.
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass
from typing import Any

import numpy as np
from foxglove import Schema
from foxglove import messages as fm

from skyherd.runio import strict_json

WORLD, NED = "world", "ned"


def ns(t_s: float) -> int:
    """Simulation time [s] → integer nanoseconds (MCAP log time); negative or NaN → 0."""
    t = float(t_s)
    return int(round(t * 1e9)) if math.isfinite(t) and t > 0 else 0


def stamp(t_s: float) -> fm.Timestamp:
    n = ns(t_s)
    return fm.Timestamp(sec=n // 1_000_000_000, nsec=n % 1_000_000_000)


@dataclass(frozen=True)
class ChannelSpec:
    """A channel: topic, schema and message encoding (protobuf or json)."""

    topic: str
    schema: Schema
    message_encoding: str
    latched: str = ""  # a live view re-sends to each new subscriber: "all" its messages so
    # far, "last" the newest, "" nothing (record.live)


def _json_schema(name: str, title: str, properties: dict[str, Any]) -> Schema:
    doc = {"title": title, "type": "object", "properties": properties}
    return Schema(name=name, encoding="jsonschema", data=json.dumps(doc).encode())


_VEC = {"type": ["array", "null"], "items": {"type": "number"}}
_CMD = {
    "type": ["object", "null"],
    "properties": {"pos_ned": _VEC, "vel_ned": _VEC, "yaw": {"type": ["number", "null"]}},
}
SCHEMAS: dict[str, Schema] = {
    "phi": _json_schema(
        "skyherd.Phi",
        "φ(s): the features the policy sees",
        {"t": {"type": "number"}, "features": {"type": "object"}, "values": _VEC},
    ),
    "decision": _json_schema(
        "skyherd.Decision",
        "one pilot decision (LAYOUT.md per-decision record)",
        {
            "t": {"type": "number"},
            "vehicle": {"type": "string"},
            "pilot": {"type": "string"},
            "phi": _VEC,
            "proposed": _CMD,
            "certified": _CMD,
            "verdict": {"type": "string"},
            "reason": {"type": "string"},
            "mode": {"type": "string"},
            "autopilot_mode": {"type": "string"},
        },
    ),
    "event": _json_schema(
        "skyherd.SafetyEvent",
        "a safety-net event (events.jsonl record)",
        {"t": {"type": "number"}, "event": {"type": "string"}, "reason": {"type": "string"}},
    ),
    "clock": _json_schema(
        "skyherd.SimClock", "simulation time from the simulator", {"t_sim": {"type": "number"}}
    ),
    "net_state": _json_schema(
        "skyherd.NetState",
        "the safety net's newest event, latched: a live client that joins late gets it",
        {"t": {"type": "number"}, "events": {"type": "integer"}, "last_event": {"type": "object"}},
    ),
}

VEHICLE_KINDS = ("frame", "pose", "setpoint", "setpoint_pose", "log", "phi", "decision", "event",
                 "net_state")  # fmt: skip
SHARED_KINDS = ("tf", "ugvs", "geometry", "clock")
"""Every kind of message: a live view advertises all of them before the flight's first."""


def channel(kind: str, vehicle: str = "uav0") -> ChannelSpec:
    """The channel of one kind of message (see the table above)."""
    proto = {
        "frame": (f"/{vehicle}/camera/image", fm.CompressedImage),
        "pose": (f"/{vehicle}/pose", fm.PoseInFrame),
        "tf": ("/tf", fm.FrameTransforms),
        "setpoint": (f"/{vehicle}/setpoint", fm.SceneUpdate),
        "setpoint_pose": (f"/{vehicle}/setpoint/pose", fm.PoseInFrame),
        "ugvs": ("/ugvs", fm.SceneUpdate),
        "log": (f"/{vehicle}/log", fm.Log),
        "geometry": ("/geometry", fm.SceneUpdate),
    }
    if kind in proto:
        topic, cls = proto[kind]
        latched = "all" if kind == "geometry" else ""  # the fence and the envelope
        return ChannelSpec(topic, cls.get_schema(), "protobuf", latched)
    topic = {
        "phi": f"/{vehicle}/phi",
        "decision": f"/{vehicle}/decision",
        "event": f"/{vehicle}/safety/event",
        "net_state": f"/{vehicle}/safety/state",
        "clock": "/sim/clock",
    }[kind]
    return ChannelSpec(topic, SCHEMAS[kind], "json", "last" if kind == "net_state" else "")


def json_bytes(record: dict[str, Any]) -> bytes:
    """A record as strict JSON (NaN and ±inf become null: JSON has no NaN).

    A record of plain JSON values with finite numbers (a decision, a clock sample: nearly all)
    is written as it is; `strict_json` (~1 µs a number: a decision holds ~30) only when json
    refuses it (a NaN, a numpy value, a dataclass). Both write the same bytes for any record
    whose dict keys are strings, as JSON's are (every record recorded: parsed from JSON, or
    made here); other keys json would sort and spell its own way (2 before 10, True as
    "true"). tests/record/test_record_messages.py."""
    try:
        return json.dumps(record, sort_keys=True, allow_nan=False).encode()
    except (TypeError, ValueError):
        return json.dumps(strict_json(record), sort_keys=True, allow_nan=False).encode()


# -- geometry helpers ---------------------------------------------------------------------


def _v3(p) -> fm.Vector3:
    return fm.Vector3(x=float(p[0]), y=float(p[1]), z=float(p[2]))


def _p3(p) -> fm.Point3:
    return fm.Point3(x=float(p[0]), y=float(p[1]), z=float(p[2]))


def _quat(q_wxyz) -> fm.Quaternion:
    """(w, x, y, z) as a message; the identity unless it is four finite numbers, not all zero.
    Plain floats: the recorder makes ~5,000 of these a flight (numpy's checks cost 13 µs each)."""
    if isinstance(q_wxyz, np.ndarray) and q_wxyz.shape == (4,):
        q_wxyz = q_wxyz.tolist()
    q = tuple(q_wxyz) if isinstance(q_wxyz, list | tuple) and len(q_wxyz) == 4 else None
    if q is None or not all(type(v) in (float, int) for v in q):  # anything else: as numpy says
        a = np.asarray(q_wxyz, dtype=float)
        q = tuple(a.tolist()) if a.shape == (4,) else (math.nan,) * 4
    w, x, y, z = (float(v) for v in q)
    if not (all(map(math.isfinite, (w, x, y, z))) and w * w + x * x + y * y + z * z > 0):
        w, x, y, z = 1.0, 0.0, 0.0, 0.0
    return fm.Quaternion(w=w, x=x, y=y, z=z)


def _yaw_quat(yaw_rad: float) -> fm.Quaternion:
    """Rotation by yaw about NED's down axis."""
    return _quat([math.cos(yaw_rad / 2), 0.0, 0.0, math.sin(yaw_rad / 2)])


def _pose(pos, q_wxyz=(1.0, 0.0, 0.0, 0.0)) -> fm.Pose:
    return fm.Pose(position=_v3(pos), orientation=_quat(q_wxyz))


def _color(rgba) -> fm.Color:
    return fm.Color(r=rgba[0], g=rgba[1], b=rgba[2], a=rgba[3])


_X = np.array([1.0, 0.0, 0.0])


def _norm(v: np.ndarray) -> float:
    """np.linalg.norm of a float vector, as it computes it (the square root of v.dot(v): BLAS's
    rounding, kept so that the arrows are the same to the bit) without its checks (~2 µs)."""
    return math.sqrt(v.dot(v))


def _arrow_to(origin, vec, rgba, scale_s: float = 1.0) -> fm.ArrowPrimitive | None:
    """An arrow from `origin` along `vec` × scale_s (a velocity shown as where it goes in 1 s)."""
    v = np.asarray(vec, dtype=float) * scale_s
    n = _norm(v)
    if not (math.isfinite(n) and n > 1e-6):
        return None
    # Foxglove arrows point along the pose's +x: rotate +x onto v (half-way quaternion).
    h = _X + v / n
    if _norm(h) < 1e-9:  # pointing backwards: 180° about z
        q = [0.0, 0.0, 0.0, 1.0]
    else:
        hx, hy, hz = (h / _norm(h)).tolist()
        # (x·h, x × h) for x = (1, 0, 0) in plain floats, rounded as np.dot and np.cross round
        # them (x·h is hx exactly; the cross product's products and differences one by one):
        # np.cross costs ~15 µs for three numbers
        q = [hx, 0.0 * hz - 0.0 * hy, 0.0 * hx - 1.0 * hz, 1.0 * hy - 0.0 * hx]
    head = min(0.3 * n, 1.0)
    return fm.ArrowPrimitive(
        pose=_pose(origin, q), shaft_length=n - head, shaft_diameter=0.1,
        head_length=head, head_diameter=0.3, color=_color(rgba),
    )  # fmt: skip


GREY, GREEN, RED, BLUE, ORANGE = (
    (0.6, 0.6, 0.6, 0.8), (0.1, 0.8, 0.2, 1.0), (0.9, 0.1, 0.1, 1.0),
    (0.2, 0.4, 1.0, 1.0), (1.0, 0.6, 0.0, 1.0),
)  # fmt: skip


# -- message builders ---------------------------------------------------------------------


def compressed_image(t: float, jpeg: bytes, vehicle: str) -> fm.CompressedImage:
    return fm.CompressedImage(timestamp=stamp(t), frame_id=f"{vehicle}/camera", data=jpeg,
                              format="jpeg")  # fmt: skip


def pose_in_frame(t: float, pos_ned, quat_wxyz) -> fm.PoseInFrame:
    return fm.PoseInFrame(timestamp=stamp(t), frame_id=NED, pose=_pose(pos_ned, quat_wxyz))


def transforms(t: float, pos_ned, quat_wxyz, vehicle: str) -> fm.FrameTransforms:
    """`world` (north-west-up) → `ned` (180° about north), and `ned` → the vehicle's body."""
    return _transforms(stamp(t), _v3(pos_ned), _quat(quat_wxyz), vehicle)


_ORIGIN = _v3((0, 0, 0))
_WORLD_TO_NED = _quat((0, 1, 0, 0))  # 180° about north


def _transforms(ts: fm.Timestamp, pos: fm.Vector3, q: fm.Quaternion,
                vehicle: str) -> fm.FrameTransforms:  # fmt: skip
    return fm.FrameTransforms(
        transforms=[
            fm.FrameTransform(timestamp=ts, parent_frame_id=WORLD, child_frame_id=NED,
                              translation=_ORIGIN, rotation=_WORLD_TO_NED),
            fm.FrameTransform(timestamp=ts, parent_frame_id=NED, child_frame_id=vehicle,
                              translation=pos, rotation=q),
        ]
    )  # fmt: skip


def pose_and_transforms(t: float, pos_ned, quat_wxyz,
                        vehicle: str) -> tuple[fm.PoseInFrame, fm.FrameTransforms]:  # fmt: skip
    """`pose_in_frame` and `transforms` of one pose, made from one stamp, position and
    quaternion (the vehicle's pose at each camera frame: 1,000 a flight)."""
    ts, pos, q = stamp(t), _v3(pos_ned), _quat(quat_wxyz)
    pose = fm.PoseInFrame(timestamp=ts, frame_id=NED, pose=fm.Pose(position=pos, orientation=q))
    return pose, _transforms(ts, pos, q, vehicle)


def setpoint_scene(t: float, origin_ned, proposed: dict | None, certified: dict | None,
                   vehicle: str) -> fm.SceneUpdate:  # fmt: skip
    """Proposed (grey) and certified (green) velocity arrows from the vehicle, the certified
    position setpoint as a green sphere; one entity, replaced at each decision."""
    arrows, spheres = [], []
    for cmd, rgba in ((proposed, GREY), (certified, GREEN)):
        if cmd and cmd.get("vel_ned") is not None and origin_ned is not None:
            a = _arrow_to(origin_ned, cmd["vel_ned"], rgba)
            if a is not None:
                arrows.append(a)
        if cmd and cmd.get("pos_ned") is not None and np.all(np.isfinite(cmd["pos_ned"])):
            spheres.append(fm.SpherePrimitive(pose=_pose(cmd["pos_ned"]),
                                              size=_v3((0.6, 0.6, 0.6)), color=_color(rgba)))  # fmt: skip
    ent = fm.SceneEntity(timestamp=stamp(t), frame_id=NED, id=f"{vehicle}/setpoint",
                         arrows=arrows, spheres=spheres)  # fmt: skip
    return fm.SceneUpdate(entities=[ent])


_UGV_SIZE = _v3((1.2, 0.8, 0.6))
_UGV_COLOURS = {False: _color(BLUE), True: _color(ORANGE)}  # camouflaged: orange
_IDENTITY = _quat((1.0, 0.0, 0.0, 0.0))


def finite3(p) -> tuple[float, float, float] | None:
    """Three finite floats from a point (a list or tuple of numbers: plain floats; anything
    else as numpy reads it), or None if it is not three finite numbers."""
    if type(p) in (list, tuple) and len(p) == 3 and all(type(v) in (float, int) for v in p):
        n, e, d = float(p[0]), float(p[1]), float(p[2])
    else:
        a = np.asarray(p, dtype=float)
        if a.shape != (3,):
            return None
        n, e, d = a.tolist()
    return (n, e, d) if math.isfinite(n) and math.isfinite(e) and math.isfinite(d) else None


def ugv_entity(ts: fm.Timestamp, u: dict, index: int) -> fm.SceneEntity | None:
    """A UGV state as an entity `ugv<id>` (`ugv<index>` without "id"): a 1.2 × 0.8 × 0.6 m box
    at pos_ned turned by heading_rad, an arrow, its id 1.5 m above (blue, orange while
    camouflaged); None if pos_ned is not three finite numbers. Plain floats and the constant
    parts made once: the recorder draws 3,000 of these a flight (issue 31)."""
    p = finite3(u["pos_ned"])
    if p is None:
        return None
    yaw = float(u.get("heading_rad", 0.0) or 0.0)
    c, s = math.cos(yaw / 2), math.sin(yaw / 2)  # as _yaw_quat: ±inf raises, NaN → identity
    q = fm.Quaternion(w=c, x=0.0, y=0.0, z=s) if math.isfinite(c) else _IDENTITY
    pose = fm.Pose(position=fm.Vector3(x=p[0], y=p[1], z=p[2]), orientation=q)
    label = fm.Pose(position=fm.Vector3(x=p[0], y=p[1], z=p[2] - 1.5), orientation=_IDENTITY)
    colour = _UGV_COLOURS[bool(u.get("camouflaged"))]
    ugv_id = u.get("id", index)
    return fm.SceneEntity(
        timestamp=ts, frame_id=NED, id=f"ugv{ugv_id}",
        cubes=[fm.CubePrimitive(pose=pose, size=_UGV_SIZE, color=colour)],
        arrows=[fm.ArrowPrimitive(pose=pose, shaft_length=1.0, shaft_diameter=0.1,
                                  head_length=0.4, head_diameter=0.3, color=colour)],
        texts=[fm.TextPrimitive(pose=label, billboard=True, font_size=14, scale_invariant=True,
                                color=colour, text=f"ugv {ugv_id}")],
    )  # fmt: skip


def ugv_scene(t: float, ugvs: list[dict]) -> fm.SceneUpdate:
    """One entity per UGV (`ugv_entity`; a state without a finite position is left out)."""
    ts = stamp(t)
    ents: list[fm.SceneEntity] = []
    for u in ugvs:
        e = ugv_entity(ts, u, len(ents))
        if e is not None:
            ents.append(e)
    return fm.SceneUpdate(entities=ents)


def line_scene(t: float, entity: str, polylines: list[np.ndarray], rgba, closed: bool = True,
               thickness_px: float = 2.0) -> fm.SceneUpdate:  # fmt: skip
    """Polylines (each (N, 3) NED [m]) as one entity of LinePrimitives."""
    kind = fm.LinePrimitiveLineType.LineLoop if closed else fm.LinePrimitiveLineType.LineStrip
    lines = [
        fm.LinePrimitive(type=kind, thickness=thickness_px, scale_invariant=True,
                         points=[_p3(p) for p in np.asarray(pl, dtype=float)], color=_color(rgba))
        for pl in polylines
    ]  # fmt: skip
    ent = fm.SceneEntity(timestamp=stamp(t), frame_id=NED, id=entity, lines=lines)
    return fm.SceneUpdate(entities=[ent])


def prism(points_ne: np.ndarray, floor_m: float, ceiling_m: float) -> list[np.ndarray]:
    """A polygon (n, 2) north-east [m] between two altitudes above home, as polylines (NED):
    the floor ring, the ceiling ring and the vertical edges."""
    pts = np.asarray(points_ne, dtype=float).reshape(-1, 2)
    lo = np.column_stack([pts, np.full(len(pts), -floor_m)])
    hi = np.column_stack([pts, np.full(len(pts), -ceiling_m)])
    return [lo, hi] + [np.array([a, b]) for a, b in zip(lo, hi)]


def log_line(t: float, record: dict, vehicle: str) -> fm.Log:
    """A safety event as one Foxglove log line (warning; error for a PID recovery)."""
    what = record.get("event", "event")
    frm, to = record.get("from"), record.get("to")
    text = f"{what} {frm} → {to}: " if frm or to else f"{what}: "
    text += str(record.get("reason", ""))
    level = fm.LogLevel.Error if str(to).lower() == "pid" else fm.LogLevel.Warning
    return fm.Log(timestamp=stamp(t), level=level, message=text, name=f"{vehicle}/safety")
