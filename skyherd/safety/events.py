"""Where supervisor switch events go: events.jsonl and, live, the Zenoh key
`skyherd/<vehicle>/safety/event` (CONVENTIONS.md), one JSON object per switch.

Any object with `write(record: dict)` is a sink; `Tee` fans one record out to several.
A sink that fails (a closed session, a full disk) is counted and skipped: the other sinks
still get the record, and the safety net never stops because of logging.
"""

from __future__ import annotations

from typing import Any

from skyherd.runio.mac import sign_record
from skyherd.runio.runfolder import to_jsonable


def event_key(vehicle: str) -> str:
    return f"skyherd/{vehicle}/safety/event"


class ZenohEventSink:
    """Publishes each record as JSON (UTF-8) on `skyherd/<vehicle>/safety/event`; with the
    flight's key `mac_key` each carries "mac" (runio.mac)."""

    def __init__(self, session, vehicle: str, mac_key: bytes | None = None):
        self.key = event_key(vehicle)
        self.mac_key = mac_key
        self._pub = session.declare_publisher(self.key)
        self.sent = 0
        self.failed = 0

    def write(self, record: dict[str, Any]) -> None:
        try:
            self._pub.put(sign_record(to_jsonable(record), self.mac_key, sort_keys=True))
            self.sent += 1
        except Exception:  # noqa: BLE001  a dead session must not stop the safety net
            self.failed += 1

    def close(self) -> None:
        try:
            self._pub.undeclare()
        except Exception:  # noqa: BLE001
            pass


class Tee:
    """Writes every record to each sink; a sink that raises is counted and skipped."""

    def __init__(self, *sinks):
        self.sinks = [s for s in sinks if s is not None]
        self.errors = 0

    def write(self, record: dict[str, Any]) -> None:
        for s in self.sinks:
            try:
                s.write(record)
            except Exception:  # noqa: BLE001
                self.errors += 1
