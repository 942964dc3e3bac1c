"""`LiveServer(port)`: the flight live in Foxglove (`--foxglove`), over the Foxglove WebSocket
protocol from the `foxglove-sdk` package, on 127.0.0.1 only.

It carries the channels of `record.messages`, the same as the MCAP file: open Foxglove, "Open
connection", `ws://127.0.0.1:PORT`. Each server has its own foxglove Context (no global
state), so several can run in one process. Messages are stamped in simulation time.
"""

from __future__ import annotations

from typing import Any

import foxglove

from record import messages as m
from record.flightlog import FlightLog

DEFAULT_PORT = 8765


class FoxgloveSink:
    """A Sink publishing to a Foxglove WebSocket server (foxglove-sdk)."""

    def __init__(self, port: int = DEFAULT_PORT, host: str = "127.0.0.1", name: str = "skyherd"):
        self.context = foxglove.Context()
        try:
            self.server = foxglove.start_server(name=name, host=host, port=port,
                                                context=self.context)  # fmt: skip
        except Exception as e:  # noqa: BLE001 - the SDK raises its own error types
            raise OSError(f"cannot start the Foxglove server on {host}:{port}: {e}") from e
        self.host, self.port = host, self.server.port

    def channel(self, spec: m.ChannelSpec) -> Any:
        return foxglove.Channel(spec.topic, schema=spec.schema,
                                message_encoding=spec.message_encoding, context=self.context)  # fmt: skip

    def write(self, handle: Any, t_ns: int, data: bytes) -> None:
        handle.log(data, log_time=t_ns)

    def close(self) -> None:
        if self.server is not None:
            self.server.stop()
            self.server = None


class LiveServer(FlightLog):
    """A FlightLog whose sink is a Foxglove WebSocket server at ws://127.0.0.1:`port`
    (port 0: any free port; `.port` says which). Pass it to `FlightRecorder(..., also=[live])`
    to feed the file and the live view with one set of calls."""

    def __init__(self, port: int = DEFAULT_PORT, host: str = "127.0.0.1"):
        self.server_sink = FoxgloveSink(port, host)
        super().__init__(self.server_sink)
        self.port = self.server_sink.port

    @property
    def url(self) -> str:
        return f"ws://{self.server_sink.host}:{self.port}"
