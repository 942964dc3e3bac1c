"""`LiveServer(port)`: the flight live in Foxglove (`--foxglove`), over the Foxglove WebSocket
protocol from the `foxglove-sdk` package, on 127.0.0.1 only.

It carries the channels of `record.messages`, the same as the MCAP file: open Foxglove, "Open
connection", `ws://127.0.0.1:PORT`. Each server has its own foxglove Context (no global
state), so several can run in one process. Messages are stamped in simulation time.

A client that joins late misses nothing it needs to understand the flight:
- every channel is advertised before the flight's first message (`FlightLog.advertise`, called
  by the recorders), so a client that connects during the take-off gets every decision;
- latched channels (`ChannelSpec.latched`: the fence and envelope geometry, the safety net's
  newest event on `/<vehicle>/safety/state`) are re-sent when a client subscribes to them. The
  SDK logs to every subscriber of a channel, so an earlier subscriber gets them again too: the
  geometry replaces its entities by id and the state is a state, so a repeat changes nothing;
- at the end the server closes each connection with a WebSocket close frame (the SDK's carries
  no status code: clients read 1005), after a status message that says the flight ended (best
  effort: the SDK's stop may drop it when it is still queued, `END_GRACE_S`).
"""

from __future__ import annotations

import threading
import time
from typing import Any

import foxglove
from foxglove.websocket import ServerListener, StatusLevel

from skyherd.record import messages as m
from skyherd.record.flightlog import FlightLog

DEFAULT_PORT = 8765


class FoxgloveSink:
    """A Sink publishing to a Foxglove WebSocket server (foxglove-sdk), re-sending its latched
    channels to each new subscriber."""

    END_GRACE_S = 0.2  # [s wall] between the "flight ended" status and the stop
    LATCH_ALL_MAX = 256  # messages kept per "all"-latched channel (the fence: a few)
    advertise_all = True  # FlightLog.advertise opens every channel here before the first message

    def __init__(self, port: int = DEFAULT_PORT, host: str = "127.0.0.1", name: str = "skyherd"):
        self.context = foxglove.Context()
        self._lock = threading.Lock()
        self._by_topic: dict[str, Any] = {}  # topic → channel
        self._latched: dict[str, tuple[str, list[tuple[int, bytes]]]] = {}  # topic → (how, msgs)
        self.resent = 0  # latched messages re-sent to new subscribers
        try:
            self.server = foxglove.start_server(name=name, host=host, port=port,
                                                context=self.context,
                                                server_listener=_Resend(self))  # fmt: skip
        except Exception as e:  # noqa: BLE001 - the SDK raises its own error types
            raise OSError(f"cannot start the Foxglove server on {host}:{port}: {e}") from e
        self.host, self.port = host, self.server.port

    def channel(self, spec: m.ChannelSpec) -> Any:
        ch = foxglove.Channel(spec.topic, schema=spec.schema,
                              message_encoding=spec.message_encoding, context=self.context)  # fmt: skip
        with self._lock:
            self._by_topic[spec.topic] = ch
            if spec.latched:
                self._latched[spec.topic] = (spec.latched, [])
        return ch

    def write(self, handle: Any, t_ns: int, data: bytes) -> None:
        handle.log(data, log_time=t_ns)
        with self._lock:
            latched = self._latched.get(handle.topic())
            if latched is not None:
                how, msgs = latched
                if how == "last":
                    msgs.clear()
                if len(msgs) < self.LATCH_ALL_MAX:
                    msgs.append((t_ns, data))

    def subscribed(self, topic: str) -> None:
        """A client subscribed to `topic`: re-send what the channel latched."""
        with self._lock:
            ch = self._by_topic.get(topic)
            msgs = list(self._latched.get(topic, ("", []))[1])
        for t_ns, data in msgs:
            ch.log(data, log_time=t_ns)
            self.resent += 1

    def close(self) -> None:
        if self.server is not None:
            try:
                self.server.publish_status("the flight ended: this live view closes",
                                           StatusLevel.Info, "skyherd-end")  # fmt: skip
                time.sleep(self.END_GRACE_S)
            except Exception:  # noqa: BLE001 - closing anyway
                pass
            self.server.stop()
            self.server = None


class _Resend(ServerListener):
    """The server's callbacks: a subscription gets the channel's latched messages."""

    def __init__(self, sink: FoxgloveSink):
        self.sink = sink

    def on_subscribe(self, client, channel) -> None:
        try:
            self.sink.subscribed(channel.topic)
        except Exception:  # noqa: BLE001 - a live view never stops a flight
            pass


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
