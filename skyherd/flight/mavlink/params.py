"""Parameter protocol (PARAM_REQUEST_LIST / _READ / PARAM_SET → PARAM_VALUE) and its
per-instance persistence.

Values travel as MAV_PARAM_TYPE_REAL32 (every skyherd parameter is a float), so both PX4-style
(bytewise) and ArduPilot-style (C-cast) clients read them unchanged. The autopilot owns the
values and their limits; this module only moves them and remembers the ones set over MAVLink
in `params.json`, written atomically. A corrupt, oversized, too deeply nested or unreadable
file → a one-line warning, the defaults, and the file moved aside to `params.json.corrupt`.
"""

from __future__ import annotations

import json
import logging
import math
import os
from collections import OrderedDict
from collections.abc import Callable
from pathlib import Path

from pymavlink.dialects.v20 import ardupilotmega as mavlink

from skyherd.flight.autopilot_api import Autopilot

log = logging.getLogger(__name__)
PARAM_ID_LEN = 16
FILE_VERSION = 1
MAX_LIST_REQUESTERS = 16  # list requests served at once; a 17th evicts the oldest
MAX_FILE_BYTES = 1 << 20  # a parameter file larger than this is refused as corrupt


class ParamFile:
    """`{"version": 1, "params": {name: value}}` holding the values set over MAVLink."""

    def __init__(self, path: Path):
        self.path = Path(path)

    def load(self) -> dict[str, float]:
        """Saved values; {} (with a warning) if the file is missing-but-expected, corrupt or odd."""
        if not self.path.exists():
            return {}
        try:
            if self.path.stat().st_size > MAX_FILE_BYTES:
                raise ValueError(f"larger than {MAX_FILE_BYTES} bytes")
            try:
                doc = json.loads(self.path.read_text(encoding="utf-8"))
            except RecursionError:
                raise ValueError("nested too deeply") from None
            if not isinstance(doc, dict) or doc.get("version") != FILE_VERSION:
                raise ValueError("not a skyherd parameter file (version 1)")
            raw = doc.get("params")
            if not isinstance(raw, dict):
                raise ValueError("'params' is not an object")
        except (OSError, UnicodeDecodeError, ValueError) as e:
            reason = " ".join(str(e).split())[:200]  # one line, whatever the file held
            log.warning("parameter file %s unreadable (%s): using defaults%s",
                        self.path, reason, self._set_aside())  # fmt: skip
            return {}
        out: dict[str, float] = {}
        for name, value in raw.items():
            if (
                isinstance(value, int | float)
                and not isinstance(value, bool)
                and math.isfinite(value)
            ):
                out[str(name)] = float(value)
            else:
                log.warning("parameter file %s: ignoring %s=%r", self.path, name, value)
        return out

    def _set_aside(self) -> str:
        """Rename a corrupt file to `<name>.corrupt` (the next save must not destroy it)."""
        aside = self.path.with_name(self.path.name + ".corrupt")
        try:
            os.replace(self.path, aside)
        except OSError:
            return ""
        return f"; the file was moved to {aside}"

    def save(self, values: dict[str, float]) -> None:
        """Write atomically (temp file + fsync + rename): a kill leaves the old or new file."""
        self.path.parent.mkdir(parents=True, exist_ok=True)
        text = json.dumps(
            {"version": FILE_VERSION, "params": dict(sorted(values.items()))}, indent=1
        )
        tmp = self.path.with_name(f".{self.path.name}.tmp{os.getpid()}")
        with open(tmp, "w", encoding="utf-8") as f:
            f.write(text + "\n")
            f.flush()
            os.fsync(f.fileno())
        os.replace(tmp, self.path)


Reply = Callable[[object], None]  # sends one message back to whoever asked


class ParamService:
    """Serves the autopilot's parameters; list requests are paced out over several updates."""

    def __init__(
        self,
        ap: Autopilot,
        mav: mavlink.MAVLink,
        store: ParamFile | None,
        broadcast: Callable[[object], None],
        statustext: Callable[[int, str], None],
        per_update: int = 40,
    ):
        self.ap = ap
        self.mav = mav
        self.store = store
        self.broadcast = broadcast
        self.statustext = statustext
        self.per_update = per_update
        self.names = [n for n in ap.param_names() if 0 < len(n) <= PARAM_ID_LEN]
        skipped = [n for n in ap.param_names() if not 0 < len(n) <= PARAM_ID_LEN]
        if skipped:
            log.warning(
                "parameters with names longer than 16 characters are not served: %s", skipped
            )
        self.index = {n: i for i, n in enumerate(self.names)}
        self.saved: dict[str, float] = {}
        # Pending list requests: requester key → [next index, reply], oldest first. Bounded
        # (MAX_LIST_REQUESTERS, the oldest evicted) and served round-robin: O(1) per packet.
        self._lists: OrderedDict[object, list] = OrderedDict()
        self.evicted_lists = 0
        if store is not None:
            self._restore(store.load())

    def _restore(self, values: dict[str, float]) -> None:
        for name, value in values.items():
            if name not in self.index:
                log.warning("saved parameter %s is unknown to this airframe: ignored", name)
                continue
            res = self.ap.set_param(name, value)
            if res.ok:
                self.saved[name] = value
            else:
                log.warning(
                    "saved parameter %s=%g refused (%s): default kept", name, value, res.reason
                )

    def value_msg(self, name: str):
        """PARAM_VALUE for one parameter."""
        v = self.ap.get_param(name)
        v = float("nan") if v is None else float(v)
        return self.mav.param_value_encode(
            name.encode("ascii"),
            v,
            mavlink.MAV_PARAM_TYPE_REAL32,
            len(self.names),
            self.index[name],
        )

    # --- handlers --------------------------------------------------------------------------
    def request_list(self, reply: Reply, key: object) -> None:
        """Queue the whole list for one requester (`key` identifies it: a repeat restarts).

        At most MAX_LIST_REQUESTERS lists are in flight; a new requester beyond that evicts
        the one waiting longest (it can ask again or read the missing ones by index)."""
        if key in self._lists:
            self._lists[key] = [0, reply]
            return
        if len(self._lists) >= MAX_LIST_REQUESTERS:
            self._lists.popitem(last=False)
            self.evicted_lists += 1
        self._lists[key] = [0, reply]

    def queued(self) -> int:
        """PARAM_VALUEs still to send for pending list requests."""
        return sum(len(self.names) - i for i, _ in self._lists.values())

    def request_read(self, msg, reply: Reply) -> None:
        idx = msg.param_index
        if idx >= 0:
            if idx < len(self.names):
                reply(self.value_msg(self.names[idx]))
            return
        name = _param_id(msg.param_id)
        if name in self.index:
            reply(self.value_msg(name))

    def set(self, msg, reply: Reply) -> None:
        name = _param_id(msg.param_id)
        if name not in self.index:
            self.statustext(mavlink.MAV_SEVERITY_WARNING, f"param {name!r} unknown")
            return
        value = float(msg.param_value)
        if not math.isfinite(value):
            self.statustext(mavlink.MAV_SEVERITY_WARNING, f"param {name}: value not a number")
            reply(self.value_msg(name))  # the current value: the set failed
            return
        res = self.ap.set_param(name, value)
        if not res.ok:
            self.statustext(mavlink.MAV_SEVERITY_WARNING, f"param {name}: {res.reason}")
            reply(self.value_msg(name))
            return
        self.saved[name] = float(self.ap.get_param(name))
        if self.store is not None:
            try:
                self.store.save(self.saved)
            except OSError as e:
                log.warning("cannot save parameters to %s: %s", self.store.path, e)
        self.broadcast(self.value_msg(name))

    @property
    def busy(self) -> bool:
        """A list request is being answered (`pump` has values to send)."""
        return bool(self._lists)

    def pump(self) -> None:
        """Send up to `per_update` PARAM_VALUEs of pending list requests, one per requester
        in turn (round-robin)."""
        lists, n = self._lists, len(self.names)
        for _ in range(self.per_update):
            if not lists:
                return
            key, entry = next(iter(lists.items()))
            i, reply = entry
            if i >= n:
                del lists[key]
                continue
            reply(self.value_msg(self.names[i]))
            entry[0] = i + 1
            if i + 1 >= n:
                del lists[key]
            else:
                lists.move_to_end(key)


def _param_id(raw) -> str:
    """param_id as text: pymavlink gives str (NUL-stripped) or bytes; junk bytes are dropped."""
    if isinstance(raw, bytes):
        raw = raw.split(b"\0", 1)[0].decode("ascii", errors="ignore")
    return str(raw).split("\0", 1)[0][:PARAM_ID_LEN]
