"""The fixed-wing orbit as a companion mission: orbit over the UGV team's centre, seen through
the camera, behind the safety net, in lockstep with `skyherd sim --airframe fixedwing`.

The geometry is mission/orbit_plan.py's (radius and altitude from the airframe's airspeed and bank
limit, the camera's field of view and the team's extent; the certified circle inside the
fence). What is new here is where the centre comes from and who renders: the simulator's
camera sits on a pan-tilt gimbal pointed where the companion sets the region of interest
(MAV_CMD_DO_SET_ROI_LOCATION); every frame received over Zenoh is detected, each UGV's
centroid is back-projected onto the ground from the camera pose the companion computes (the
autopilot's estimate at the frame's time through the head pointed at the acknowledged ROI:
mission.onboard), and their mean is the team's centre as seen. The orbit centre follows it as
far as the fence allows.

Phases: connect → read the airframe's parameters → make the autopilot agree with the envelope
(its climb and sink limits TECS_CLMB_MAX / TECS_SINK_MAX and its bank limit ROLL_LIMIT_DEG
lowered to the envelope's: safety.consistency; any other mismatch → refusal) → plan
(ValueError → refusal) → set its loiter radius (NAV_LOITER_RAD / WP_LOITER_RAD) → take off
(the profile's recipe) → climb-out (the autopilot's own loiter, DO_REPOSITION to the orbit centre at the orbit altitude, until
the net certifies the orbit's setpoint for `climb_hold_s`) → hand over → orbit (until
established, then `duration_s`) → land (the profile's recipe).

What the net certifies is what is flown: the orbit proposes the position setpoint (centre, −h)
and the autopilot is sent exactly that (DO_REPOSITION on ArduPlane), with the loiter radius the
net's implied motion assumes; the parameter guard watches every PARAM_VALUE during the flight.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from pymavlink.dialects.v20 import ardupilotmega as mavlink2

from skyherd.flight.autopilot_api import Setpoint
from skyherd.hil.telemetry import reposition_command
from skyherd.mission.authority import ModeAuthority
from skyherd.mission.flight import Record, append_track
from skyherd.mission.onboard import CameraFrame
from skyherd.mission.orbit_plan import (
    ORBIT_CAMERA,
    OrbitParams,
    OrbitPlan,
    circle_certified,
    plan_orbit,
    setpoint_certified,
    slide_centre,
)
from skyherd.mission.steps import (
    MissionError,
    Phase,
    read_params,
    recipe,
    set_param_checked,
    wait_ready,
)
from skyherd.mission.vehicle import VehicleLink
from skyherd.perception.camera import backproject_to_ground
from skyherd.perception.detector import Detector
from skyherd.perception.sheet import FrameSample, SheetParams
from skyherd.safety.consistency import agreeing_values
from skyherd.safety.net import SafetyNet

M = mavlink2


@dataclass(frozen=True)
class OrbitFlight:
    """What the orbit flight does (saved in config.json)."""

    duration_s: float = 90.0  # established orbit flown before landing [s]
    establish_s: float = 240.0  # the orbit must be established within this [s]
    radius_tol: float = 0.10  # established: |d − R| <= tol·R ...
    alt_tol_m: float = 2.0  # ... and |h_now − h| <= this [m]
    establish_hold_s: float = 10.0  # ... both held this long (a capture crossing is not enough)
    radius_trims: int = 3  # loiter-radius corrections before established (_trim_radius)
    decision_s: float = 0.2  # the orbit centre moves this often [s]
    takeoff_alt_m: float = 40.0  # runway take-off to this height above home [m]
    climb_hold_s: float = 3.0  # the orbit certified this long before the hand-over [s]
    climb_timeout_s: float = 300.0
    reposition_s: float = 5.0  # DO_REPOSITION re-sent this often during the climb-out [s]
    land: bool = True

    def __post_init__(self) -> None:
        if not (0 < self.duration_s <= 3600 and self.decision_s > 0 and self.takeoff_alt_m > 0):
            raise ValueError("duration_s must be in (0, 3600] s, decision_s and takeoff_alt_m > 0")


@dataclass(frozen=True)
class Briefing:
    """What the companion is told about the team before the flight: where it gathers and how
    fast and how wide it may get (the orbit is sized for the worst)."""

    rendezvous_ne: tuple[float, float]  # the team's centre at the start [m]
    team_speed_mps: float
    team_radius_m: float
    n_ugvs: int


class TeamSight:
    """The team's centre as the camera sees it: detections back-projected to the ground."""

    def __init__(self, n_ugvs: int, prior_ne):
        self.detector = Detector(ORBIT_CAMERA, n_ugvs)
        self.n = n_ugvs
        self.centre = np.asarray(prior_ne, float)  # last seen centre (2,) [m]; the prior first
        self.camera_t: float | None = None  # time of the last good frame [s]
        self.rows: list[tuple[float, int, bool]] = []  # (t, detected, all in view) per frame
        self.counts = {"ok": 0, "corrupt": 0, "lost": 0}
        self.strip = FrameSample(SheetParams(every_s=8.0))  # frames.png's (perception.sheet)

    def on_frame(self, t: float, frame: CameraFrame | None, status: str, phase: str = "") -> None:
        self.counts[status] = self.counts.get(status, 0) + 1
        if frame is None:
            return
        det = self.detector.detect(frame.image)
        self.camera_t = t
        n = len(det.centroids_px)
        self.rows.append((t, n, bool(det.all_in_view)))
        self.strip.add(t, frame.image, det, frame.altitude_m, phase)
        pose = frame.camera_pose(ORBIT_CAMERA, "pointed")
        if n == 0 or pose is None:
            return
        ground = backproject_to_ground(ORBIT_CAMERA, pose, det.centroids_px)
        ok = np.isfinite(ground).all(axis=1)
        if ok.any() and n == self.n:
            self.centre = ground[ok, :2].mean(axis=0)  # all UGVs seen: their centre of mass
        elif ok.any():  # some seen: move toward them, do not jump to a part of the team
            self.centre = 0.8 * self.centre + 0.2 * ground[ok, :2].mean(axis=0)


class OrbitMission:
    """connect → plan → take off → climb-out → hand over → orbit → land (module docstring)."""

    name = "orbit"

    def __init__(self, net: SafetyNet, flight: OrbitFlight, briefing: Briefing,
                 record: Record, reserve_m: float, alt_band: tuple[float, float]):  # fmt: skip
        self.net, self.f, self.brief, self.rec = net, flight, briefing, record
        self.reserve_m = reserve_m
        self.alt_band = alt_band  # (min, max) altitude the plan may use [m]
        self.sight = TeamSight(briefing.n_ugvs, briefing.rendezvous_ne)
        self.perception = self.sight
        self.authority = ModeAuthority(net.authority)
        self.plan: OrbitPlan | None = None
        self.centre = np.asarray(briefing.rendezvous_ne, float)  # the certified orbit centre
        self.phase = "connect"
        self.outcome, self.reason = "running", ""
        self.end_mode = ""  # the profile's documented end when it does not land ("" = landed)
        self.t_decision: float | None = None
        self.t_established: float | None = None
        self.t_handover: float | None = None
        self.t_orbit_end: float | None = None
        self.limited = 0  # decisions where the fence held the centre short of the team's
        self._written = 0
        self.loiter_setting = math.nan  # the loiter radius parameter as set [its unit]
        self.trims, self.trim_log = 0, []  # _trim_radius's corrections: (t, mean distance, set)
        self._trim_d: list[float] = []
        self._trim_t = 0.0
        self._airspeed = 20.0
        self.guard = net.params  # the autopilot's parameters against the envelope

    # ---- called by the companion's loop --------------------------------------------------------
    def on_frame(self, t: float, frame, status: str) -> None:
        self.sight.on_frame(t, frame, status, self.phase)
        if frame is not None:
            self.net.frame(t)

    def write_track(self, v: VehicleLink) -> None:
        self._written = append_track(self.rec.track, v, self._written, self.phase)

    # ---- the mission ---------------------------------------------------------------------------
    def run(self, v: VehicleLink) -> Phase:
        f = self.f
        yield from wait_ready(v)
        prof = v.profile
        if prof.vehicle != "fixedwing":
            raise MissionError(
                f"the orbit is a fixed-wing mission; this vehicle is a {prof.vehicle}"
            )
        self.phase = "parameters"
        yield from read_params(v)
        yield from self._agree(v)  # first: the plan reads the bank limit as it will be
        self.plan = self._plan(v)
        self.net.supervisor.loiter_radius_m = self.plan.radius_m  # what its loiter flies
        self.phase = "loiter radius"
        self.loiter_setting = prof.loiter_radius_setting(self.plan.radius_m,
                                                         v.home_amsl_m + self.plan.altitude_m)  # fmt: skip
        yield from set_param_checked(v, prof.param_name("loiter_radius"), self.loiter_setting)
        self.phase = "takeoff"
        yield from recipe(v, prof.takeoff_steps(f.takeoff_alt_m, v.home_amsl_m))
        self.phase = "climb-out"
        yield from self._climb_out(v)
        self.phase = "offboard"
        self.t_handover = v.t
        yield from recipe(v, prof.handover_steps(), hold=self._proposal)
        self._begin_orbit(v)
        t_in, t_end = None, math.inf
        while v.t < t_end - 1e-9:
            rule = self.authority.update(v)
            if rule == "end":
                break
            if rule == "wait":
                self.phase, v.setpoint = "autopilot", None
                yield
                continue
            self.phase = "orbit" if self.t_established is None else "orbit established"
            self._tick(v)
            if self.t_established is None:
                self._trim_radius(v)
                inside = self._inside(v)
                t_in = (t_in if t_in is not None else v.t) if inside else None
                if t_in is not None and v.t - t_in >= f.establish_hold_s - 1e-9:
                    self.t_established, t_end = v.t, v.t + f.duration_s
                elif v.t - self.t_handover > f.establish_s:
                    raise MissionError(f"orbit not established in {f.establish_s:.0f} s")
            yield
        self.t_orbit_end = v.t
        if self.authority.yielded is not None:
            self.phase, v.setpoint = "autopilot", None
            self.outcome, self.reason = "yielded", self.authority.yielded
            return
        if f.land:
            self.phase = "land"
            yield from recipe(v, prof.land_steps())
            yield from recipe(v, prof.end_steps())
            self.end_mode = prof.end_mode.name if prof.end_mode else ""
        self.outcome = "completed"

    def _trim_radius(self, v: VehicleLink) -> None:
        """Until established, once per revolution (2πR / V of the plan): the mean distance to
        the orbit centre flown in AI against R; off by more than radius_tol/2 · R, the loiter
        radius parameter is scaled by R / mean (PARAM_SET, at most `radius_trims` times; the
        guard sees the echo). An autopilot's loiter about a moving centre runs wide of its set
        radius (measured on ArduPlane: 108 m for 93 m × EAS2TAS² = 99 m)."""
        p = v.tel.pos_ned
        if (p is None or not v.profile.loiter_radius_trim or self.net.mode.value != "ai"
                or self.trims >= self.f.radius_trims):  # fmt: skip
            self._trim_d = []
            return
        if not self._trim_d:
            self._trim_t = v.t
        self._trim_d.append(float(np.hypot(*(p[:2] - self.centre))))
        R = self.plan.radius_m
        if v.t - self._trim_t < 2 * math.pi * R / self._airspeed:
            return
        mean = float(np.mean(self._trim_d))
        self._trim_d = []
        if abs(mean - R) <= 0.5 * self.f.radius_tol * R:
            return
        prof = v.profile
        value = prof.param_value("loiter_radius", self.loiter_setting * R / mean)
        if value == self.loiter_setting:
            return
        self.trims += 1
        self.loiter_setting = value
        self.trim_log.append((round(v.t, 3), round(mean, 2), value))
        if self.net.events is not None:
            self.net.events.write({"t": round(v.t, 6), "event": "loiter_radius_trim",
                                   "vehicle": self.rec.vehicle, "mean_distance_m": round(mean, 2),
                                   "radius_m": round(R, 2), "set": value})  # fmt: skip
        name = prof.param_name("loiter_radius")
        v.send(M.MAVLink_param_set_message(v.target_system or 1, 1, name.encode("ascii"),
                                           float(value), M.MAV_PARAM_TYPE_REAL32))  # fmt: skip

    def _begin_orbit(self, v: VehicleLink) -> None:
        """The hand-over is done: the net has the vehicle. Its first decision must carry the
        orbit's setpoint — the climb-out aimed moments ago, and a decision without an action
        is judged as "no velocity command" (ArduPlane is in GUIDED already: the hand-over can
        take less than one decision period)."""
        self.net.handover(v.t, v.tel.mode, v.profile.ai_mode)
        self.t_decision = None
        self.phase = "orbit"

    def _plan(self, v: VehicleLink) -> OrbitPlan:
        prof = v.profile
        try:
            V = prof.param_to_si("airspeed_trim", v.params[prof.param_name("airspeed_trim")])
            self._airspeed = V
            bank = prof.param_to_si("bank_limit", v.params[prof.param_name("bank_limit")])
        except (KeyError, ValueError) as e:
            raise MissionError(f"cannot plan the orbit: the autopilot's {e} was not read") from None
        b = self.brief
        spec = self.net.envelope.spec  # the autopilot's hold circle may be at most R(v_max) (C4)
        r_max = spec.dynamics.turn_radius(spec.limits.speed_h_mps)
        try:
            return plan_orbit(OrbitParams(airspeed_mps=V, bank_max_rad=bank, team_speed_mps=b.team_speed_mps,
                                          team_radius_m=b.team_radius_m, n_ugvs=b.n_ugvs,
                                          alt_min_m=self.alt_band[0], alt_max_m=self.alt_band[1],
                                          radius_max_m=r_max))  # fmt: skip
        except ValueError as e:
            raise MissionError(f"refusing to fly the orbit: {e}") from None

    def _agree(self, v: VehicleLink) -> Phase:
        """The autopilot's parameters against the envelope (safety.consistency): those a
        companion may set are set to agree (a fixed-wing's climb and sink limits), then any
        mismatch left refuses the take-off with the rule's reason. Before the plan, which reads
        the bank limit as set; the loiter radius the plan sets is checked by the guard as its
        echo arrives (the climb-out waits for a consistent guard)."""
        self.phase = "parameters"
        self.guard.load(v.t, v.params)
        v.param_updates.clear()  # the list just read, and the loiter radius's echo
        for name, value in agreeing_values(self.guard.spec, self.guard.params).items():
            yield from set_param_checked(v, name, value)
        self._read_param_updates(v)
        ok, why = self.guard.handover()
        if not ok:
            raise MissionError(
                f"refusing to take off: the autopilot's parameters disagree with the envelope: {why}"
            )

    def _read_param_updates(self, v: VehicleLink) -> None:
        """Anyone's PARAM_SET seen since the last tick (PARAM_VALUE) → the guard."""
        for t_p, name, value in v.param_updates:
            self.guard.update(t_p, name, value)
        v.param_updates.clear()

    # ---- the climb-out -------------------------------------------------------------------------
    def _climb_out(self, v: VehicleLink) -> Phase:
        """The autopilot's own loiter to the orbit (DO_REPOSITION), until the net certifies the
        orbit's setpoint at the present state for `climb_hold_s` (no supervisor state changed)."""
        f = self.f
        sent, since, t0 = -math.inf, None, v.t
        while True:
            self._aim(v)
            if v.t - sent >= f.reposition_s:
                target = np.array([self.centre[0], self.centre[1], -self.plan.altitude_m])
                v.send(
                    reposition_command(
                        v.tel, v.profile, v.target_system or 1, target, change_mode=True
                    )
                )  # ArduPlane: GUIDED from TAKEOFF
                sent = v.t
            self._read_param_updates(v)
            vs = v.tel.vehicle_state()
            ok = vs is not None and not self.guard.problems and self._certified_now(vs)
            since = (since if since is not None else v.t) if ok else None
            if since is not None and v.t - since >= f.climb_hold_s - 1e-9:
                return
            if v.t - t0 > f.climb_timeout_s:
                raise MissionError(
                    f"climb-out: the orbit was not certified within {f.climb_timeout_s:.0f} s"
                )
            yield

    # ---- per tick ------------------------------------------------------------------------------
    def _proposal(self) -> Setpoint:
        """The position setpoint the autopilot loiters about with radius R (its NAV_LOITER_RAD):
        the orbit centre at the orbit altitude. The net certifies the turn it implies."""
        return Setpoint(pos_ned=np.array([self.centre[0], self.centre[1], -self.plan.altitude_m]))

    def _ok(self, c: np.ndarray) -> bool:
        return circle_certified(self.net.supervisor.geometry, c, self.plan.radius_m, self.plan.altitude_m,
                                self.reserve_m, self.net.envelope.spec.limits.margin_m)  # fmt: skip

    def _certified_now(self, state) -> bool:
        return self._ok(self.centre) and setpoint_certified(
            self.net.supervisor, state, self._proposal()
        )

    def _move_centre(self) -> None:
        """Toward the team's centre as seen, as far as the fence allows (hil.orbit.slide_centre)."""
        self.centre, held = slide_centre(self._ok, self.centre, self.sight.centre)
        self.limited += held

    def _aim(self, v: VehicleLink) -> bool:
        """Every decision period: point the camera at the team's centre as seen
        (DO_SET_ROI_LOCATION at ground level, addressed to the vehicle's gimbal component,
        MAV_COMP_ID_GIMBAL: world/follow.py plays it beside a real autopilot, whose routing
        forwards the command) and move the orbit centre. True if it did."""
        if self.t_decision is not None and v.t - self.t_decision < self.f.decision_s - 1e-9:
            return False
        self.t_decision = v.t
        v.point_gimbal(np.array([*self.sight.centre, 0.0]))  # the autopilot routes it there
        self._move_centre()
        return True

    def _tick(self, v: VehicleLink) -> None:
        state = v.tel.vehicle_state()
        if state is None:
            return
        proposal = self._proposal() if self._aim(v) else None
        v.feed(self.net)  # link, anyone's PARAM_SET mid-flight (re-checked), wind
        d = self.net.step(v.t, state, proposal)
        mode = self.net.wanted_mode(d)
        self.authority.want(v, mode)
        v.setpoint = (
            d.command if d.command.pos_ned is not None or d.command.vel_ned is not None else None
        )
        if proposal is not None:
            row = d.record(vehicle=self.rec.vehicle, pilot="orbit", autopilot_mode=mode)
            row["centre_seen"] = [round(float(x), 3) for x in self.sight.centre]
            self.rec.decision(row)

    def _inside(self, v: VehicleLink) -> bool:
        p = v.tel.pos_ned
        if p is None or self.net.mode.value != "ai":
            return False
        d = float(np.hypot(*(p[:2] - self.centre)))
        return (abs(d - self.plan.radius_m) <= self.f.radius_tol * self.plan.radius_m
                and abs(-p[2] - self.plan.altitude_m) <= self.f.alt_tol_m)  # fmt: skip


def briefing_for(scenario: str, seed: int, duration_s: float, establish_s: float) -> Briefing:
    """The team's briefing from its scenario (policy.groundair.scenarios): where it starts,
    its speed, and the widest it gets over the flight."""
    from skyherd.task.scenarios import Formation, draw_plan

    team = Formation(draw_plan(scenario, np.random.default_rng(seed), 3))
    p = team.plan
    r = min(p.r0 + p.r_amp + abs(p.r_rate) * (duration_s + establish_s), p.r_max)
    c = np.mean(np.array(team.positions(), float), axis=0)
    return Briefing((float(c[0]), float(c[1])), float(p.speed), float(r), len(p.angles))
