"""`skyherd fly`'s own recording: flight.mcap (and the live Foxglove view) from the flight's Zenoh
keys, in fly's process beside its children. The flight never depends on it: a recording that
cannot start is said on stderr, and the flight flies without one."""

from __future__ import annotations

import dataclasses
import sys
import time
from collections.abc import Callable
from pathlib import Path

START_PATIENCE_S = 120.0  # wall time the recording waits for the simulator to listen [s]
START_POLL_S = 0.02  # ... looking this often [wall s]


class FlightRecording:
    """A ZenohRecorder and the Zenoh client session it records from; `close()` ends both."""

    def __init__(self, session, recorder):
        self.session, self.recorder = session, recorder

    def close(self) -> None:
        self.recorder.close()
        self.session.close()


def record_flight(zenoh_port: int, path: Path | None, foxglove: int | None, *,
                  key_file: str | None = None, envelope=None,
                  connect: Callable[[object], object | None],
                  ready: Callable[[], bool] | None = None,
                  give_up: Callable[[], bool] | None = None) -> FlightRecording | None:  # fmt: skip
    """The recording of the flight whose simulator listens on 127.0.0.1:`zenoh_port`: into
    `path` (None: none) and live to Foxglove on `foxglove` (None: none); with the flight's
    `key_file` only authentic frames, UGV states and clock; the fence and rows of `envelope`
    (a safety EnvelopeSpec) first. `connect(params)` opens the client session (None: it gave
    up). It connects once `ready()` is True (the simulator's session listens; never a stranger
    on its port) and returns None when `give_up()` becomes True first (a signal came, or a
    child ended: the caller says which), or when it cannot start (said on stderr)."""
    try:
        from skyherd.flight.mavlink.keys import load_key

        key = load_key(Path(key_file)) if key_file else None
        from skyherd.perception.transport import subscriber_params
        from skyherd.record.zenoh import ZenohRecorder

        deadline = time.monotonic() + START_PATIENCE_S
        while ready is not None and not ready() and time.monotonic() < deadline:
            if give_up is not None and give_up():
                return None
            time.sleep(START_POLL_S)
        params = subscriber_params(f"tcp/127.0.0.1:{zenoh_port}")
        session = connect(dataclasses.replace(params, mode="client"))
        if session is None:  # it gave up
            return None
        also = []
        if foxglove is not None:  # the live view's module only then (foxglove's server)
            from skyherd.record.live import LiveServer

            also = [LiveServer(foxglove)]
        if also:
            print(
                f"skyherd fly: live view on {also[0].url} (Foxglove: open connection)", flush=True
            )
        rec = ZenohRecorder(session, "uav0", path, also=also, key=key)
        if envelope is not None:  # the fence and the envelope's rows
            rec.log.geometry(0.0, envelope)
        return FlightRecording(session, rec)
    except Exception as e:  # noqa: BLE001 - say so and fly without a recording
        print(f"skyherd fly: no flight.mcap ({type(e).__name__}: {e})", file=sys.stderr)
        return None
