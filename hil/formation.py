"""Fly a learned grid formation with K quadrotors, each through its own MAVLink client.

Frames (all NED, metres). The *field frame* is local NED about the field origin (a geodetic
`Home`, the project's default home unless told otherwise). Grid cell (x, y), 1-based as in
`policy/sql`, has its centre at

    north = (y − 1) · cell_m,    east = (x − 1) · cell_m,

so cell (1, 1) sits on the field origin, x grows east and y grows north. Vehicle k's own home
is the centre of its start cell (a geodetic point from `flight.geo.ned_to_geodetic`), so it
starts ON that cell and, like PX4, reports positions about its own home; its client adds the
home's field-frame offset to every position it receives and subtracts it from every setpoint.

Simulation: `LockstepSwarm` steps K built-in vehicles (instances N0 .. N0+K−1, each with its
own SimClock advanced by the same control period, so every `time_boot_ms` agrees) from one
thread, then waits once on one `Pacer`. Clients: `FormationFlight` runs one `VehicleClient`
(receive + heartbeat threads) per vehicle over real loopback UDP sockets and orchestrates the
shared phases from the calling thread: connect, arm, take off to distinct altitudes
(`base_altitude_m + altitude_step_m · k`), OFFBOARD hold above the start cell, the lock-step
plan in time (one plan step per cell_m / speed_mps of simulation time, linear between cell centres with
velocity feed-forward), hold over the target cell, LAND, disarm.
"""

from __future__ import annotations

import dataclasses
import json
import math
import threading
import time
import traceback
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from tqdm import tqdm

from flight.airframes_registry import make_autopilot
from flight.autopilot_api import FlightMode, Setpoint
from flight.clock import Pacer, SimClock
from flight.geo import Home, geodetic_to_ned, ned_to_geodetic
from flight.mavlink import EndpointConfig
from flight.mavlink.tlog import TlogWriter
from flight.sitl import Sitl
from hil.client import ClientTimeout, Telemetry, VehicleClient
from hil.link import MavlinkLink
from runio.runfolder import CsvWriter
from safety.config import default_envelope_path, load_envelope
from safety.envelope import EnvelopeSpec, Zone
from safety.separation import SeparationParams, separation_rows
from safety.supervisor import Health, Supervisor, SupervisorParams

Cell = tuple[int, int]

TRACK_COLUMNS = ["t", "vehicle", "north", "east", "down", "vn", "ve", "vd", "ref_north",
                 "ref_east", "mode", "armed", "phase"]  # fmt: skip


PACER_MAX_LAG_S = 0.02
"""Wall time [s] the simulation may fall behind before the pacer re-anchors instead of
catching up (a burst would starve the clients' setpoint streams)."""


class PlanError(ValueError):
    """A formation plan is malformed (the message says what is wrong)."""


@dataclass(frozen=True)
class FormationParams:
    """How the grid plan is flown (saved in config.json)."""

    cell_m: float = 2.0
    """Grid cell size [m] (one cell = one plan move)."""
    speed_mps: float = 2.0
    """Cruise speed along a straight plan leg [m/s]: one plan step takes cell_m / speed_mps."""
    base_altitude_m: float = 8.0
    """Cruise altitude of vehicle 0 above its home [m]."""
    altitude_step_m: float = 1.5
    """Extra cruise altitude per vehicle index [m] (vertical separation)."""
    lead_s: float = 2.0
    """Simulation time between the OFFBOARD hand-over and the plan's first step [s]."""
    accept_radius_m: float = 0.3
    """A vehicle is over its target within this 3-D distance [m] ..."""
    settle_s: float = 1.0
    """... held for this long [s] of simulation time, before the landing starts."""
    similar_alt_m: float = 1.0
    """Two vehicles are 'at similar altitude' when their altitudes differ by less [m]."""

    def __post_init__(self) -> None:
        checks = {
            "cell_m in [1, 20]": 1.0 <= self.cell_m <= 20.0,
            "speed_mps in [0.5, 8]": 0.5 <= self.speed_mps <= 8.0,
            "base_altitude_m in [3, 60]": 3.0 <= self.base_altitude_m <= 60.0,
            "altitude_step_m in [0.5, 10]": 0.5 <= self.altitude_step_m <= 10.0,
            "lead_s >= 0": self.lead_s >= 0.0,
            "accept_radius_m > 0": self.accept_radius_m > 0.0,
            "settle_s >= 0": self.settle_s >= 0.0,
            "similar_alt_m > 0": self.similar_alt_m > 0.0,
        }  # every comparison is False for NaN
        bad = [k for k, ok in checks.items() if not ok]
        if bad:
            raise ValueError(f"bad formation parameters: {', '.join(bad)}")

    def altitude(self, k: int) -> float:
        """Cruise altitude of vehicle index k above home [m]."""
        return self.base_altitude_m + self.altitude_step_m * k

    @property
    def step_s(self) -> float:
        """Simulation time per lock-step plan step [s]."""
        return self.cell_m / self.speed_mps


# ---- the plan on the ground ---------------------------------------------------------------


def cell_ne(cell: Cell, cell_m: float) -> np.ndarray:
    """Field-frame (north, east) [m] of a 1-based grid cell's centre, shape (2,)."""
    x, y = cell
    return np.array([(y - 1) * cell_m, (x - 1) * cell_m], dtype=float)


def plan_ne(paths: list[list[Cell]], cell_m: float) -> np.ndarray:
    """Lock-step paths → field-frame waypoints, shape (K, T+1, 2) [m] (north, east)."""
    a = np.array(paths, dtype=float)  # (K, T+1, 2) as (x, y)
    return np.stack([(a[..., 1] - 1) * cell_m, (a[..., 0] - 1) * cell_m], axis=-1)


def reference(path: np.ndarray, t_rel: float, step_s: float) -> tuple[np.ndarray, np.ndarray]:
    """Where one vehicle should be at `t_rel` [s] after the plan starts.

    path: (T+1, 2) field-frame waypoints [m]; waypoint i is due at t_rel = i · step_s and the
    reference moves linearly between them. Returns position (2,) [m] and velocity (2,) [m/s];
    before the start it is the first waypoint, after the end the last, both at rest.
    """
    n = path.shape[0] - 1
    if n < 1 or t_rel <= 0.0:
        return path[0].copy(), np.zeros(2)
    s = t_rel / step_s
    if s >= n:
        return path[-1].copy(), np.zeros(2)
    i = int(s)
    f = s - i
    d = path[i + 1] - path[i]
    return path[i] + f * d, d / step_s


def plan_moves(paths: list[list[Cell]]) -> list[int]:
    """Number of cell changes per agent (waits not counted)."""
    return [sum(a != b for a, b in zip(p, p[1:])) for p in paths]


def validate_plan(paths, n_agents: int, size: int) -> list[list[Cell]]:
    """Check a lock-step plan: K lists of the same length ≥ 2, 1-based cells on the M×M grid,
    each move to a 4-neighbour or a wait, distinct cells at every step. Returns it as tuples."""
    if not isinstance(paths, list) or len(paths) != n_agents:
        got = len(paths) if isinstance(paths, list) else type(paths).__name__
        raise PlanError(f"plan must hold {n_agents} paths (one per agent), got {got}")
    out: list[list[Cell]] = []
    for k, p in enumerate(paths):
        if not isinstance(p, list) or len(p) < 2:
            raise PlanError(f"path {k} must be a list of at least 2 cells")
        row = []
        for c in p:
            if (
                not isinstance(c, list | tuple)
                or len(c) != 2
                or not all(isinstance(v, int) and not isinstance(v, bool) for v in c)
            ):
                raise PlanError(f"path {k}: a cell must be [x, y] integers, got {c!r}")
            if not (1 <= c[0] <= size and 1 <= c[1] <= size):
                raise PlanError(f"path {k}: cell {tuple(c)} is off the {size}×{size} grid")
            row.append((int(c[0]), int(c[1])))
        out.append(row)
    if len({len(p) for p in out}) != 1:
        raise PlanError("all paths must have the same length (one cell per global step)")
    for k, p in enumerate(out):
        for t, (a, b) in enumerate(zip(p, p[1:])):
            if abs(a[0] - b[0]) + abs(a[1] - b[1]) > 1:
                raise PlanError(f"path {k} jumps from {a} to {b} at step {t + 1}")
    for t in range(len(out[0])):
        cells = [p[t] for p in out]
        if len(set(cells)) != len(cells):
            raise PlanError(f"two agents share a cell at step {t}")
    return out


def load_plan(path: Path | str, n_agents: int, size: int = 50) -> list[list[Cell]]:
    """A plan saved by `skyherd train sql` (plan_K<K>.json); PlanError if unusable."""
    try:
        raw = json.loads(Path(path).read_text(encoding="utf-8"))
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as e:
        raise PlanError(f"cannot read plan {path}: {e}") from None
    return validate_plan(raw, n_agents, size)


def vehicle_homes(origin: Home, starts: list[Cell], cell_m: float) -> list[Home]:
    """Geodetic home of each vehicle: its start cell's centre, same altitude as the origin."""
    homes = []
    for c in starts:
        n, e = cell_ne(c, cell_m)
        lat, lon, alt = ned_to_geodetic(origin, np.array([n, e, 0.0]))
        homes.append(Home(lat, lon, alt, origin.heading_rad))
    return homes


# ---- the safety net of the formation -------------------------------------------------------

FORMATION_NET = SupervisorParams(hysteresis_s=1.0, hold_min_s=0.5, deadline_s=0.5,
                                 recover_margin_m=1.0, recover_tol_m=0.5)  # fmt: skip
"""Supervisor settings of each formation vehicle (setpoints come with every telemetry sample).
The recovery keeps only 1 m from the rows: with the field set's 6 m, every vehicle's target
was the floor + 6 m = 11 m, two vehicles met there and their separation rows held both."""

SEPARATION = SeparationParams(radius_m=1.0)
"""Stopping points of two formation vehicles keep 1 m (cells 2 m apart, altitudes 1.5 m)."""

FORMATION_ACCEL_MPS2 = 8.0
"""Horizontal acceleration a formation setpoint may demand [m/s²] (g tan 40° = 8.2 m/s²)."""
FORMATION_TILT_RAD = 0.70
"""Tilt a formation setpoint may demand [rad] (40°, inside the autopilot's MPC_TILTMAX_AIR 45°)."""

LEASH_M = 3.0
"""A vehicle behind its reference chases a point at most this far ahead [m]: the position
setpoint then implies at most 0.95·3 m/s + the feed-forward, inside the envelope's speed rows
(a reference 50 m ahead would imply the autopilot's 12 m/s and never be certified)."""

LEASH_V_M = 1.0
"""... and at most this far up or down [m]: MPC_Z_P 1/s × 1 m is a 1 m/s step, inside the
vertical accel row (3 m/s² × τ 0.5 s); after a recovery 3 m above its cruise altitude a 2 m/s
step was refused for ever."""

FENCE_PAD_M = 10.0
"""The formation's fence: the plan's bounding box, this much wider on every side [m]."""


def formation_envelope(paths_ne: list[np.ndarray], params: FormationParams,
                       base: Path | str | None = None) -> EnvelopeSpec:  # fmt: skip
    """The constraint set every formation vehicle flies in (field frame): the quadrotor field
    set's dynamics and limits, its fence replaced by the plan's bounding box + FENCE_PAD_M,
    no home radius (each vehicle has its own home) and no zones."""
    spec, _ = load_envelope(base if base is not None else default_envelope_path("quadrotor"))
    pts = np.concatenate([np.asarray(p, float).reshape(-1, 2) for p in paths_ne])
    lo, hi = pts.min(axis=0) - FENCE_PAD_M, pts.max(axis=0) + FENCE_PAD_M
    box = np.array([[lo[0], lo[1]], [hi[0], lo[1]], [hi[0], hi[1]], [lo[0], hi[1]]])
    top = params.altitude(len(paths_ne) - 1) + 10.0
    # the plan's corners turn a 2 m/s feed-forward by 90° within a step: |Δu| = 2.8 m/s, a
    # demand of 5.7 m/s² through τ = 0.5 s, which the autopilot's 45° tilt limit flies
    lim = dataclasses.replace(spec.limits, home_radius_m=0.0, accel_h_mps2=FORMATION_ACCEL_MPS2,
                              tilt_cmd_rad=FORMATION_TILT_RAD,
                              ceiling_m=max(spec.limits.ceiling_m, top))  # fmt: skip
    return dataclasses.replace(
        spec, name=f"{spec.name}-formation", version=f"{spec.version}+formation",
        limits=lim, inclusions=(Zone("formation field", box),), exclusions=(),
        source=f"{spec.source}: plan bounding box + {FENCE_PAD_M:g} m",
    )  # fmt: skip


# ---- K simulated vehicles on one thread ----------------------------------------------------


class LockstepSwarm:
    """K built-in quadrotors with their MAVLink endpoints, stepped in lockstep by one thread.

    Per iteration every vehicle steps one control period (its own SimClock, all advanced by
    the same amount), its endpoint answers and streams, then one Pacer wait keeps the common
    simulation time at `speedup` × wall time (or as fast as the machine goes, if slower).
    """

    def __init__(self, homes: list[Home], base_instance: int, speedup: float, seed: int = 0):
        self.sitls: list[Sitl] = []
        self.instances = [base_instance + k for k in range(len(homes))]
        self.error: str = ""
        self.wall_s = 0.0
        self.sim_s = 0.0
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        try:
            for inst, home in zip(self.instances, homes):
                ap = make_autopilot("quadrotor", clock=SimClock(), home=home, seed=seed,
                                    instance=inst)  # fmt: skip
                self.sitls.append(Sitl(ap, EndpointConfig(instance=inst), speedup=speedup))
        except BaseException:
            self.close()
            raise
        # a stalled wall clock is not caught up in a burst (the clients could not keep up)
        self.pacer = Pacer(speedup, max_lag_s=PACER_MAX_LAG_S)

    @property
    def t(self) -> float:
        """Common simulation time [s]."""
        return self.sitls[0].clock.t

    def start(self) -> LockstepSwarm:
        self._thread = threading.Thread(target=self._run, name="swarm-sim", daemon=True)
        self._thread.start()
        return self

    def _run(self) -> None:
        sim0, wall0 = self.t, time.monotonic()
        try:
            for s in self.sitls:
                s.endpoint.update()
            while not self._stop.is_set():
                for s in self.sitls:
                    s.step()
                self.pacer.wait_until(self.t)
                # let the clients' threads take the interpreter even when the simulation is
                # behind and the pacer never sleeps: their setpoints are due in simulation
                # time (COM_OF_LOSS_T), and Python's 5 ms switch interval × 2K threads is more
                time.sleep(0)
                self.sim_s, self.wall_s = self.t - sim0, time.monotonic() - wall0
        except Exception as e:  # report to the main thread instead of dying silently
            where = traceback.extract_tb(e.__traceback__)[-1]
            self.error = (f"simulation stopped at t={self.t:.2f} s: {type(e).__name__}: {e} "
                          f"({Path(where.filename).name}:{where.lineno})")  # fmt: skip

    @property
    def real_time_factor(self) -> float:
        return self.sim_s / self.wall_s if self.wall_s > 0 else math.nan

    def close(self) -> None:
        self._stop.set()
        if self._thread is not None:
            self._thread.join(timeout=10.0)
            self._thread = None
        for s in self.sitls:
            s.endpoint.close()


# ---- the clients ---------------------------------------------------------------------------


class TrackRecorder:
    """Thread-safe metrics.csv rows and per-vehicle tracks (t, north, east, down) in the field frame."""

    def __init__(self, metrics: CsvWriter | None, n: int):
        self.metrics = metrics
        self.tracks: list[list[tuple[float, float, float, float]]] = [[] for _ in range(n)]
        self._lock = threading.Lock()

    def write(self, k: int, row: dict) -> None:
        with self._lock:
            self.tracks[k].append((row["t"], row["north"], row["east"], row["down"]))
            if self.metrics is not None:
                self.metrics.write(row)

    def close(self) -> list[np.ndarray]:
        with self._lock:
            if self.metrics is not None:
                self.metrics.close()
            return [np.array(t) if t else np.zeros((0, 4)) for t in self.tracks]


class FormationVehicle:
    """One vehicle's client side: field-frame offset, cruise altitude, plan and setpoints."""

    def __init__(
        self,
        index: int,
        client: VehicleClient,
        offset_ne: np.ndarray,
        altitude: float,
        path_ne: np.ndarray,
        step_s: float,
        recorder: TrackRecorder,
    ):
        self.index = index
        self.client = client
        self.tel: Telemetry = client.telemetry
        self.offset_ne = np.asarray(offset_ne, dtype=float)
        self.altitude = float(altitude)
        self.path_ne = path_ne
        self.step_s = step_s
        self.recorder = recorder
        self.phase = "connect"
        self.hold_ne: np.ndarray | None = None  # field-frame hold point while in OFFBOARD
        self.t0: float | None = None  # plan start [s, vehicle time]
        self.error = ""
        self.net: Supervisor | None = None
        self.others: list[FormationVehicle] = []
        self.separation = SeparationParams()
        self.events = self.decisions = None
        self.last_decision = None
        client.stream_offboard(self._setpoint)

    @property
    def t(self) -> float:
        """Vehicle (simulation) time of the newest position sample [s]."""
        return self.tel.time_boot_ms / 1000.0

    def pos_field(self) -> np.ndarray | None:
        p = self.tel.pos_ned
        return (
            None
            if p is None
            else np.array([p[0] + self.offset_ne[0], p[1] + self.offset_ne[1], p[2]])
        )

    @property
    def target_ne(self) -> np.ndarray:
        return self.path_ne[-1]

    def _setpoint(self, tel: Telemetry):
        """Called on every LOCAL_POSITION_NED (receive thread): record, then the setpoint.
        An error is kept for the flight to report (the receive thread must not die)."""
        try:
            return self._setpoint_unguarded(tel)
        except Exception as e:  # noqa: BLE001
            self.error = self.error or f"vehicle {self.index} setpoint: {type(e).__name__}: {e}"
            return None

    def _setpoint_unguarded(self, tel: Telemetry):
        t = tel.time_boot_ms / 1000.0
        ref_ne = vel_ne = None
        if self.t0 is not None:
            ref_ne, vel_ne = reference(self.path_ne, t - self.t0, self.step_s)
        elif self.hold_ne is not None:
            ref_ne, vel_ne = self.hold_ne, None
        p, v = tel.pos_ned, tel.vel_ned
        self.recorder.write(self.index, {
            "t": t, "vehicle": self.index, "north": p[0] + self.offset_ne[0],
            "east": p[1] + self.offset_ne[1], "down": p[2], "vn": v[0], "ve": v[1], "vd": v[2],
            "ref_north": "" if ref_ne is None else ref_ne[0],
            "ref_east": "" if ref_ne is None else ref_ne[1],
            "mode": tel.mode.name if tel.mode else "", "armed": int(tel.armed),
            "phase": self.phase,
        })  # fmt: skip
        if ref_ne is None:
            return None
        vel = None if vel_ne is None else np.array([vel_ne[0], vel_ne[1], 0.0])
        if self.net is None:  # no safety net attached (unit use only): the plan as it is
            local = np.array([ref_ne[0] - self.offset_ne[0], ref_ne[1] - self.offset_ne[1],
                              -self.altitude])  # fmt: skip
            return local, vel, 0.0
        return self.certify(t, tel, np.array([ref_ne[0], ref_ne[1], -self.altitude]), vel)

    # ---- the safety net ----------------------------------------------------------------
    def attach_net(self, supervisor: Supervisor, others: list[FormationVehicle],
                   separation: SeparationParams = SEPARATION, events=None,
                   decisions=None) -> None:  # fmt: skip
        """Every setpoint of this vehicle goes through `supervisor` (field frame), with the
        separation from `others` as constraint rows (safety.separation)."""
        self.net, self.others, self.separation = supervisor, others, separation
        self.events, self.decisions = events, decisions

    def certify(self, t: float, tel: Telemetry, target_field: np.ndarray,
                vel_ff: np.ndarray | None):  # fmt: skip
        """The plan's setpoint (field frame) through the net → (pos, vel, yaw) in the vehicle's
        own frame for the offboard stream. The fallback is flown in OFFBOARD (a brake, then a
        position hold), not in the autopilot's HOLD: the formation needs every vehicle in
        OFFBOARD, and the other vehicles' nets keep their distance from a holding vehicle."""
        vs = tel.vehicle_state()
        if vs is None:
            return None
        off = np.array([self.offset_ne[0], self.offset_ne[1], 0.0])
        state = dataclasses.replace(vs, pos_ned=vs.pos_ned + off)
        others = []
        for w in self.others:
            pw, vw = w.pos_field(), w.tel.vel_ned
            if pw is not None and vw is not None:
                others.append((f"uav{w.index}", pw, np.asarray(vw, float)))
        self.net.set_dynamic_rows(*separation_rows(self.net.envelope.spec, state.pos_ned, others,
                                                   self.separation))  # fmt: skip
        sw = self.net.stats.switches
        e = target_field[:2] - state.pos_ned[:2]
        dist = float(np.hypot(e[0], e[1]))
        if dist > LEASH_M:  # fallen behind: chase a point on the way, not the far reference
            target_field = np.array([*(state.pos_ned[:2] + e * (LEASH_M / dist)), target_field[2]])
        dz = float(np.clip(target_field[2] - state.pos_ned[2], -LEASH_V_M, LEASH_V_M))
        target_field = np.array([target_field[0], target_field[1], state.pos_ned[2] + dz])
        proposed = Setpoint(pos_ned=target_field, vel_ned=vel_ff, yaw=0.0)
        d = self.net.update(t, state, proposed, Health())
        self.last_decision = d
        if self.decisions is not None:
            self.decisions.write(d.record(vehicle=f"uav{self.index}", pilot="formation",
                                          autopilot_mode=tel.mode or "unknown"))  # fmt: skip
        if self.events is not None and self.net.stats.switches != sw:
            self.events.write({"t": t, "event": "switch", "vehicle": f"uav{self.index}",
                               "to": d.mode.value, "reason": d.reason})  # fmt: skip
        c = d.command
        pos = None if c.pos_ned is None else np.asarray(c.pos_ned, float) - off
        return pos, c.vel_ned, c.yaw


@dataclass(frozen=True)
class FlightTimes:
    """Simulation times [s] of the phases (NaN if not reached) and the wall time [s]."""

    takeoff: float
    plan_start: float
    plan_end: float
    all_over_targets: float
    all_disarmed: float
    wall_s: float


class FormationFlight:
    """The shared phases for K vehicles, orchestrated from the calling thread."""

    def __init__(self, vehicles: list[FormationVehicle], params: FormationParams, timeout: float,
                 swarm: LockstepSwarm | None = None, events=None, decisions=None,
                 separation: SeparationParams = SEPARATION, net: bool = True):  # fmt: skip
        self.v = vehicles
        self.envelope = formation_envelope([v.path_ne for v in vehicles], params)
        for v in vehicles if net else ():  # one net per vehicle, the others' positions as rows
            sup = Supervisor(self.envelope.envelope(), FORMATION_NET, None)
            v.attach_net(sup, [w for w in vehicles if w is not v], separation, events, decisions)
        self.p = params
        self.swarm = swarm
        self.wall0 = time.monotonic()
        self.t_end = self.wall0 + timeout
        self.times = dict.fromkeys(
            ("takeoff", "plan_start", "plan_end", "all_over_targets", "all_disarmed"), math.nan
        )
        self.bar = tqdm(total=6, desc="formation", unit="phase", leave=True)

    def left(self) -> float:
        return max(1.0, self.t_end - time.monotonic())

    def now(self) -> float:
        return max(v.t for v in self.v)

    def _phase(self, name: str, description: str) -> None:
        for v in self.v:
            v.phase = name
        self.bar.set_description(description)

    def _wait_all(self, pred, what: str, timeout: float | None = None, check=None) -> None:
        """Poll until pred() holds (wall-clock limit); check() may raise to abort."""
        deadline = time.monotonic() + (
            self.left() if timeout is None else min(timeout, self.left())
        )
        while not pred():
            if self.swarm is not None and self.swarm.error:
                raise ClientTimeout(self.swarm.error)
            for v in self.v:
                if v.error:
                    raise ClientTimeout(v.error)
            if check is not None:
                check()
            if time.monotonic() > deadline:
                raise ClientTimeout(f"timed out waiting for {what}")
            time.sleep(0.02)

    def _require_offboard(self) -> None:
        for v in self.v:
            if v.tel.mode is not FlightMode.OFFBOARD:
                name = v.tel.mode.name if v.tel.mode else "unknown"
                why = f": {v.tel.statustext}" if v.tel.statustext else ""
                raise ClientTimeout(f"vehicle {v.index} left OFFBOARD (now {name}){why}")

    def fly(self) -> None:
        """Every phase; raises ClientTimeout / CommandError when one fails."""
        p, vs = self.p, self.v
        self._phase("connect", f"connect {len(vs)} vehicles")
        for v in vs:
            v.client.wait_ready(timeout=min(30.0, self.left()))
        self._wait_all(
            lambda: all(v.tel.landed_state == 1 for v in vs), "vehicles on the ground", 30
        )
        self.bar.update()

        self._phase("takeoff", "arm and take off")
        self.times["takeoff"] = self.now()
        for v in vs:
            v.client.arm()
            v.client.takeoff(v.altitude)
        self._wait_all(
            lambda: all(
                v.tel.pos_ned is not None and -v.tel.pos_ned[2] > v.altitude - 0.3 for v in vs
            ),
            "every vehicle at its cruise altitude",
        )
        self.bar.update()

        self._phase("offboard", "offboard hand-over")
        for v in vs:
            v.hold_ne = v.path_ne[0].copy()
        for v in vs:  # PX4 wants the setpoint stream before the mode switch
            v.client.wait_message("LOCAL_POSITION_NED", timeout=min(5.0, self.left()))
            v.client.wait_message("LOCAL_POSITION_NED", timeout=min(5.0, self.left()))
        for v in vs:
            v.client.set_mode(FlightMode.OFFBOARD)
        self._wait_all(lambda: all(v.tel.mode is FlightMode.OFFBOARD for v in vs), "OFFBOARD", 10)
        self.bar.update()

        n_steps = vs[0].path_ne.shape[0] - 1
        t0 = self.now() + p.lead_s
        self.times["plan_start"] = t0
        self._phase("plan", f"plan: {n_steps} steps")
        for v in vs:
            v.t0 = t0
        t_plan_end = t0 + n_steps * p.step_s
        self.times["plan_end"] = t_plan_end
        last = {"step": -1}

        def progress() -> None:
            self._require_offboard()
            step = int(min(n_steps, max(0.0, self.now() - t0) / p.step_s))
            if step != last["step"]:
                last["step"] = step
                self.bar.set_postfix_str(f"step {step}/{n_steps}", refresh=False)

        self._wait_all(lambda: self.now() >= t_plan_end, "the end of the plan", check=progress)
        self.bar.update()

        self._phase("settle", "over the targets")
        since = {"t": None}

        def over_targets() -> bool:
            ok = all(np.linalg.norm(v.pos_field() - np.r_[v.target_ne, -v.altitude])
                     < p.accept_radius_m for v in vs)  # fmt: skip
            t = self.now()
            if not ok:
                since["t"] = None
                return False
            since["t"] = t if since["t"] is None else since["t"]
            return t - since["t"] >= p.settle_s

        self._wait_all(over_targets, "every vehicle over its target", check=self._require_offboard)
        self.times["all_over_targets"] = self.now()
        self.bar.update()

        self._phase("land", "land")
        for v in vs:
            v.client.land()
        self._wait_all(
            lambda: all(not v.tel.armed for v in vs), "every vehicle landed and disarmed"
        )
        self.times["all_disarmed"] = self.now()
        self.bar.update()

    def result_times(self) -> FlightTimes:
        return FlightTimes(**self.times, wall_s=time.monotonic() - self.wall0)

    def close(self) -> None:
        for v in self.v:
            v.client.stream_offboard(None)
        self.bar.close()


class _SharedTlog:
    """One tlog for every link: a link closing does not close it (the caller does, last)."""

    def __init__(self, writer: TlogWriter):
        self.writer = writer

    def write(self, packet: bytes) -> None:
        try:
            self.writer.write(packet)
        except ValueError:  # closed at shutdown while a receive thread was still finishing
            pass

    def close(self) -> None:
        pass


def open_clients(
    instances: list[int], tlog: Path | None
) -> tuple[list[VehicleClient], TlogWriter | None]:
    """One started VehicleClient per instance on udpin:127.0.0.1:14540+N; one shared tlog.

    Raises hil.link.LinkError (after closing what was opened) if a port is taken.
    """
    writer = TlogWriter(tlog) if tlog is not None else None
    shared = _SharedTlog(writer) if writer is not None else None
    clients: list[VehicleClient] = []
    try:
        for inst in instances:
            link = MavlinkLink.open(f"udpin:127.0.0.1:{14540 + inst}")
            link.tlog = shared
            clients.append(VehicleClient(link, target_system=1 + inst).start())
    except BaseException:
        for c in clients:
            c.close()
        if writer is not None:
            writer.close()
        raise
    return clients, writer


def field_offsets(origin: Home, homes: list[Home]) -> list[np.ndarray]:
    """Field-frame (north, east) [m] of each vehicle's home."""
    return [geodetic_to_ned(origin, h.lat_deg, h.lon_deg, h.alt_m)[:2] for h in homes]


# ---- what the flight achieved --------------------------------------------------------------


def resample(tracks: list[np.ndarray], dt: float) -> tuple[np.ndarray, np.ndarray]:
    """Tracks (t, n, e, d) on one time grid over their common span: times (N,), pos (K, N, 3)."""
    t0 = max(tr[0, 0] for tr in tracks)
    t1 = min(tr[-1, 0] for tr in tracks)
    if not t1 > t0:
        return np.zeros(0), np.zeros((len(tracks), 0, 3))
    ts = np.arange(t0, t1 + 1e-9, dt)
    pos = np.stack([np.stack([np.interp(ts, tr[:, 0], tr[:, i]) for i in (1, 2, 3)], -1)
                    for tr in tracks])  # fmt: skip
    return ts, pos


@dataclass(frozen=True)
class Separation:
    """Closest approaches between any two vehicles over the flight [m] (NaN if no such pair)."""

    min_3d: float
    min_horizontal_similar_alt: float
    """Smallest horizontal distance between two vehicles whose altitudes differ < similar_alt_m."""
    min_horizontal_any: float
    """Smallest horizontal distance regardless of altitude (paths crossing at different heights)."""
    pair_3d: tuple[int, int] = (-1, -1)
    """Vehicle indices of the closest 3-D approach ..."""
    t_3d: float = math.nan
    """... and its simulation time [s]."""
    times: np.ndarray | None = None
    """(N,) time grid [s] of the series below (for plots)."""
    series_3d: np.ndarray | None = None
    """(N,) smallest 3-D distance over all pairs at each time [m]."""
    series_similar: np.ndarray | None = None
    """(N,) smallest horizontal distance over pairs at similar altitude (NaN if none) [m]."""


def separation(tracks: list[np.ndarray], similar_alt_m: float, dt: float = 0.1) -> Separation:
    """Pairwise separations on a `dt` [s] time grid over the tracks' common span."""
    if len(tracks) < 2 or any(len(tr) < 2 for tr in tracks):
        return Separation(math.nan, math.nan, math.nan)
    ts, pos = resample(tracks, dt)  # (K, N, 3)
    if pos.shape[1] == 0:
        return Separation(math.nan, math.nan, math.nan)
    i, j = np.triu_indices(pos.shape[0], 1)
    d = pos[i] - pos[j]  # (P, N, 3)
    hor = np.hypot(d[..., 0], d[..., 1])
    full = np.linalg.norm(d, axis=-1)
    similar = np.abs(d[..., 2]) < similar_alt_m
    hor_similar = np.where(similar, hor, np.inf).min(axis=0)
    p, n = np.unravel_index(int(np.argmin(full)), full.shape)
    return Separation(
        float(full.min()),
        float(hor[similar].min()) if similar.any() else math.nan,
        float(hor.min()),
        (int(i[p]), int(j[p])),
        float(ts[n]),
        ts,
        full.min(axis=0),
        np.where(np.isfinite(hor_similar), hor_similar, np.nan),
    )


def tracking_error(
    track: np.ndarray, path_ne: np.ndarray, t0: float, step_s: float
) -> tuple[float, float]:
    """Largest and RMS horizontal distance [m] from the plan's reference while the plan runs
    (track rows t, north, east, down in the field frame; NaN if no sample falls in the plan)."""
    t_end = t0 + (path_ne.shape[0] - 1) * step_s
    sel = track[(track[:, 0] >= t0) & (track[:, 0] <= t_end)] if len(track) else track
    if len(sel) == 0:
        return math.nan, math.nan
    refs = np.array([reference(path_ne, t - t0, step_s)[0] for t in sel[:, 0]])
    e = np.linalg.norm(sel[:, 1:3] - refs, axis=1)
    return float(e.max()), float(np.sqrt(np.mean(e * e)))
