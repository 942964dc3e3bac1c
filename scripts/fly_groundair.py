"""The ground–air mission of `skyherd fly`: a learned policy keeps three UGVs in the camera's
view, through MAVLink offboard, behind the safety net.

The UGV team drives the composite scenario the policy was trained on (the same formation
model as `skyherd/GroundAir-v0`); frames go out on Zenoh (`skyherd/uav0/camera/frame`) so
`skyherd watch` can look on. The safety net's fallback is mapped onto the autopilot's own
HOLD mode, and back to OFFBOARD when the recovery controller or the AI flies again.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from flight.autopilot_api import FlightMode
from hil.client import ClientTimeout, CommandError, Telemetry, VehicleClient
from hil.companion import GroundAirCompanion, PerceptionFollower, PolicyPilot
from hil.session import TRACK_COLUMNS, FlightSession
from perception.detector import contact_sheet, write_png
from perception.pipeline import CameraRig, CameraRigParams
from policy.groundair.fastphi import min_circle
from policy.groundair.params import TaskParams
from policy.groundair.scenarios import make_team
from runio.runfolder import RunFolder, markdown_table
from safety.supervisor import Mode, Supervisor

STRIP_EVERY_S = 6.0  # one annotated frame in the strip per this much simulation time [s]


@dataclass(frozen=True)
class GroundAirMission:
    """What the ground–air flight does (saved in config.json)."""

    scenario: str = "composite"  # UGV team: a training scenario or groundsim:<behaviour>
    pilot: str = "policy"  # "policy" (learned) or "pid" (classic follower on φ)
    duration_s: float = 60.0  # policy flight time after the hand-over [s]
    vehicle: str = "uav0"  # Zenoh key prefix
    renderer: str = "fast"
    camera_hz: float = 10.0


def start_altitude(task: TaskParams, team) -> float:
    """The altitude [m] that frames the team at the expert's spread target (as the env starts)."""
    cam = task.camera
    half_diag = 0.5 * math.hypot(cam.width_px, cam.height_px)
    radius = max(min_circle(team.positions())[2], 3.0)
    alt = cam.fx * radius / (task.spread_target * half_diag)
    alt += cam.mount_offset_frd[2]
    return float(min(max(alt, task.uav.alt_min_m + 2.0), task.uav.alt_max_m - 2.0))


def fly_groundair(
    client: VehicleClient,
    mission: GroundAirMission,
    policy,
    supervisor: Supervisor,
    publisher,
    run_dir: RunFolder,
    seed: int,
    timeout: float,
) -> bool:
    task = TaskParams()
    team = make_team(mission.scenario, np.random.default_rng(seed), task.n_ugvs)
    pilot = PolicyPilot(policy, task) if mission.pilot == "policy" else PerceptionFollower(task)
    world = None
    if mission.renderer == "bullet":
        from groundsim.world import GroundWorld, WorldParams

        initial = GroundAirCompanion.team_states(team)
        world = GroundWorld(initial, behaviour=None, params=WorldParams(n_ugv=task.n_ugvs))
    rig = CameraRig(task.camera, task.n_ugvs, CameraRigParams(mission.renderer, mission.camera_hz),
                    world=world, publisher=publisher)  # fmt: skip
    companion = GroundAirCompanion(task, team, pilot, supervisor, rig, world=world)
    altitude = start_altitude(task, team)
    strip: list[np.ndarray] = []
    state = {"active": False, "t_end": math.inf, "error": ""}

    def setpoint(tel: Telemetry):
        vs = tel.vehicle_state()
        if not state["active"] or vs is None:
            return None if fs.hold_target is None else (fs.hold_target, None, 0.0)
        t = vs.t
        try:
            d = companion.update(t, vs)
        except Exception as e:  # never let the receive thread die: fall back to hover
            state["error"] = f"companion failed at t={t:.1f} s: {type(e).__name__}: {e}"
            state["active"] = False
            fs.hold_target = vs.pos_ned.copy()
            return fs.hold_target, None, 0.0
        tick = companion.last_tick
        if tick is not None and tick.t >= len(strip) * STRIP_EVERY_S + companion.t0:
            from perception.detector import annotate

            strip.append(annotate(tick.frame, tick.detections))
        cmd = d.command
        return cmd.pos_ned, cmd.vel_ned, 0.0 if cmd.yaw is None else cmd.yaw

    steps = ["connect", "arm", "takeoff", "offboard", "policy flight", "land"]
    fs = FlightSession(client, run_dir.metrics(TRACK_COLUMNS), steps, timeout)
    fs.mission_fn = setpoint
    ok = True
    try:
        fs.connect_arm_takeoff(altitude)
        fs.offboard(altitude)
        fs.step("policy", f"policy flight, {mission.duration_s:.0f} s behind the safety net")
        state["active"] = True
        t_end = fs.vehicle_time() + mission.duration_s
        tel = client.telemetry
        while fs.vehicle_time() < t_end:
            if state["error"]:
                raise ClientTimeout(state["error"])
            # the safety net's fallback is the autopilot's own HOLD; recovery flies offboard
            if companion.wants_hold and tel.mode is FlightMode.OFFBOARD:
                fs.set_mode(FlightMode.HOLD)
            elif not companion.wants_hold and tel.mode is FlightMode.HOLD:
                fs.set_mode(FlightMode.OFFBOARD)
            client.wait_message("LOCAL_POSITION_NED", timeout=min(5.0, fs.left()))
            shown = (
                f"t={fs.vehicle_time() - t_end + mission.duration_s:.0f} s {supervisor.mode.value}"
            )
            if shown != fs.bar.postfix:
                fs.bar.set_postfix_str(shown)
        state["active"] = False
        fs.hold_target = tel.pos_ned.copy()
        fs.done()
        fs.land()
    except (ClientTimeout, CommandError) as e:
        fs.bar.write(f"skyherd fly: {e}")
        ok = False
    state["active"] = False
    track = fs.close()
    if world is not None:
        world.close()
    return _report(run_dir, mission, task, companion, supervisor, track, strip, ok)


def _report(run_dir, mission, task, companion, supervisor, track, strip, ok) -> bool:
    samples = companion.samples
    cam = task.camera
    in_view = np.array([s.phi[5] > 0.5 for s in samples], dtype=bool)
    ratios = []
    for s, alt in zip(samples, _sample_altitudes(samples, track)):
        if s.phi[5] > 0.5:
            _, _, r = min_circle([tuple(p) for p in s.ugvs_ne])
            z = alt - cam.mount_offset_frd[2]
            footprint = (cam.width_px * z / cam.fx) * (cam.height_px * z / cam.fx)
            ratios.append(footprint / max(math.pi * r * r, 1e-6))
    losses = int(np.sum(in_view[:-1] & ~in_view[1:])) if len(in_view) > 1 else 0
    st = supervisor.stats
    rows = [
        ["decisions", len(samples)],
        ["all UGVs in view [fraction of decisions]", float(in_view.mean()) if len(in_view) else math.nan],
        ["footprint / smallest circle [mean]", float(np.mean(ratios)) if ratios else math.nan],
        ["UGV losses (all-in-view → not)", losses],
        ["safety-net switches", st.switches],
        ["AI actions rejected", st.rejected],
        ["time in fallback [s]", st.fallback_s],
        ["time under PID [s]", st.pid_s],
        ["AI in control at the end", supervisor.mode is Mode.AI],
    ]  # fmt: skip
    table = markdown_table(["metric", "value"], rows)
    _plot(run_dir, samples, track)
    if strip:
        _save_strip(run_dir, strip)
    status = "completed" if ok else "ABORTED"
    run_dir.write_summary(
        f"# skyherd fly: ground–air mission {status}\n\n"
        f"UGV team `{mission.scenario}`, pilot `{mission.pilot}`, {mission.duration_s:.0f} s of "
        f"flight behind the safety net.\n\n{table}"
    )
    print(table)
    print(f"skyherd fly: {status}; tlog, metrics.csv, events.jsonl, groundair.png, "
          f"frames.png and summary.md in {run_dir.path}")  # fmt: skip
    return ok


def _sample_altitudes(samples, track: np.ndarray) -> list[float]:
    if len(track) == 0:
        return [math.nan] * len(samples)
    return [float(-np.interp(s.t, track[:, 0], track[:, 3])) for s in samples]


def _plot(run_dir: RunFolder, samples, track: np.ndarray) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axs = plt.subplots(1, 3, figsize=(15, 4.5))
    if samples:
        t = np.array([s.t for s in samples])
        ugv = np.array([s.ugvs_ne for s in samples])  # (K, N, 2)
        for i in range(ugv.shape[1]):
            axs[0].plot(ugv[:, i, 1], ugv[:, i, 0], lw=0.8, alpha=0.7, label=f"UGV {i}")
        sel = (track[:, 0] >= t[0]) if len(track) else slice(None)
        axs[0].plot(track[sel, 2], track[sel, 1], "k-", lw=1.5, label="UAV")
        axs[1].plot(track[:, 0], -track[:, 3], "k-")
        phi = np.array([s.phi for s in samples])
        axs[2].plot(t, phi[:, 5], "g-", label="all in view")
        axs[2].plot(t, phi[:, 2], "b-", label="spread")
        mode = np.array(
            [{"ai": 0.0, "fallback": 1.0, "pid": 0.5}[s.decision.mode.value] for s in samples]
        )
        axs[2].plot(t, mode, "r:", label="safety net (0 AI, .5 PID, 1 fallback)")
        axs[2].legend(fontsize=8)
    axs[0].set_xlabel("east [m]")
    axs[0].set_ylabel("north [m]")
    axs[0].set_aspect("equal", adjustable="datalim")
    axs[0].legend(fontsize=8)
    axs[0].set_title("UAV over the UGV team (NED)")
    axs[1].set_xlabel("time [s]")
    axs[1].set_ylabel("altitude [m]")
    axs[1].set_title("altitude")
    axs[2].set_xlabel("time [s]")
    axs[2].set_title("features and safety net")
    fig.tight_layout()
    fig.savefig(run_dir.file("groundair.png"), dpi=100)
    plt.close(fig)


def _save_strip(run_dir: RunFolder, frames: list[np.ndarray]) -> None:
    write_png(run_dir.file("frames.png"), contact_sheet(frames, cols=4))
