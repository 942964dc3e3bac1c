"""The square mission of `skyherd fly --mission square`: take off, fly a square in offboard
position control, land; the table gives each leg's time and largest cross-track error."""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from flight.autopilot_api import FlightMode
from hil.client import ClientTimeout, CommandError, VehicleClient
from hil.session import TRACK_COLUMNS, FlightSession
from runio.runfolder import RunFolder, markdown_table


@dataclass(frozen=True)
class SquareMission:
    """Take off, fly a square of side `side` [m] at `altitude` [m] above home, land."""

    altitude: float = 20.0
    side: float = 40.0
    accept_radius: float = 1.0  # [m] a corner counts as reached within this distance
    settle_s: float = 1.0  # [s] of vehicle time held inside the radius at each corner

    def corners_ned(self) -> list[np.ndarray]:
        d, s = -self.altitude, self.side
        return [np.array(p, dtype=float) for p in ([s, 0, d], [s, s, d], [0, s, d], [0, 0, d])]


def fly_square(
    client: VehicleClient, mission: SquareMission, run_dir: RunFolder, timeout: float
) -> bool:
    steps = ["connect", "arm", "takeoff", "offboard"] + [f"corner {i + 1}" for i in range(4)]
    fs = FlightSession(client, run_dir.metrics(TRACK_COLUMNS), steps + ["land"], timeout)
    tel = client.telemetry
    legs: list[list] = []
    try:
        fs.connect_arm_takeoff(mission.altitude)
        fs.offboard(mission.altitude)
        for i, corner in enumerate(mission.corners_ned()):
            fs.step(
                f"corner {i + 1}", f"corner {i + 1} of 4 ({corner[0]:.0f} N, {corner[1]:.0f} E)"
            )
            start, t0 = tel.pos_ned.copy(), fs.vehicle_time()
            fs.hold_target = corner
            _wait_settled(client, corner, mission, fs.left())
            t1 = fs.vehicle_time()
            track = np.array(fs.track)
            err = _cross_track(track[:, 1:], start, corner, t0, t1, track[:, 0])
            legs.append([i + 1, f"{corner[0]:.0f} N {corner[1]:.0f} E", t1 - t0, err])
            fs.done()
        fs.land()
        ok = True
    except (ClientTimeout, CommandError) as e:
        fs.bar.write(f"skyherd fly: {e}")
        ok = False
    track = fs.close()
    _plot_track(run_dir, track, mission)
    table = markdown_table(["leg", "to", "time [s]", "max cross-track [m]"], legs)
    status = "completed" if ok else "ABORTED"
    run_dir.write_summary(
        f"# skyherd fly: square mission {status}\n\n"
        f"{mission.side:.0f} m square at {mission.altitude:.0f} m.\n\n{table}"
    )
    print(table)
    print(f"skyherd fly: {status}; tlog, metrics.csv, track.png and summary.md in {run_dir.path}")
    return ok


def _wait_settled(
    client: VehicleClient, corner: np.ndarray, mission: SquareMission, timeout: float
) -> None:
    tel = client.telemetry
    since = {"t": None}

    def settled() -> bool:
        if tel.mode is not FlightMode.OFFBOARD:
            raise ClientTimeout(f"vehicle left OFFBOARD (now {tel.mode.name})")
        if tel.pos_ned is None:
            return False
        t = tel.time_boot_ms / 1000.0
        if np.linalg.norm(tel.pos_ned - corner) > mission.accept_radius:
            since["t"] = None
            return False
        since["t"] = t if since["t"] is None else since["t"]
        return t - since["t"] >= mission.settle_s

    client.wait_until(settled, timeout, f"corner {corner[0]:.0f} N {corner[1]:.0f} E")


def _cross_track(
    pos: np.ndarray, a: np.ndarray, b: np.ndarray, t0: float, t1: float, t: np.ndarray
) -> float:
    """Largest horizontal distance [m] from the segment a→b over the leg's samples."""
    sel = pos[(t >= t0) & (t <= t1)][:, :2]
    if len(sel) == 0:
        return math.nan
    ab = (b - a)[:2]
    u = np.clip(((sel - a[:2]) @ ab) / max(ab @ ab, 1e-9), 0.0, 1.0)
    closest = a[:2] + u[:, None] * ab
    return float(np.max(np.linalg.norm(sel - closest, axis=1)))


def _plot_track(run_dir: RunFolder, track: np.ndarray, mission: SquareMission) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, (ax1, ax2) = plt.subplots(1, 2, figsize=(11, 4.5))
    c = np.array(mission.corners_ned())
    ax1.plot(np.r_[0, c[:, 1]], np.r_[0, c[:, 0]], "k--", lw=1, label="planned")
    if len(track):
        ax1.plot(track[:, 2], track[:, 1], "b-", lw=1.5, label="flown")
        ax2.plot(track[:, 0], -track[:, 3], "b-")
    ax1.set_xlabel("east [m]")
    ax1.set_ylabel("north [m]")
    ax1.set_aspect("equal")
    ax1.legend()
    ax1.set_title("track (NED, about home)")
    ax2.set_xlabel("time [s]")
    ax2.set_ylabel("altitude above home [m]")
    ax2.set_title("altitude")
    fig.tight_layout()
    fig.savefig(run_dir.file("track.png"), dpi=110)
    plt.close(fig)
