"""Recording and live view of flights: MCAP files (Foxglove, PlotJuggler) and a Foxglove
WebSocket server, both with Foxglove's well-known schemas, stamped in simulation time.

    from skyherd.record import FlightRecorder, LiveServer, ZenohRecorder
    rec = FlightRecorder(run.file("flight.mcap"))        # in-process calls (record.flightlog)
    rec = ZenohRecorder(session, "uav0", path)          # or: from the Zenoh keys
    live = LiveServer(8765); rec = FlightRecorder(path, also=[live])   # file + live view
    rec = open_recording(run.file("flight.mcap"), foxglove_port=args.foxglove)   # the same

The layer sits just above runio; it imports perception (frame wire format, feature names).
"""

from skyherd.record.flightlog import FlightLog
from skyherd.record.live import LiveServer
from skyherd.record.mcap_file import FlightRecorder
from skyherd.record.read import read_messages
from skyherd.record.zenoh import ZenohRecorder

__all__ = [
    "FlightLog",
    "FlightRecorder",
    "LiveServer",
    "ZenohRecorder",
    "open_recording",
    "read_messages",
]


def open_recording(path, foxglove_port: int | None = None, **mcap_options) -> FlightLog:
    """The one call a command makes: a FlightRecorder at `path` (e.g. run.file("flight.mcap")),
    also feeding a live Foxglove server on 127.0.0.1:`foxglove_port` when one is given
    (`--foxglove PORT`). Closing it closes both."""
    if foxglove_port is None:
        return FlightRecorder(path, **mcap_options)
    live = LiveServer(foxglove_port)
    rec = FlightRecorder(path, also=[live], **mcap_options)
    rec.advertise()  # the live view shows every channel before the first message
    return rec
