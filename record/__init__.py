"""Recording and live view of flights: MCAP files (Foxglove, PlotJuggler) and a Foxglove
WebSocket server, both with Foxglove's well-known schemas, stamped in simulation time.

    from record import FlightRecorder, LiveServer, ZenohRecorder
    rec = FlightRecorder(run.file("flight.mcap"))        # in-process calls (record.flightlog)
    rec = ZenohRecorder(session, "uav0", path)          # or: from the Zenoh keys
    live = LiveServer(8765); rec = FlightRecorder(path, also=[live])   # file + live view

The layer sits just above runio; it imports perception (frame wire format, feature names).
"""

from record.flightlog import FlightLog
from record.live import LiveServer
from record.mcap_file import FlightRecorder
from record.read import read_messages
from record.zenoh import ZenohRecorder

__all__ = ["FlightLog", "FlightRecorder", "LiveServer", "ZenohRecorder", "read_messages"]
