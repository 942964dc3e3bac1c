"""Mission protocol for missions (type 0), geofences (type 1) and rally points (type 2).

Upload: MISSION_COUNT → MISSION_REQUEST_INT(seq)… ← MISSION_ITEM_INT → MISSION_ACK.
Download: MISSION_REQUEST_LIST → MISSION_COUNT, MISSION_REQUEST_INT(seq) → MISSION_ITEM_INT,
ending with the client's MISSION_ACK. MISSION_CLEAR_ALL clears one type (or all).

Missions are converted to `MissionItem`s and handed to the autopilot; a mission it refuses
leaves the old one in place. Fences are validated and kept here (as uploaded, and as NED
shapes) for the safety net. Rally points: this vehicle has none; downloads answer an empty
list and uploads of points are refused (MAV_MISSION_UNSUPPORTED).
Upload timeouts run on the simulation clock. One upload runs at a time: a MISSION_COUNT from
another client while one is in progress is answered MISSION_ACK DENIED (the same client may
restart its own); a stalled upload is cancelled after RETRY_S x MAX_RETRIES without items.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, fields

import numpy as np
from pymavlink.dialects.v20 import ardupilotmega as mavlink

from skyherd.flight.autopilot_api import Autopilot, MissionCommand, MissionItem
from skyherd.flight.geo import geodetic_to_ned

M = mavlink
MISSION, FENCE, RALLY, ALL = 0, 1, 2, 255
MAX_ITEMS = {MISSION: 500, FENCE: 100, RALLY: 0}
RETRY_S = 1.0  # [s sim] re-request a missing item after this long
MAX_RETRIES = 5
MAX_RANGE_M = 100_000.0  # items farther than this from home are refused

_GLOBAL_FRAMES_AMSL = {M.MAV_FRAME_GLOBAL, M.MAV_FRAME_GLOBAL_INT}
_GLOBAL_FRAMES_REL = {M.MAV_FRAME_GLOBAL_RELATIVE_ALT, M.MAV_FRAME_GLOBAL_RELATIVE_ALT_INT}
FENCE_RETURN_POINT = 5000
FENCE_POLY_INCL, FENCE_POLY_EXCL = 5001, 5002
FENCE_CIRCLE_INCL, FENCE_CIRCLE_EXCL = 5003, 5004


@dataclass(frozen=True)
class RawItem:
    """A mission item exactly as MISSION_ITEM_INT carries it (x, y: degrees·1e7)."""

    seq: int
    frame: int
    command: int
    current: int
    autocontinue: int
    param1: float
    param2: float
    param3: float
    param4: float
    x: int
    y: int
    z: float
    mission_type: int

    @staticmethod
    def from_msg(msg) -> RawItem:
        """From MISSION_ITEM_INT, or legacy MISSION_ITEM (x, y in degrees as floats)."""
        x, y = msg.x, msg.y
        if msg.get_type() == "MISSION_ITEM":
            if not (math.isfinite(x) and math.isfinite(y)):
                raise ValueError("latitude/longitude not a number")
            x, y = int(round(x * 1e7)), int(round(y * 1e7))
        return RawItem(
            msg.seq, msg.frame, msg.command, msg.current, msg.autocontinue,
            float(msg.param1), float(msg.param2), float(msg.param3), float(msg.param4),
            int(x), int(y), float(msg.z), getattr(msg, "mission_type", 0),
        )  # fmt: skip

    def same_as(self, other: RawItem) -> bool:
        """Field-by-field equality where NaN equals NaN."""
        for f in fields(self):
            a, b = getattr(self, f.name), getattr(other, f.name)
            if a != b and not (isinstance(a, float) and math.isnan(a) and math.isnan(b)):
                return False
        return True


@dataclass(frozen=True)
class FenceShape:
    """A geofence shape about home, NED [m].

    kind "polygon": vertices_ne (k, 2); kind "circle": center_ne (2,) and radius [m];
    kind "return": center_ne (2,) is the fence return point. inclusion: inside is allowed.
    """

    kind: str
    inclusion: bool
    vertices_ne: np.ndarray | None = None
    center_ne: np.ndarray | None = None
    radius: float = 0.0


class ItemError(ValueError):
    """An item that cannot be accepted, with the MAV_MISSION_RESULT to answer."""

    def __init__(self, result: int, reason: str):
        super().__init__(reason)
        self.result = result


@dataclass
class _Upload:
    mission_type: int
    count: int
    reply: Callable
    key: object
    sender: tuple[int, int]  # (system, component) of the client uploading
    items: list
    last_request_t: float
    retries: int = 0


class MissionService:
    """Holds the uploaded lists and runs the upload state machine."""

    def __init__(
        self,
        ap: Autopilot,
        mav: mavlink.MAVLink,
        statustext: Callable[[int, str], None],
        on_fence: Callable[[list[FenceShape]], None] | None = None,
    ):
        self.ap = ap
        self.mav = mav
        self.statustext = statustext
        self.on_fence = on_fence
        self.lists: dict[int, list[RawItem]] = {MISSION: [], FENCE: [], RALLY: []}
        self.fence_shapes: list[FenceShape] = []
        self._upload: _Upload | None = None

    # --- upload ----------------------------------------------------------------------------
    def on_count(self, msg, reply, key, sender: tuple[int, int]) -> None:
        mtype = getattr(msg, "mission_type", 0)
        if mtype not in MAX_ITEMS:
            reply(self._ack(sender, M.MAV_MISSION_UNSUPPORTED, mtype))
            return
        if msg.count > MAX_ITEMS[mtype]:
            result = M.MAV_MISSION_UNSUPPORTED if mtype == RALLY else M.MAV_MISSION_NO_SPACE
            reply(self._ack(sender, result, mtype))
            return
        up = self._upload
        if up is not None and up.key != key:
            # One upload at a time: another client's transfer is not replaced. It finishes,
            # or times out after RETRY_S x MAX_RETRIES of simulation time without an item.
            self.statustext(M.MAV_SEVERITY_WARNING,
                            f"mission upload from {up.sender[0]}/{up.sender[1]} in progress: try later")  # fmt: skip
            reply(self._ack(sender, M.MAV_MISSION_DENIED, mtype))
            return
        if msg.count == 0:
            self._apply(mtype, [], reply, sender)
            return
        self._upload = _Upload(mtype, msg.count, reply, key, sender, [], self.ap.clock.t)
        reply(self._request(sender, 0, mtype))

    def on_item(self, msg, reply, key, sender) -> None:
        up = self._upload
        if up is None or key != up.key or getattr(msg, "mission_type", 0) != up.mission_type:
            return  # not part of an upload we are running: ignore
        if msg.seq != len(up.items):
            return  # out of order or duplicate: the retry timer re-requests the right one
        try:
            item = RawItem.from_msg(msg)
            self._check_raw(item)
        except ItemError as e:
            self._upload = None
            self.statustext(M.MAV_SEVERITY_WARNING, f"mission item {msg.seq}: {e}")
            reply(self._ack(sender, e.result, up.mission_type))
            return
        except (ValueError, OverflowError) as e:
            self._upload = None
            self.statustext(M.MAV_SEVERITY_WARNING, f"mission item {msg.seq}: {e}")
            reply(self._ack(sender, M.MAV_MISSION_ERROR, up.mission_type))
            return
        up.items.append(item)
        up.retries = 0
        up.last_request_t = self.ap.clock.t
        if len(up.items) < up.count:
            reply(self._request(sender, len(up.items), up.mission_type))
            return
        self._upload = None
        self._apply(up.mission_type, up.items, reply, sender)

    @property
    def busy(self) -> bool:
        """An upload is running (`service` has work to time)."""
        return self._upload is not None

    def service(self) -> None:
        """Re-request a missing item after RETRY_S of simulation time; give up after retries."""
        up = self._upload
        if up is None or self.ap.clock.t - up.last_request_t < RETRY_S:
            return  # nothing running, or not yet time to re-request
        up.retries += 1
        up.last_request_t = self.ap.clock.t
        if up.retries > MAX_RETRIES:
            self._upload = None
            self.statustext(M.MAV_SEVERITY_WARNING, "mission upload timed out")
            up.reply(self._ack(up.sender, M.MAV_MISSION_OPERATION_CANCELLED, up.mission_type))
            return
        up.reply(self._request(up.sender, len(up.items), up.mission_type))

    def _apply(self, mtype: int, items: list[RawItem], reply, sender) -> None:
        try:
            if mtype == MISSION:
                converted = self.to_mission_items(items)
                res = self.ap.set_mission(converted)
                if not res.ok:
                    raise ItemError(M.MAV_MISSION_DENIED, res.reason or "mission refused")
            elif mtype == FENCE:
                shapes = self.to_fence_shapes(items)
                self.fence_shapes = shapes
                if self.on_fence is not None:
                    self.on_fence(shapes)
        except ItemError as e:
            self.statustext(M.MAV_SEVERITY_WARNING, str(e))
            reply(self._ack(sender, e.result, mtype))
            return
        self.lists[mtype] = list(items)
        reply(self._ack(sender, M.MAV_MISSION_ACCEPTED, mtype))

    # --- download, clear, set current --------------------------------------------------------
    def on_request_list(self, msg, reply, sender) -> None:
        mtype = getattr(msg, "mission_type", 0)
        if mtype not in self.lists:
            reply(self._ack(sender, M.MAV_MISSION_UNSUPPORTED, mtype))
            return
        reply(self.mav.mission_count_encode(sender[0], sender[1], len(self.lists[mtype]), mtype))

    def on_request(self, msg, reply, sender) -> None:
        """MISSION_REQUEST_INT → MISSION_ITEM_INT; legacy MISSION_REQUEST → MISSION_ITEM."""
        mtype = getattr(msg, "mission_type", 0)
        items = self.lists.get(mtype)
        if items is None or not 0 <= msg.seq < len(items):
            reply(self._ack(sender, M.MAV_MISSION_INVALID_SEQUENCE, mtype))
            return
        it = items[msg.seq]
        if msg.get_type() == "MISSION_REQUEST":
            reply(
                self.mav.mission_item_encode(
                    sender[0],
                    sender[1],
                    it.seq,
                    it.frame,
                    it.command,
                    it.current,
                    it.autocontinue,
                    it.param1,
                    it.param2,
                    it.param3,
                    it.param4,
                    it.x / 1e7,
                    it.y / 1e7,
                    it.z,
                    mtype,
                )  # fmt: skip
            )
            return
        reply(
            self.mav.mission_item_int_encode(
                sender[0],
                sender[1],
                it.seq,
                it.frame,
                it.command,
                it.current,
                it.autocontinue,
                it.param1,
                it.param2,
                it.param3,
                it.param4,
                it.x,
                it.y,
                it.z,
                mtype,
            )  # fmt: skip
        )

    def on_clear_all(self, msg, reply, sender) -> None:
        mtype = getattr(msg, "mission_type", 0)
        types = list(self.lists) if mtype == ALL else [mtype]
        if any(t not in self.lists for t in types):
            reply(self._ack(sender, M.MAV_MISSION_UNSUPPORTED, mtype))
            return
        if MISSION in types:
            res = self.ap.set_mission([])
            if not res.ok:
                self.statustext(M.MAV_SEVERITY_WARNING, f"clear refused: {res.reason}")
                reply(self._ack(sender, M.MAV_MISSION_DENIED, mtype))
                return
        for t in types:
            self.lists[t] = []
        if FENCE in types:
            self.fence_shapes = []
            if self.on_fence is not None:
                self.on_fence([])
        reply(self._ack(sender, M.MAV_MISSION_ACCEPTED, mtype))

    # --- conversions -------------------------------------------------------------------------
    def _check_raw(self, it: RawItem) -> None:
        for name in ("param1", "param2", "param3", "z"):
            v = getattr(it, name)
            if math.isinf(v):
                raise ItemError(M.MAV_MISSION_ERROR, f"{name} infinite")
        if it.mission_type == MISSION and it.command not in MissionCommand._value2member_map_:
            raise ItemError(M.MAV_MISSION_UNSUPPORTED, f"command {it.command} unsupported")
        if it.mission_type == FENCE and it.command not in (
            FENCE_RETURN_POINT, FENCE_POLY_INCL, FENCE_POLY_EXCL, FENCE_CIRCLE_INCL, FENCE_CIRCLE_EXCL,
        ):  # fmt: skip
            raise ItemError(M.MAV_MISSION_UNSUPPORTED, f"fence command {it.command} unsupported")
        if it.mission_type == RALLY:
            raise ItemError(M.MAV_MISSION_UNSUPPORTED, "rally points unsupported")
        if it.frame not in _GLOBAL_FRAMES_AMSL | _GLOBAL_FRAMES_REL | {M.MAV_FRAME_MISSION}:
            raise ItemError(M.MAV_MISSION_UNSUPPORTED_FRAME, f"frame {it.frame} unsupported")
        if not (-90e7 <= it.x <= 90e7):
            raise ItemError(M.MAV_MISSION_INVALID_PARAM5_X, "latitude out of range")
        if not (-180e7 <= it.y <= 180e7):
            raise ItemError(M.MAV_MISSION_INVALID_PARAM6_Y, "longitude out of range")
        if math.isnan(it.z) and it.frame != M.MAV_FRAME_MISSION:
            raise ItemError(M.MAV_MISSION_INVALID_PARAM7, "altitude not a number")

    def _ned(self, it: RawItem, prev_ne: np.ndarray) -> np.ndarray:
        """NED position of a positional item; x = y = 0 means "here" (the previous item)."""
        home = self.ap.home
        if it.frame == M.MAV_FRAME_MISSION or (it.x == 0 and it.y == 0):
            ne = prev_ne
        else:
            ned = geodetic_to_ned(home, it.x / 1e7, it.y / 1e7, home.alt_m)
            ne = ned[:2]
        if it.frame in _GLOBAL_FRAMES_REL or it.frame == M.MAV_FRAME_MISSION:
            down = -it.z if math.isfinite(it.z) else 0.0
        else:
            down = home.alt_m - it.z
        pos = np.array([ne[0], ne[1], down], dtype=float)
        if not np.all(np.isfinite(pos)) or np.linalg.norm(pos) > MAX_RANGE_M:
            raise ItemError(M.MAV_MISSION_INVALID_PARAM5_X, f"item {it.seq} too far from home")
        return pos

    def to_mission_items(self, items: list[RawItem]) -> list[MissionItem]:
        out = []
        prev_ne = np.zeros(2)
        for it in items:
            cmd = MissionCommand(it.command)
            yaw = math.radians(it.param4) if math.isfinite(it.param4) else None
            p1 = it.param1 if math.isfinite(it.param1) else 0.0
            if cmd is MissionCommand.RETURN_TO_LAUNCH:
                out.append(MissionItem(cmd, np.zeros(3)))
                continue
            pos = self._ned(it, prev_ne)
            if cmd is MissionCommand.LAND:
                pos[2] = 0.0
            kw: dict = {"yaw": yaw}
            if cmd is MissionCommand.WAYPOINT:
                kw["hold_s"] = max(p1, 0.0)
                kw["accept_radius"] = max(it.param2, 0.0) if math.isfinite(it.param2) else 0.0
            elif cmd is MissionCommand.LOITER_TIME:
                kw["hold_s"] = max(p1, 0.0)
            if cmd in (MissionCommand.LOITER_TIME, MissionCommand.LOITER_UNLIM):
                kw["loiter_radius"] = abs(it.param3) if math.isfinite(it.param3) else 0.0
            out.append(MissionItem(cmd, pos, **kw))
            prev_ne = pos[:2]
        return out

    def to_fence_shapes(self, items: list[RawItem]) -> list[FenceShape]:
        home = self.ap.home
        shapes: list[FenceShape] = []
        i = 0
        while i < len(items):
            it = items[i]
            ne = geodetic_to_ned(home, it.x / 1e7, it.y / 1e7, home.alt_m)[:2]
            if it.command in (FENCE_CIRCLE_INCL, FENCE_CIRCLE_EXCL):
                if not (math.isfinite(it.param1) and it.param1 > 0):
                    raise ItemError(M.MAV_MISSION_INVALID_PARAM1, f"fence item {i}: radius <= 0")
                shapes.append(
                    FenceShape(
                        "circle", it.command == FENCE_CIRCLE_INCL, center_ne=ne, radius=it.param1
                    )
                )
                i += 1
            elif it.command == FENCE_RETURN_POINT:
                shapes.append(FenceShape("return", True, center_ne=ne))
                i += 1
            else:
                n = it.param1
                if not (math.isfinite(n) and float(n).is_integer() and n >= 3):
                    raise ItemError(
                        M.MAV_MISSION_INVALID_PARAM1, f"fence item {i}: vertex count < 3"
                    )
                n = int(n)
                group = items[i : i + n]
                if len(group) < n or any(
                    g.command != it.command or g.param1 != it.param1 for g in group
                ):
                    raise ItemError(
                        M.MAV_MISSION_INVALID_PARAM1, f"fence item {i}: polygon incomplete"
                    )
                verts = np.array(
                    [geodetic_to_ned(home, g.x / 1e7, g.y / 1e7, home.alt_m)[:2] for g in group]
                )
                shapes.append(
                    FenceShape("polygon", it.command == FENCE_POLY_INCL, vertices_ne=verts)
                )
                i += n
        return shapes

    # --- messages ----------------------------------------------------------------------------
    def _ack(self, sender, result: int, mtype: int):
        return self.mav.mission_ack_encode(sender[0], sender[1], result, mtype)

    def _request(self, sender, seq: int, mtype: int):
        return self.mav.mission_request_int_encode(sender[0], sender[1], seq, mtype)
