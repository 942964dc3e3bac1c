"""`skyherd watch` in a run folder: a vehicle's camera frames detected as they arrive
(perception.watch) and the flight seen on Zenoh recorded beside them (ZenohRecorder: flight.mcap
and/or a live Foxglove view). With the flight key, only authentic frames and records count."""

from __future__ import annotations

from collections.abc import Callable

from skyherd.perception.transport import FrameSubscriber
from skyherd.perception.watch import Watched, WatchParams, watch_folder, watch_frames
from skyherd.record.zenoh import ZenohRecorder


class FlightWatch:
    """One vehicle's frames (`sub`, `seen`) and, after `record`, its recording (`recorder`)."""

    def __init__(self, session, vehicle: str, key: bytes | None) -> None:
        self.session, self.vehicle, self.key = session, vehicle, key
        self.sub = FrameSubscriber(session, vehicle, key=key)
        self.seen = Watched()
        self.recorder: ZenohRecorder | None = None
        self.mcap = False

    def record(self, run, mcap: bool, live=None) -> None:
        """flight.mcap in the run folder `run` (runio.Run) with `mcap`, and/or the live view
        `live` (record.LiveServer); the recorder closes with the run."""
        self.mcap = mcap
        if mcap or live is not None:
            path = run.file("flight.mcap") if mcap else None
            also = [live] if live is not None else []
            rec = ZenohRecorder(self.session, self.vehicle, path, also=also, key=self.key)
            self.recorder = run.closing(rec)

    def recorded(self) -> dict[str, int] | None:
        """flight.mcap's messages per channel (None: no flight.mcap)."""
        return self.recorder.log.counts if self.recorder is not None and self.mcap else None

    def watch(
        self,
        run,
        p: WatchParams,
        stop: Callable[[], bool],
        on_frame: Callable[[], None] | None = None,
    ) -> Watched:
        """frames/ and metrics.csv in `run`, then the frame loop (perception.watch)."""
        metrics = watch_folder(run, p.save_every)
        watch_frames(self.sub, p, metrics, run.path / "frames", stop, self.seen, on_frame)
        return self.seen

    def close(self) -> None:
        """The subscriber, then the session (closing twice is harmless)."""
        self.sub.close()
        self.session.close()
