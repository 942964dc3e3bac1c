"""`skyherd fly --airframe fixedwing`: the fixed-wing orbits over the UGV team's centre of mass.

Runway take-off to 40 m, then OFFBOARD: a position setpoint at the team's centre of mass and
the planned altitude, which the autopilot loiters about with the planned radius (NAV_LOITER_RAD
set over MAVLink). The setpoint moves with the team. A gimballed camera points at the centre of
mass; frames go out on Zenoh and through the detector. The safety net judges every decision; its
fallback is the autopilot's HOLD (a loiter). After `--orbit-duration` s of established orbit it
lands straight ahead. See hil/orbit.py for the geometry and docs/orbit.md for results.
"""

from __future__ import annotations

import argparse
import json
import math
from dataclasses import asdict, dataclass

import numpy as np
from pymavlink.dialects.v20 import common as mavlink2

from flight.autopilot_api import FlightMode
from groundsim.ugv import UGVStates
from hil.client import ClientTimeout, CommandError, Telemetry, VehicleClient
from hil.orbit import (
    ORBIT_CAMERA,
    OrbitCompanion,
    OrbitParams,
    OrbitPlan,
    climb_out,
    fence_reserve,
    plan_orbit,
)
from hil.session import TRACK_COLUMNS, FlightSession
from perception.detector import contact_sheet, write_png
from perception.pipeline import CameraRig, CameraRigParams
from policy.groundair.scenarios import Formation, draw_plan
from runio.runfolder import RunFolder, atomic_write_bytes, markdown_table
from safety.net import warm_up
from scripts.fly_options import add_orbit_arguments  # noqa: F401 - the options live there

TAKEOFF_ALT_M = 40.0
STRIP_EVERY_S = 8.0  # one annotated frame in frames.png per this much simulation time [s]


@dataclass(frozen=True)
class OrbitMission:
    """What the orbit flight does (saved in orbit.json)."""

    scenario: str = "lateral"  # policy.groundair.scenarios Formation
    duration_s: float = 90.0  # established orbit flown before landing [s]
    establish_s: float = 240.0  # the orbit must be established within this [s, vehicle time]
    radius_tol: float = 0.10  # established: |d − R| <= tol·R ...
    alt_tol_m: float = 2.0  # ... and |h_now − h| <= this [m]
    establish_hold_s: float = 10.0  # ... both held this long (a capture crossing is not enough)
    mode_retry_s: float = 2.0  # repeat a mode request not yet shown by the heartbeat [s]
    mode_give_up_s: float = 30.0  # abort when the autopilot does not follow for this long [s]
    alt_reserve_m: float = 15.0  # planned h stays this far inside the envelope's ceiling margin [m]
    camera_hz: float = 10.0
    renderer: str = "fast"  # "fast" (OpenCV) or "bullet" (PyBullet GroundWorld)
    land: bool = True
    vehicle: str = "uav0"


def _mission(args) -> OrbitMission:
    dur = getattr(args, "orbit_duration", None)  # else `skyherd fly --duration`, else 90 s
    dur = float(dur if dur is not None else getattr(args, "duration", None) or 90.0)
    if not (math.isfinite(dur) and 0 < dur <= 3600):
        from scripts.cli import UsageError

        raise UsageError(
            "the orbit duration (--orbit-duration / --duration) must be in (0, 3600] s"
        )
    renderer = getattr(args, "renderer", None) or "fast"
    if renderer not in ("fast", "bullet"):
        from scripts.cli import UsageError

        raise UsageError(f"--renderer must be fast or bullet, got {renderer!r}")
    return OrbitMission(scenario=getattr(args, "orbit_scenario", "lateral"), duration_s=dur,
                        land=not getattr(args, "orbit_no_land", False), renderer=renderer)  # fmt: skip


def _envelope(args):
    from safety.config import ENVELOPE_DIR, EnvelopeFileError, load_envelope
    from safety.supervisor import SupervisorParams
    from scripts.cli import UsageError

    path = getattr(args, "envelope", None) or ENVELOPE_DIR / "fixedwing_field.toml"
    try:
        spec, sup = load_envelope(path)
        sp = SupervisorParams(**sup)
    except (EnvelopeFileError, TypeError, ValueError) as e:
        raise UsageError(f"{e}; fix the file or pass another --envelope") from None
    if spec.airframe != "fixedwing":
        raise UsageError(f"{path} is a {spec.airframe} envelope; pass a fixed-wing one")
    return path, spec, sp


def orbit_params_for(team: Formation, spec, mission: OrbitMission, **airframe) -> OrbitParams:
    """Orbit parameters from the team's plan, the envelope's altitude band and the airframe."""
    p = team.plan
    r = min(p.r0 + p.r_amp + abs(p.r_rate) * (mission.duration_s + mission.establish_s), p.r_max)
    lim = spec.limits
    return OrbitParams(team_speed_mps=p.speed, team_radius_m=r, n_ugvs=len(p.angles),
                       alt_min_m=lim.floor_m + lim.margin_m,
                       alt_max_m=lim.ceiling_m - lim.margin_m - mission.alt_reserve_m, **airframe)  # fmt: skip


def read_param(client: VehicleClient, name: str, timeout: float = 3.0) -> float:
    """PARAM_REQUEST_READ → PARAM_VALUE of `name` (ClientTimeout when unanswered)."""
    seen = {"v": None}

    def got() -> bool:
        m = client.latest("PARAM_VALUE")
        if m is not None and m.param_id.rstrip("\x00") == name:
            seen["v"] = float(m.param_value)
        return seen["v"] is not None

    for _ in range(3):
        client.link.send(mavlink2.MAVLink_param_request_read_message(
            client.target_system, 1, name.encode(), -1))  # fmt: skip
        try:
            client.wait_until(got, timeout / 3, f"parameter {name}")
            return seen["v"]
        except ClientTimeout:
            continue
    raise ClientTimeout(f"no PARAM_VALUE for {name}")


def write_param(client: VehicleClient, name: str, value: float, timeout: float = 3.0) -> None:
    """PARAM_SET, confirmed by the PARAM_VALUE echo (ClientTimeout when unanswered)."""

    def echoed() -> bool:
        m = client.latest("PARAM_VALUE")
        return (m is not None and m.param_id.rstrip("\x00") == name
                and abs(m.param_value - value) < 1e-3 * max(1.0, abs(value)))  # fmt: skip

    for _ in range(3):
        client.link.send(mavlink2.MAVLink_param_set_message(
            client.target_system, 1, name.encode(), float(value),
            mavlink2.MAV_PARAM_TYPE_REAL32))  # fmt: skip
        try:
            client.wait_until(echoed, timeout / 3, f"{name} = {value:g}")
            return
        except ClientTimeout:
            continue
    raise ClientTimeout(f"{name} was not set to {value:g}")


def run_orbit(args: argparse.Namespace, client: VehicleClient, run_dir: RunFolder,
              publisher) -> bool:  # fmt: skip
    """Fly the orbit through a started client; write the run folder; True when it completed."""
    from safety.supervisor import Supervisor

    mission = _mission(args)
    env_path, spec, sp = _envelope(args)
    seed = int(getattr(args, "seed", 0))
    team = Formation(draw_plan(mission.scenario, np.random.default_rng(seed), 3))
    try:
        plan = plan_orbit(orbit_params_for(team, spec, mission))  # checked before flying
    except ValueError as e:
        from scripts.cli import UsageError

        raise UsageError(f"orbit: {e}") from None
    envelope = spec.envelope()
    warm_up(envelope, sp)
    supervisor = Supervisor(envelope, sp, run_dir.events())
    if publisher is not None and getattr(publisher, "cam", ORBIT_CAMERA) != ORBIT_CAMERA:
        publisher.cam = ORBIT_CAMERA  # camera info on Zenoh must describe the gimbal camera
    world = None
    if mission.renderer == "bullet":
        from groundsim.world import GroundWorld, WorldParams

        pos = np.array(team.positions(), dtype=float)
        initial = UGVStates(pos, np.zeros(3), np.zeros(3), np.zeros(3, dtype=bool))
        world = GroundWorld(initial, behaviour=None, params=WorldParams(n_ugv=3))
    rig = CameraRig(ORBIT_CAMERA, 3, CameraRigParams(mission.renderer, mission.camera_hz),
                    world=world, publisher=publisher)  # fmt: skip
    timeout = float(getattr(args, "timeout", 600.0))
    steps = ["connect", "arm", "takeoff", "plan", "climb-out", "offboard", "orbit",
             "orbit established"]  # fmt: skip
    steps += ["land"] if mission.land else []
    fs = FlightSession(client, run_dir.metrics(TRACK_COLUMNS), steps, timeout)
    state = {"comp": None, "error": "", "t_est": None, "modes": []}
    strip: list[np.ndarray] = []

    def setpoint(tel: Telemetry):
        comp, vs = state["comp"], tel.vehicle_state()
        if comp is None or vs is None:
            return None if fs.hold_target is None else (fs.hold_target, None, None)
        try:
            comp.update(vs.t, vs)
            tick = comp.last_tick
            if tick is not None and tick.t >= len(strip) * STRIP_EVERY_S + comp.t0:
                from perception.detector import annotate

                strip.append(annotate(tick.frame, tick.detections))
            return comp.setpoint()
        except Exception as e:  # never let the receive thread die: loiter where we are
            state["error"] = f"companion failed at t={vs.t:.1f} s: {type(e).__name__}: {e}"
            state["comp"] = None
            fs.hold_target = vs.pos_ned.copy()
            return fs.hold_target, None, None

    fs.mission_fn = setpoint
    ok, comp = True, None
    try:
        fs.connect_arm_takeoff(TAKEOFF_ALT_M)
        fs.step("plan", "plan: airframe parameters over MAVLink")
        airframe = dict(airspeed_mps=read_param(client, "FW_AIRSPD_TRIM"),
                        bank_max_rad=math.radians(read_param(client, "FW_R_LIM")))  # fmt: skip
        plan = plan_orbit(orbit_params_for(team, spec, mission, **airframe))
        write_param(client, "NAV_LOITER_RAD", plan.radius_m)
        atomic_write_bytes(run_dir.file("orbit.json"), json.dumps(
            {"mission": asdict(mission), "plan": asdict(plan), "camera": repr(ORBIT_CAMERA),
             "envelope": {"path": str(env_path), "name": spec.name, "version": spec.version},
             "team_plan": asdict(team.plan), "seed": seed}, indent=2, default=str).encode())  # fmt: skip
        fs.done()
        comp = OrbitCompanion(plan, team, supervisor, rig, fence_reserve(spec), world=world)
        fs.step("climb-out", "climb-out: the autopilot's loiter to the orbit, until certified")
        climb_out(client, comp, fs.vehicle_time)  # hil/orbit.py: the climb-out inside the envelope
        fs.done()
        fs.offboard(plan.altitude_m)
        fs.step("orbit", f"orbit: R {plan.radius_m:.0f} m at {plan.altitude_m:.0f} m")
        state["comp"] = comp
        _fly(fs, client, comp, mission, state)
        if mission.land:
            state["comp"] = None
            fs.hold_target = None
            fs.mission_fn = None
            fs.set_mode(FlightMode.HOLD)
            fs.land()
    except (ClientTimeout, CommandError, ValueError) as e:
        fs.bar.write(f"skyherd fly: orbit: {e}")
        state["abort"] = f"aborted at t={fs.vehicle_time():.1f} s ({fs.phase}): {e}"
        ok = False
    state["comp"] = None
    track = fs.close()
    if world is not None:
        world.close()
    return _report(run_dir, mission, plan, comp, supervisor, track, strip, state["t_est"],
                   state.get("abort", ""), state["modes"], ok)  # fmt: skip


def _fly(fs: FlightSession, client: VehicleClient, comp: OrbitCompanion, mission: OrbitMission,
         state: dict) -> None:  # fmt: skip
    tel = client.telemetry
    t_start = fs.vehicle_time()
    t_end = math.inf
    t_in = None  # since when the aircraft has been inside the tolerances
    while fs.vehicle_time() < t_end:
        if state["error"]:
            raise ClientTimeout(state["error"])
        _follow_safety_net(client, comp, fs.vehicle_time(), state, mission)
        client.wait_message("LOCAL_POSITION_NED", timeout=min(5.0, fs.left()))
        t = fs.vehicle_time()
        if state["t_est"] is None:
            inside = _established(tel, comp, mission)
            t_in = (t_in if t_in is not None else t) if inside else None
            if t_in is not None and t - t_in >= mission.establish_hold_s:
                state["t_est"] = t
                comp.switches_at_est = comp.supervisor.stats.switches
                t_end = t + mission.duration_s
                fs.done()
                fs.step("orbit established", f"orbit established, {mission.duration_s:.0f} s")
            elif t - t_start > mission.establish_s:
                raise ClientTimeout(f"orbit not established in {mission.establish_s:.0f} s")
    fs.done()


def _follow_safety_net(client: VehicleClient, comp: OrbitCompanion, t: float, state: dict,
                       mission: OrbitMission) -> None:  # fmt: skip
    """Put the autopilot in the mode the safety net flies: HOLD (its loiter) in FALLBACK,
    OFFBOARD otherwise. The request is repeated every `mode_retry_s` of vehicle time until the
    heartbeat shows it (a denied or reverted switch is retried, not fatal); ClientTimeout when
    the autopilot has not followed for `mode_give_up_s`."""
    tel = client.telemetry
    want = FlightMode.HOLD if comp.wants_hold else FlightMode.OFFBOARD
    if tel.mode not in (FlightMode.HOLD, FlightMode.OFFBOARD) or tel.mode is want:
        state["mode_since"] = None
        return
    since = state.get("mode_since")
    if since is None or since[1] is not want:
        since = state["mode_since"] = (t, want)
    elif t - since[0] > mission.mode_give_up_s:
        raise ClientTimeout(f"the autopilot stayed in {tel.mode.name} for {t - since[0]:.0f} s "
                            f"although the safety net asks for {want.name}")  # fmt: skip
    last = state.get("mode_asked")
    if last is not None and last[1] is want and t - last[0] < mission.mode_retry_s:
        return
    state["mode_asked"] = (t, want)
    state["modes"].append((t, want.name))
    try:
        client.set_mode(want)
    except CommandError as e:
        state["modes"].append((t, f"{want.name} refused ({e})"))


def _established(tel: Telemetry, comp: OrbitCompanion, mission: OrbitMission) -> bool:
    if tel.pos_ned is None or comp.supervisor.mode.value != "ai":
        return False
    d = float(np.hypot(*(tel.pos_ned[:2] - comp.centre)))
    return (abs(d - comp.plan.radius_m) <= mission.radius_tol * comp.plan.radius_m
            and abs(-tel.pos_ned[2] - comp.plan.altitude_m) <= mission.alt_tol_m)  # fmt: skip


@dataclass(frozen=True)
class OrbitResult:
    """The figures of one orbit flight (after the orbit was established)."""

    frames: int
    all_detected: float  # fraction of frames where the detector found every UGV
    all_projected: float  # fraction where every UGV's true position is inside the image
    body_fixed: float  # the same for a body-fixed downward camera (not flown, for comparison)
    radius_err_mean_m: float  # mean |d − R|, d from the commanded orbit centre
    radius_err_max_m: float
    alt_err_mean_m: float  # mean |h_now − h|
    alt_err_max_m: float
    bank_mean_deg: float
    tilt_mean_deg: float
    switches: int
    switches_orbit: int  # after the orbit was established
    fallback_s: float
    limited: int  # decisions where the fence held the orbit centre short of the com
    centre_travel_m: float  # how far the UGV centre of mass moved during the established orbit
    held_back_max_m: float  # largest distance between the orbit centre and the com (fence)


def orbit_result(comp: OrbitCompanion | None, supervisor, t_est: float | None) -> OrbitResult:
    sel = [] if comp is None or t_est is None else [s for s in comp.samples if s.t >= t_est]
    st = supervisor.stats
    if not sel:
        nan = math.nan
        return OrbitResult(0, nan, nan, nan, nan, nan, nan, nan, nan, nan, st.switches, 0, st.fallback_s,
                           comp.limited if comp else 0, nan, nan)  # fmt: skip
    plan = comp.plan
    d = np.array([np.hypot(*(s.pos_ned[:2] - s.orbit_ne)) for s in sel])
    off = np.array([np.hypot(*(s.orbit_ne - s.centre_ne)) for s in sel])
    h = np.array([-s.pos_ned[2] for s in sel])
    return OrbitResult(
        len(sel), float(np.mean([s.all_detected for s in sel])),
        float(np.mean([s.all_projected for s in sel])),
        float(np.mean([s.body_fixed for s in sel])),
        float(np.mean(np.abs(d - plan.radius_m))), float(np.max(np.abs(d - plan.radius_m))),
        float(np.mean(np.abs(h - plan.altitude_m))), float(np.max(np.abs(h - plan.altitude_m))),
        math.degrees(float(np.mean(np.abs([s.bank_rad for s in sel])))),
        math.degrees(float(np.mean([s.tilt_rad for s in sel]))),
        st.switches, st.switches - comp.switches_at_est, st.fallback_s, comp.limited,
        float(np.hypot(*(sel[-1].centre_ne - sel[0].centre_ne))), float(np.max(off)),
    )  # fmt: skip


def _report(run_dir, mission, plan: OrbitPlan, comp, supervisor, track, strip, t_est, abort: str,
            modes: list, ok) -> bool:  # fmt: skip
    res = orbit_result(comp, supervisor, t_est)
    rows = [
        ["orbit radius R (planned) [m]", plan.radius_m],
        ["orbit altitude h (planned) [m]", plan.altitude_m],
        ["slant range / look-down [m / deg]", f"{plan.slant_m:.0f} / {math.degrees(plan.depression_rad):.1f}"],
        ["frames after the orbit was established", res.frames],
        ["all UGVs detected [fraction of frames]", res.all_detected],
        ["all UGVs inside the image (true positions)", res.all_projected],
        ["radius error about the orbit centre, mean / max [m]", f"{res.radius_err_mean_m:.1f} / {res.radius_err_max_m:.1f}"],
        ["altitude error mean / max [m]", f"{res.alt_err_mean_m:.1f} / {res.alt_err_max_m:.1f}"],
        ["mean bank / gimbal tilt [deg]", f"{res.bank_mean_deg:.1f} / {res.tilt_mean_deg:.1f}"],
        ["... for a body-fixed downward camera (comparison)", res.body_fixed],
        ["safety-net switches (all / after establishment)", f"{res.switches} / {res.switches_orbit}"],
        ["time in fallback (loiter) [s]", res.fallback_s],
        ["decisions with the orbit centre held back by the fence", res.limited],
        ["largest orbit centre – centre of mass distance [m]", res.held_back_max_m],
        ["UGV centre of mass moved during the orbit [m]", res.centre_travel_m],
    ]  # fmt: skip
    table = markdown_table(["metric", "value"], rows)
    _plot(run_dir, comp, plan, track, t_est)
    if strip:
        _save_strip(run_dir, strip)
    status = "completed" if ok else "ABORTED"
    run_dir.write_summary(
        f"# skyherd fly: fixed-wing orbit {status}\n\nScenario `{mission.scenario}`, "
        f"{mission.duration_s:.0f} s of established orbit over the UGV team's centre of mass, "
        f"gimballed camera ({math.degrees(ORBIT_CAMERA.hfov_rad):.0f}° field of view).\n\n"
        f"{table}\n"
        + (f"\n**{abort}**\n" if abort else "")
        + ("\nAutopilot mode changes asked for by the safety net: "
           + ", ".join(f"t={t:.1f} s {m}" for t, m in modes) + "\n" if modes else "")
    )  # fmt: skip
    print(table)
    print(f"skyherd fly: {status}; tlog, metrics.csv, events.jsonl, orbit.json, orbit.png, "
          f"frames.png and summary.md in {run_dir.path}")  # fmt: skip
    atomic_write_bytes(
        run_dir.file("orbit_result.json"), json.dumps(asdict(res), indent=2).encode()
    )
    return ok


def _plot(run_dir, comp, plan: OrbitPlan, track: np.ndarray, t_est) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axs = plt.subplots(1, 3, figsize=(16, 4.8))
    if len(track):
        axs[0].plot(track[:, 2], track[:, 1], "k-", lw=0.8, label="aircraft")
        axs[2].plot(track[:, 0], -track[:, 3], "k-", lw=1, label="altitude")
    axs[2].axhline(plan.altitude_m, color="g", ls="--", lw=0.8, label="planned h")
    if comp is not None and comp.samples:
        s = comp.samples
        t = np.array([x.t for x in s])
        ugv = np.array([x.ugvs_ne for x in s])
        for i in range(ugv.shape[1]):
            axs[0].plot(ugv[:, i, 1], ugv[:, i, 0], lw=1.2, label=f"UGV {i}")
        d = np.array([np.hypot(*(x.pos_ned[:2] - x.orbit_ne)) for x in s])
        axs[1].plot(t, d, "b-", lw=1, label="distance to the orbit centre")
        off = np.array([np.hypot(*(x.orbit_ne - x.centre_ne)) for x in s])
        if off.max() > 1.0:
            axs[1].plot(t, off, "m-", lw=1, label="orbit centre – centre of mass (fence)")
        axs[1].axhline(plan.radius_m, color="g", ls="--", lw=0.8, label="planned R")
        inview = np.array([x.all_detected for x in s], dtype=float)
        ax = axs[1].twinx()
        ax.plot(t, inview, "r.", ms=1.5, label="all UGVs detected")
        ax.set_ylim(-0.05, 1.05)
        ax.set_ylabel("all detected (0/1)", color="r")
        if t_est is not None:
            for a in axs[1:]:
                a.axvline(t_est, color="grey", ls=":", lw=1)
    axs[0].set_xlabel("east [m]")
    axs[0].set_ylabel("north [m]")
    axs[0].set_aspect("equal", adjustable="datalim")
    axs[0].legend(fontsize=8)
    axs[0].set_title("orbit over the UGV team (NED about home)")
    axs[1].set_xlabel("time [s]")
    axs[1].set_ylabel("[m]")
    axs[1].legend(fontsize=8, loc="lower right")
    axs[1].set_title("orbit radius (dotted: established)")
    axs[2].set_xlabel("time [s]")
    axs[2].set_ylabel("altitude [m]")
    axs[2].legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(run_dir.file("orbit.png"), dpi=100)
    plt.close(fig)


def _save_strip(run_dir: RunFolder, frames: list[np.ndarray]) -> None:
    write_png(run_dir.file("frames.png"), contact_sheet(frames, cols=4))
