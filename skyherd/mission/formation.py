"""The formation mission: K quadrotors fly a learned lock-step grid plan to their targets, each
behind its own safety net, in one companion ticking in lockstep with K vehicle processes.

Each vehicle is its own `skyherd sim --ugvs none` (its home on its start cell); the companion
holds one `VehicleLink` per vehicle and ticks when every vehicle has marked the same instant
(mission.companion.run_fleet), so the K simulations run in parallel between ticks and a flight
is the same at any speed-up and load.

Phases, for all vehicles together (`together`): connect → take off to distinct altitudes
(FormationParams.altitude(k)) → OFFBOARD hold above the start cell → the plan in time (one plan
step per cell_m / speed_mps, `formation_plan.reference`) → hold over the targets for settle_s →
land → disarmed. At every tick every vehicle's plan setpoint goes through its `FormationNet`
(field frame): the formation fence, the envelope's dynamics, and the other vehicles' positions
and velocities as separation rows (safety.separation). The net's fallback is flown in OFFBOARD
(its brake, then a position hold), not the autopilot's HOLD: the other vehicles' nets keep their
distance from a holding vehicle. A vehicle whose autopilot takes over (a mode the companion did
not ask for) is left to it (mission.authority); the others fly on around it.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Iterable

import numpy as np

from skyherd.flight.autopilot_api import Setpoint
from skyherd.flight.geo import GRAVITY
from skyherd.flight.state import VehicleState
from skyherd.mission.authority import ModeAuthority
from skyherd.mission.formation_plan import (
    FORMATION_NET,
    LEASH_M,
    LEASH_V_M,
    SEPARATION,
    FormationParams,
    formation_envelope,
    reference,
)
from skyherd.mission.steps import MissionError, Phase, quiet_streams, recipe, wait_ready, wait_until
from skyherd.mission.vehicle import VehicleLink
from skyherd.runio import CsvWriter, JsonlWriter
from skyherd.safety.envelope import EnvelopeSpec
from skyherd.safety.net import SafetyNet, warm_up
from skyherd.safety.separation import SeparationParams, fleet_separation_rows, separation_rows
from skyherd.safety.supervisor import Decision, Supervisor


def together(phases: Iterable[Phase]) -> Phase:
    """Step several vehicles' phases once per tick until every one has finished; the first
    failure ends them all (MissionError, naming the vehicle)."""
    running = dict(enumerate(phases))
    while running:
        for k in list(running):
            try:
                next(running[k])
            except StopIteration:
                del running[k]
            except MissionError as e:
                raise MissionError(f"vehicle {k}: {e}") from None
        if running:
            yield


class FormationNet:
    """One vehicle's safety net in the field frame: its SafetyNet over the formation's envelope,
    with the other vehicles as separation rows. Its fallback is flown as a setpoint in OFFBOARD
    (use_autopilot_hold False): K vehicles each waiting out a mode switch beside the others
    would hold worse than the fallback's own brake."""

    def __init__(self, index: int, spec: EnvelopeSpec, events=None,
                 separation: SeparationParams = SEPARATION):  # fmt: skip
        self.index = index
        self.spec = spec
        self.net = SafetyNet(Supervisor(spec.envelope(), FORMATION_NET, events), events,
                             vehicle=f"uav{index}", camera=False, use_autopilot_hold=False)  # fmt: skip
        self.separation = separation
        # _chase's bounds: 90 % of the inradius of the envelope's n-gon speed and accel rows
        lim = spec.limits
        cosk = math.cos(math.pi / lim.speed_sides)
        a_h = min(lim.accel_h_mps2, GRAVITY * math.tan(lim.tilt_cmd_rad))
        self.du_max = 0.9 * a_h * spec.dynamics.tau_s * cosk  # |u − v| [m/s]
        self.u_max = 0.9 * lim.speed_h_mps * cosk  # |u| [m/s]

    def rows_against(self, state: VehicleState, others) -> tuple:
        """The separation rows (A, b, names) against `others` = [(name, position (3,), velocity
        (3,))]; a fleet's are made all at once by safety.separation.fleet_separation_rows."""
        return separation_rows(self.spec, state.pos_ned, others, self.separation)

    def certify(self, t: float, state: VehicleState, separation: tuple, target: np.ndarray,
                vel_ff: np.ndarray | None) -> Decision:  # fmt: skip
        """The plan's point `target` (3,) with feed-forward `vel_ff` through the net, all in the
        field frame; `separation` = the rows (A, b, names) against the other vehicles. A
        reference far ahead is chased on a leash (`_chase`, LEASH_V_M) so the setpoint stays
        inside the speed and acceleration rows."""
        self.net.supervisor.set_dynamic_rows(*separation)
        p0, p1, p2 = state.pos_ned.tolist()
        v0, v1, _ = state.vel_ned.tolist()
        t0, t1, t2 = np.asarray(target, float).tolist()
        f0, f1, f2 = (0.0, 0.0, 0.0) if vel_ff is None else np.asarray(vel_ff, float).tolist()
        (f0, f1), (d0, d1) = self._chase((p0, p1), (v0, v1), (t0, t1), (f0, f1))
        dz = min(max(t2 - p2, -LEASH_V_M), LEASH_V_M)  # np.clip's value, NaN included
        sp = Setpoint(pos_ned=np.array([p0 + d0, p1 + d1, p2 + dz]),
                      vel_ned=np.array([f0, f1, f2]), yaw=0.0)  # fmt: skip
        return self.net.step(t, state, sp)

    def _chase(self, p: tuple[float, float], v: tuple[float, float], target: tuple[float, float],
               ff: tuple[float, float]) -> tuple[tuple[float, float], tuple[float, float]]:  # fmt: skip
        """The horizontal part of the setpoint, from the position p, velocity v, reference
        `target` and its feed-forward ff (north, east): (feed-forward, offset d from p) such
        that the velocity the autopilot flies, u = ff + K d (SupervisorParams.pos_gain_xy), is
        inside the envelope's speed and acceleration rows with 10 % to spare:

            |u| ≤ 0.9 V cos(π/n),   |u − v| ≤ 0.9 a τ cos(π/n)     (the n-gon rows' inradius)

        d points at the plan's reference, as far as those allow (at most LEASH_M): a vehicle
        behind its reference (after a fallback) speeds up along the accel limit instead of
        proposing a jump the net refuses for ever. Plain floats, except numpy's hypot and dot:
        math.hypot and a·b + c·d on floats differ from them in the last bit."""
        du_max, u_max = self.du_max, self.u_max  # (__init__)
        (p0, p1), (v0, v1), (t0, t1), (f0, f1) = p, v, target, ff
        dv0, dv1 = f0 - v0, f1 - v1
        h = float(np.hypot(dv0, dv1))
        if h > du_max:  # the plan's own speed change is too abrupt
            s = du_max / h
            f0, f1 = v0 + dv0 * s, v1 + dv1 * s
        e0, e1 = t0 - p0, t1 - p1
        dist = float(np.hypot(e0, e1))
        if dist < 1e-9:
            return (f0, f1), (0.0, 0.0)
        n = np.array([e0 / dist, e1 / dist])
        k = self.net.p.pos_gain_xy
        reach = min(dist, LEASH_M)
        for w, r in ((np.array([f0 - v0, f1 - v1]), du_max), (np.array([f0, f1]), u_max)):
            # |w + k x n| ≤ r ⇔ x ≤ (−w·n + √D) / k
            wn = float(w.dot(n))
            disc = wn * wn - float(w.dot(w)) + r * r
            reach = min(reach, max(0.0, (-wn + math.sqrt(disc)) / k) if disc > 0 else 0.0)
        n0, n1 = n.tolist()
        return (f0, f1), (n0 * reach, n1 * reach)


@dataclasses.dataclass
class Tagged:
    """An event sink that adds the vehicle's name to every event (one events.jsonl for K)."""

    sink: object
    vehicle: str

    def write(self, row: dict) -> None:
        self.sink.write({**row, "vehicle": self.vehicle})


@dataclasses.dataclass
class FleetRecord:
    """What the formation companion writes (each writer appends and flushes). A tick's
    decisions are held until `flush()`, which the companion calls after the tick's close."""

    decisions: JsonlWriter | None = None
    track: CsvWriter | None = None
    rows: int = 0  # decisions recorded
    _held: list[dict] = dataclasses.field(default_factory=list, repr=False)

    def decision(self, row: dict) -> None:
        self.rows += 1
        if self.decisions is not None:
            self._held.append(row)

    def flush(self) -> None:
        held, self._held = self._held, []
        if held:
            self.decisions.write_many(held)


class FormationMission:
    """K vehicles: connect → take off → hand over → the plan → settle → land."""

    name = "formation"

    def __init__(self, paths_ne: np.ndarray, offsets_ne: list[np.ndarray], params: FormationParams,
                 record: FleetRecord, events=None):  # fmt: skip
        self.paths = np.asarray(paths_ne, float)  # (K, T+1, 2) field frame [m]
        self.off = [np.array([o[0], o[1], 0.0]) for o in offsets_ne]  # home in the field [m]
        self.p = params
        self.rec = record
        self.K = len(self.paths)
        self.spec = formation_envelope(list(self.paths), params)
        self.nets = [FormationNet(k, self.spec, Tagged(events, f"uav{k}") if events else None)
                     for k in range(self.K)]  # fmt: skip
        self._warm_up()
        self.authority = [ModeAuthority(n.net.authority) for n in self.nets]
        self.phase = "connect"
        self.outcome, self.reason = "running", ""
        self.t0: float | None = None  # plan start [s]
        self.times = dict.fromkeys(("takeoff", "plan_start", "plan_end", "all_over_targets",
                                    "all_disarmed"), math.nan)  # fmt: skip
        self.yielded: dict[int, str] = {}
        self.perception = None
        self._written: list[int] = [0] * self.K

    def _warm_up(self) -> None:
        """Compile the net's kernels before the clock starts, separation rows included (their
        shapes are new signatures: compiled at the first tick, 2 s of CPU inside the flight)."""
        warm_up(self.nets[0].net.envelope, FORMATION_NET)
        net = FormationNet(0, self.spec)
        for k, north in enumerate((0.0, 1e4)):  # inside, then far outside: AI and FALLBACK
            st = VehicleState(t=float(k), pos_ned=np.array([north, 0.0, -8.0]), vel_ned=np.zeros(3),
                              quat=np.array([1.0, 0, 0, 0]), omega_frd=np.zeros(3),
                              accel_frd=np.zeros(3), on_ground=False)  # fmt: skip
            rows = net.rows_against(st, [("uav1", np.array([north, 5.0, -9.5]), np.zeros(3))])
            net.certify(float(k), st, rows, st.pos_ned, np.zeros(3))

    # ---- called by the companion's loop --------------------------------------------------------
    def on_frame(self, t: float, frame, status: str) -> None:
        pass  # no camera

    def write_track(self, vs: list[VehicleLink]) -> None:
        """Append the position samples that arrived this tick to metrics.csv (field frame)."""
        rows = []
        for k, v in enumerate(vs):
            for t, p, vel, mode, armed in v.positions[self._written[k] :]:
                ref = self._ref(k, t)[0] if self.t0 is not None else None
                rows.append({
                    "t": t, "vehicle": k, "north": p[0] + self.off[k][0],
                    "east": p[1] + self.off[k][1], "down": p[2], "vn": vel[0], "ve": vel[1],
                    "vd": vel[2], "ref_north": "" if ref is None else ref[0],
                    "ref_east": "" if ref is None else ref[1], "mode": mode,
                    "armed": int(armed), "phase": self.phase})  # fmt: skip
            self._written[k] = len(v.positions)
        if rows and self.rec.track is not None:
            self.rec.track.write_rows(rows)
        self.rec.flush()

    # ---- the mission ---------------------------------------------------------------------------
    def run(self, vs: list[VehicleLink]) -> Phase:
        p = self.p
        if len(vs) != self.K:
            raise MissionError(f"{len(vs)} vehicle links for a plan of {self.K} vehicles")
        yield from together(wait_ready(v) for v in vs)
        for v in vs:
            quiet_streams(v)
        self.phase = "takeoff"
        self.times["takeoff"] = vs[0].t
        yield from together(recipe(v, v.profile.takeoff_steps(p.altitude(k), v.home_amsl_m))
                            for k, v in enumerate(vs))  # fmt: skip
        self.phase = "offboard"
        yield from together(recipe(v, v.profile.handover_steps(),
                                   hold=lambda k=k: self._local(k, self._start_point(k)))
                            for k, v in enumerate(vs))  # fmt: skip
        for k, v in enumerate(vs):
            self.nets[k].net.handover(v.t, v.tel.mode, v.profile.ai_mode)
        self.phase = "plan"
        self.t0 = vs[0].t + p.lead_s
        t_end = self.t0 + (self.paths.shape[1] - 1) * p.step_s
        self.times["plan_start"], self.times["plan_end"] = self.t0, t_end
        while vs[0].t < t_end - 1e-9:
            self._fly(vs)
            yield
        self.phase = "settle"
        since: float | None = None
        while True:
            self._fly(vs)
            ok = all(k in self.yielded or self._over_target(k, v) for k, v in enumerate(vs))
            since = (since if since is not None else vs[0].t) if ok else None
            if since is not None and vs[0].t - since >= p.settle_s - 1e-9:
                break
            if vs[0].t - t_end > p.settle_timeout_s:
                raise MissionError(f"not every vehicle over its target {p.settle_timeout_s:.0f} s "
                                   "after the plan's end")  # fmt: skip
            yield
        self.times["all_over_targets"] = vs[0].t
        self.phase = "land"
        flying = [(k, v) for k, v in enumerate(vs) if k not in self.yielded]
        yield from together(self._land(v) for _, v in flying)
        yield from together(wait_until(v, lambda v=v: not v.tel.armed, 120.0, "its landing")
                            for k, v in enumerate(vs) if k in self.yielded)  # fmt: skip
        self.times["all_disarmed"] = vs[0].t
        if self.yielded:
            self.outcome = "yielded"
            self.reason = "; ".join(f"uav{k}: {why}" for k, why in sorted(self.yielded.items()))
        else:
            self.outcome = "completed"

    def _land(self, v: VehicleLink) -> Phase:
        v.setpoint = Setpoint(pos_ned=v.tel.pos_ned.copy(), yaw=0.0)
        yield from recipe(v, v.profile.land_steps())
        yield from recipe(v, v.profile.end_steps())

    # ---- per tick ------------------------------------------------------------------------------
    def _start_point(self, k: int) -> np.ndarray:
        return np.array([*self.paths[k, 0], -self.p.altitude(k)])

    def _local(self, k: int, field: np.ndarray) -> Setpoint:
        return Setpoint(pos_ned=field - self.off[k], yaw=0.0)

    def _ref(self, k: int, t: float) -> tuple[np.ndarray, np.ndarray]:
        return reference(self.paths[k], t - self.t0, self.p.step_s)

    def field_state(self, k: int, v: VehicleLink) -> VehicleState | None:
        s = v.tel.vehicle_state()
        if s is None:
            return None
        return VehicleState(s.t, s.pos_ned + self.off[k], s.vel_ned, s.quat, s.omega_frd,
                            s.accel_frd, s.on_ground)  # fmt: skip

    def _over_target(self, k: int, v: VehicleLink) -> bool:
        s = self.field_state(k, v)
        goal = np.array([*self.paths[k, -1], -self.p.altitude(k)])
        return s is not None and float(np.linalg.norm(s.pos_ned - goal)) < self.p.accept_radius_m

    def _fly(self, vs: list[VehicleLink]) -> None:
        states = [self.field_state(k, v) for k, v in enumerate(vs)]
        seen = [k for k, s in enumerate(states) if s is not None]  # yielded ones too: they fly
        rows = dict(zip(seen, fleet_separation_rows(
            self.spec, [states[k].pos_ned for k in seen], [states[k].vel_ned for k in seen],
            [f"uav{k}" for k in seen], self.nets[0].separation)))  # fmt: skip
        for k, v in enumerate(vs):
            if k in self.yielded:
                continue
            rule = self.authority[k].update(v)
            if rule != "fly":  # its autopilot has it: no more setpoints, no more requests
                self.yielded[k] = self.authority[k].yielded or f"autopilot in {v.tel.mode_name}"
                v.setpoint = None
                continue
            if states[k] is None:
                continue
            ref, vel = self._ref(k, v.t)
            target = np.array([ref[0], ref[1], -self.p.altitude(k)])
            net = self.nets[k]
            v.feed(net.net)
            d = net.certify(v.t, states[k], rows[k], target, np.array([vel[0], vel[1], 0.0]))
            self.authority[k].want(v, net.net.wanted_mode(d))
            c = d.command
            pos = None if c.pos_ned is None else np.asarray(c.pos_ned, float) - self.off[k]
            v.setpoint = Setpoint(pos_ned=pos, vel_ned=c.vel_ned, yaw=c.yaw)
            self.rec.decision(d.record(vehicle=f"uav{k}", pilot="formation",
                                       autopilot_mode=v.tel.mode or "unknown"))  # fmt: skip

    # ---- what the report needs -----------------------------------------------------------------
    def net_counts(self) -> dict:
        st = [n.net.stats for n in self.nets]
        return {"switches": sum(s.switches for s in st), "rejected": sum(s.rejected for s in st),
                "projected": sum(s.projected for s in st),
                "fallback_s": sum(s.fallback_s for s in st)}  # fmt: skip
