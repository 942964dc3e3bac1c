"""companion.json: how the companion's flight ended, its counters, the decision latency, the state
of its links and the records a full disk or a read-only folder cut. Written whole (never raises:
the ending is still reported); report.reason and `skyherd fly`'s ending lines read it."""

from __future__ import annotations

import dataclasses
import json
import math
import time
from pathlib import Path

import numpy as np

from skyherd.mission.connect import say
from skyherd.runio import CsvWriter, try_write_text


def tick_stats(stats) -> dict:
    """companion.json's loop figures: ticks, decision latency (wall) and CPU time."""
    lat = np.array(stats.decide_wall_s if stats and stats.decide_wall_s else [np.nan])
    some = bool(np.isfinite(lat).any())
    return {
        "ticks": stats.ticks if stats else 0,
        "decide_wall_p50_s": float(np.nanpercentile(lat, 50)) if some else None,
        "decide_wall_p95_s": float(np.nanpercentile(lat, 95)) if some else None,
        "cpu_s": time.process_time(),  # the companion's CPU time since it started [s]
        "cpu_flight_s": stats.cpu_s if stats else None,  # ... from its first tick on [s]
    }


def signed(link) -> bool:
    """Does the MAVLink link sign its frames?"""
    return link.signing is not None and link.signing.enabled


def write_outcome(run_dir: Path, mission, stats, frames, cut: list | None = None,
                  link=None) -> None:  # fmt: skip
    """One vehicle's companion.json (and the orbit's sight.csv, the frames' sheet frames.png);
    `link`: the autopilot's MAVLink link."""
    out = {
        "outcome": mission.outcome,
        "reason": mission.reason,
        "handover": stats.handover if stats is not None else None,
        "records_cut": cut or [],
        "phase": mission.phase,
        "decisions": len(mission.rec.rows),
        **tick_stats(stats),
        "mode_requests": mission.authority.requests,
        "yielded": mission.authority.yielded,
        "frames": None if mission.perception is None else mission.perception.counts,
        "landing": getattr(mission, "landing_note", "") or "as planned",
        "configured": [c.record() for c in getattr(mission, "configured", [])],
        "authority": {
            "t_start": mission.authority.t_start,
            "t_end": mission.authority.t_last,
            "land": bool(getattr(getattr(mission, "f", mission.plan), "land", True)),
            "end_mode": getattr(mission, "end_mode", ""),  # the profile's end when not landed
        },  # fmt: skip
    }
    if link is not None:  # the link's signing: on or off, frames refused by it
        out["mavlink"] = {"signed": signed(link), "rejected": link.rejected_packets}
    sub = getattr(getattr(frames, "source", frames), "sub", None)
    if sub is not None:  # the camera link: authenticated or not, frames refused by it
        out["camera_link"] = {"authenticated": sub.key is not None, "refused": sub.stats.refused,
                              "out_of_order": sub.stats.out_of_order,
                              "repeated": sub.stats.repeated,
                              "info_refused": sub.stats.info_refused}  # fmt: skip
    flock = getattr(mission, "flock_sub", None)
    if flock is not None:  # the shepherd's UGV states: authenticated or not, refused
        out["ugv_link"] = {"authenticated": flock.key is not None, "received": flock.received,
                           "refused": flock.refused}  # fmt: skip
    if getattr(mission, "plan", None) is not None and mission.name == "orbit":
        out["orbit"] = {"plan": dataclasses.asdict(mission.plan),
                        "briefing": dataclasses.asdict(mission.brief),
                        "t_handover": mission.t_handover, "t_established": mission.t_established,
                        "t_orbit_end": mission.t_orbit_end,
                        "centre_limited": mission.limited, "roi": "DO_SET_ROI_LOCATION"}  # fmt: skip
        w = CsvWriter(run_dir / "sight.csv", ["t", "detected", "all_in_view"])
        for t, n, all_in in mission.sight.rows:
            w.write({"t": t, "detected": n, "all_in_view": int(all_in)})
        w.close()
    if mission.net is not None:
        st = mission.net.stats
        out["net"] = {"switches": st.switches, "rejected": st.rejected, "projected": st.projected,
                      "fallback_s": st.fallback_s, "pid_s": st.pid_s}  # fmt: skip
    try_write_text(run_dir / "companion.json", json.dumps(out, indent=2) + "\n")
    if mission.perception is not None and mission.perception.strip:
        from skyherd.perception.detector import write_png

        try:
            write_png(run_dir / "frames.png", mission.perception.strip.sheet())
        except OSError as e:
            say(f"skyherd companion: frames.png not written ({e.strerror or e})")


def write_fleet_outcome(run_dir: Path, mission, record, stats, links, cut: list) -> None:
    """The formation's companion.json: per-vehicle figures under uav<k>."""
    times = {k: None if math.isnan(t) else t for k, t in mission.times.items()}
    out = {"outcome": mission.outcome, "reason": mission.reason, "phase": mission.phase,
           "decisions": record.rows, "vehicles": len(links), "times": times,
           "yielded": {f"uav{k}": w for k, w in mission.yielded.items()},
           "mode_requests": sum(a.requests for a in mission.authority),
           "net": mission.net_counts(), **tick_stats(stats),
           "handover": stats.handover if stats is not None else None,
           "records_cut": cut,
           "mavlink": {"signed": all(signed(link) for link in links),
                       "rejected": {f"uav{k}": link.rejected_packets for k, link in enumerate(links)}}}  # fmt: skip
    try_write_text(run_dir / "companion.json", json.dumps(out, indent=2) + "\n")
