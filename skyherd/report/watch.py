"""`skyherd watch`'s run folder at its end (on every ending, Ctrl-C too): strip.png and
summary.md from what was received: the link's counts, the detection figures, the camera and
detector used, what flight.mcap holds and whether the frames were authenticated."""

from __future__ import annotations

import numpy as np

from skyherd.perception.detector import write_png
from skyherd.perception.transport import LinkStats
from skyherd.perception.watch import Watched, strip_image
from skyherd.record.watch import FlightWatch
from skyherd.runio import Run, markdown_table


def watch_table(stats: LinkStats, seen: Watched) -> str:
    """The link's counts, frames processed, UGVs detected, all-in-view and latency."""
    lat = np.array(stats.latencies_s) * 1e3
    counts, all_in = seen.counts, seen.all_in
    rows = [[k, v] for k, v in stats.as_dict().items()]
    rows += [
        ["processed", seen.processed],
        ["mean UGVs detected", float(np.mean(counts)) if counts else None],
        ["all in view (fraction)", float(np.mean(all_in)) if all_in else None],
        ["latency p50 [ms]", float(np.percentile(lat, 50)) if lat.size else None],
        ["latency p95 [ms]", float(np.percentile(lat, 95)) if lat.size else None],
    ]
    return markdown_table(["quantity", "value"], rows, missing="no frame was processed")


def finish_watch(run: Run, w: FlightWatch, strip: int, signing_key: str | None) -> None:
    """strip.png (at most `strip` frames) and summary.md from what `w` received; the table and
    the run folder on standard output. `signing_key`: the key file the frames were
    authenticated with (None: not authenticated)."""
    stats, seen, vehicle, recorded = w.sub.stats, w.seen, w.vehicle, w.recorded()
    if strip and seen.strip:
        image, n = strip_image(seen.strip, strip)
        write_png(run.file("strip.png"), image)
        run.describe("strip.png", f"{n} annotated frames, sim time on each (red dot "
                     "image centre, blue dot UGVs' centre of mass, blue circle their spread)")  # fmt: skip
    table = watch_table(stats, seen)
    det = seen.detector
    cam_line = f"Camera: {det.cam}\n\nDetector: {det.p}\n" if det is not None else ""
    rec_line = ""
    if recorded is not None:
        rec_line = (f"flight.mcap: {sum(recorded.values())} messages on {len(recorded)} channels "
                    f"({', '.join(f'{k} {n}' for k, n in sorted(recorded.items()))}).\n\n")  # fmt: skip
    checked = (f"authenticated with the flight key ({signing_key}): {stats.refused} refused"
               if signing_key is not None else "not authenticated (no --signing-key): any publisher's are shown")  # fmt: skip
    run.summary(f"Frames of `skyherd/{vehicle}/camera/frame`, {checked}.\n\n"
                f"{table}\n{rec_line}{cam_line}")  # fmt: skip
    print(table)
    print(f"run folder: {run.path}")


def no_frame(
    vehicle: str, timeout_s: float, refused: int, signing_key: str | None, connect: str | None
) -> str:
    """Why a watch ends failed: no frame within the timeout, and the likely cause."""
    why = (f"{refused} refused as not signed with --signing-key {signing_key} (another "
           "flight's key, or an unsigned source?)" if refused else
           f"is a flight publishing? --connect {connect}")  # fmt: skip
    return f"no frame on skyherd/{vehicle}/camera/frame within {timeout_s:g} s ({why})"
