"""The formation's plan on the field: a learned lock-step grid plan (policy/sql) as field-frame
waypoints, each vehicle's home and cruise altitude, the envelope every vehicle flies in, and what
a flight achieved (separations, tracking error).

Frames (all NED, metres). The *field frame* is local NED about the field origin (a geodetic
`Home`, the project's default home unless told otherwise). Grid cell (x, y), 1-based as in
`policy/sql`, has its centre at

    north = (y − 1) · cell_m,    east = (x − 1) · cell_m,

so cell (1, 1) sits on the field origin, x grows east and y grows north. Vehicle k's own home
is the centre of its start cell (a geodetic point from `flight.geo.ned_to_geodetic`), so it
starts ON that cell and, like PX4, reports positions about its own home; the companion adds the
home's field-frame offset to every position it receives and subtracts it from every setpoint.
The plan is flown in time: one plan step per cell_m / speed_mps of simulation time, linear
between cell centres with velocity feed-forward (`reference`).
"""

from __future__ import annotations

import dataclasses
import json
import math
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from skyherd.flight.geo import Home, geodetic_to_ned, ned_to_geodetic
from skyherd.runio import ports
from skyherd.safety.config import default_envelope_path, load_envelope
from skyherd.safety.envelope import EnvelopeSpec, Zone
from skyherd.safety.separation import SeparationParams
from skyherd.safety.supervisor import SupervisorParams

if TYPE_CHECKING:
    from skyherd.policy.sql.params import PlanParams

Cell = tuple[int, int]

TRACK_COLUMNS = ["t", "vehicle", "north", "east", "down", "vn", "ve", "vd", "ref_north",
                 "ref_east", "mode", "armed", "phase"]  # fmt: skip


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
    altitude_step_m: float = 3.0
    """Extra cruise altitude per vehicle index [m] (vertical separation). The learned plans
    cross: with 1.5 m layers every crossing tripped the nets' 1 m stopping-point separation
    rows (learned K = 4 / 9 / 16: 180 / 636 / 1,050 switches, closest approach 1.5 m, K = 16 at
    7.9x); with 3 m, 6 / 72 / 339 switches, closest approach 2.8 m, K = 16 at 22.5x."""
    lead_s: float = 2.0
    """Simulation time between the OFFBOARD hand-over and the plan's first step [s]."""
    accept_radius_m: float = 0.3
    """A vehicle is over its target within this 3-D distance [m] ..."""
    settle_s: float = 1.0
    """... held for this long [s] of simulation time, before the landing starts."""
    similar_alt_m: float = 1.0
    """Two vehicles are 'at similar altitude' when their altitudes differ by less [m]."""
    settle_timeout_s: float = 60.0
    """After the plan's end, every vehicle must be over its target within this time [s]."""

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


def plan_text(paths: list[list[Cell]]) -> str:
    """A plan as plan.json's text (what `load_plan` reads): one agent's path per line,
    cells as [x,y]."""
    rows = ("  " + str([list(c) for c in p]).replace(" ", "") for p in paths)
    return "[\n" + ",\n".join(rows) + "\n]\n"


def load_plan(path: Path | str, n_agents: int, size: int = 50) -> list[list[Cell]]:
    """A plan saved by `skyherd train sql` (plan_K<K>.json); PlanError if unusable."""
    try:
        raw = json.loads(Path(path).read_text(encoding="utf-8"))
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as e:
        raise PlanError(f"cannot read plan {path}: {e}") from None
    return validate_plan(raw, n_agents, size)


def plan_params(n_agents: int, sql_seed: int) -> PlanParams:
    """How the study's SQL-SIE plan for K = `n_agents` is learnt, with the fixed learner seed
    `sql_seed`; PlanError if K has no built-in layout."""
    from skyherd.policy.sql import GridParams, PlanParams
    from skyherd.policy.sql.layout import STARTS

    if n_agents not in STARTS:
        raise PlanError(f"the study's SQL-SIE plans are for K = {', '.join(map(str, STARTS))}: "
                        f"for K = {n_agents} pass --policy-file")  # fmt: skip
    return PlanParams(GridParams(n_agents=n_agents), seed=sql_seed)


def learned_plan(
    params: PlanParams, progress: Callable[[int], object] | None = None
) -> list[list[Cell]]:
    """The plan learnt in this process (policy.sql.learn_plan, a few seconds;
    `progress(episodes)`); PlanError if it is unusable."""
    from skyherd.policy.sql import learn_plan

    K = params.grid.n_agents
    try:
        return validate_plan(learn_plan(params, progress), K, params.grid.size)
    except ValueError as e:
        raise PlanError(f"{e}; try another --sql-seed or pass --policy-file") from None


def obtain_plan(
    policy_file: str | None, n_agents: int, sql_seed: int, bar: Callable[..., Any] | None = None
) -> tuple[list[list[Cell]], dict]:
    """The lock-step plan of `skyherd fly --mission formation`: `policy_file` (a
    plan_K<K>.json of `skyherd train sql`), else learnt here (learned_plan, with `bar` a
    progress bar of tqdm.tqdm's signature), and where it came from (for config.json);
    PlanError (one line) if it is unusable."""
    from skyherd.policy.sql import GridParams

    if policy_file:
        try:
            plan = load_plan(policy_file, n_agents, GridParams().size)
        except PlanError as e:
            raise PlanError(f"{e}; pass a plan_K{n_agents}.json from `skyherd train sql`") from None
        return plan, {"source": "file", "path": str(policy_file)}
    params = plan_params(n_agents, sql_seed)
    if bar is None:
        return learned_plan(params), params.describe()
    with bar(total=params.hyper.episodes, desc=f"train SQL-SIE K={n_agents}", unit="ep") as b:
        return learned_plan(params, b.update), params.describe()


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


def vehicle_instances(base: int, n: int) -> list[int]:
    """The MAVLink instances of n formation vehicles from `base` up: `runio.ports.disjoint_instances`,
    whose port sets meet nowhere (instance 10 skipped, its companion port is the ground stations'
    14550; N+40 skipped once N flies, its companion port is N's API port; CONVENTIONS.md,
    "overlaps"). ValueError if they would go past MAX_INSTANCE."""
    return ports.disjoint_instances(base, n)


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
