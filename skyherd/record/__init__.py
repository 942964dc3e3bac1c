"""Recording and live view of flights: MCAP files (Foxglove, PlotJuggler) and a Foxglove
WebSocket server, both with Foxglove's well-known schemas, stamped in simulation time.

    from skyherd.record import FlightRecorder, LiveServer, ZenohRecorder
    rec = FlightRecorder(run.file("flight.mcap"))        # in-process calls (record.flightlog)
    rec = ZenohRecorder(session, "uav0", path)          # or: from the Zenoh keys
    live = LiveServer(8765); rec = FlightRecorder(path, also=[live])   # file + live view
    rec = open_recording(run.file("flight.mcap"), foxglove_port=args.foxglove)   # the same

The layer sits just above runio; it imports perception (frame wire format, feature names).
"""

from __future__ import annotations

import importlib
from typing import TYPE_CHECKING

if TYPE_CHECKING:
    from skyherd.record.flightlog import FlightLog

_WHERE = {  # each name's module, imported when the name is first asked for (PEP 562): a
    # process imports only what it uses (`skyherd fly` records, it never reads a file back)
    "FlightLog": "flightlog",
    "FlightRecorder": "mcap_file",
    "LiveServer": "live",
    "ZenohRecorder": "zenoh",
    "read_messages": "read",
}

__all__ = [
    "FlightLog",
    "FlightRecorder",
    "LiveServer",
    "ZenohRecorder",
    "open_recording",
    "read_messages",
]


def __getattr__(name: str):
    if name not in _WHERE:
        raise AttributeError(f"module 'skyherd.record' has no attribute {name!r}")
    return getattr(importlib.import_module(f"skyherd.record.{_WHERE[name]}"), name)


def open_recording(path, foxglove_port: int | None = None, **mcap_options) -> FlightLog:
    """The one call a command makes: a FlightRecorder at `path` (e.g. run.file("flight.mcap")),
    also feeding a live Foxglove server on 127.0.0.1:`foxglove_port` when one is given
    (`--foxglove PORT`). Closing it closes both."""
    from skyherd.record.mcap_file import FlightRecorder

    if foxglove_port is None:
        return FlightRecorder(path, **mcap_options)
    from skyherd.record.live import LiveServer

    live = LiveServer(foxglove_port)
    rec = FlightRecorder(path, also=[live], **mcap_options)
    rec.advertise()  # the live view shows every channel before the first message
    return rec
