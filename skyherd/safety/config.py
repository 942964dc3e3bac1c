"""Constraint-set files: versioned TOML, one per airframe and mission (safety/envelopes/).

Schema (every number SI; see quadrotor_field.toml for a commented example):

    [envelope]  name, version, airframe ("quadrotor" | "fixedwing")
    [dynamics]  fields of safety.envelope.Dynamics
    [limits]    fields of safety.envelope.Limits
    [guards]    every guard, stated: gps_jump_m, wind_limit_mps, link_timeout_s,
                camera_timeout_s — a number > 0 (on, its threshold) or the string "off"
    [supervisor] fields of safety.supervisor.SupervisorParams (optional; not the guards)
    [[fence.inclusion]]  name, points_ne = [[n, e], ...]  or  center_ne, radius_m
    [[fence.exclusion]]  the same

A file that cannot be read, parsed or validated raises EnvelopeFileError with a one-line
reason that names the file and the field.
"""

from __future__ import annotations

import dataclasses
import math
import tomllib
from pathlib import Path
from typing import Any

import numpy as np

from skyherd.runio.schema import fill_dataclass as _fill_dataclass
from skyherd.safety.envelope import (
    Dynamics,
    EnvelopeSpec,
    Guards,
    Limits,
    Zone,
    circle_zone,
    polygon_zone,
)

ENVELOPE_DIR = Path(__file__).parent / "envelopes"
AIRFRAMES = ("quadrotor", "fixedwing")
# the constraint set `skyherd fly` flies by default, per airframe (and judges a run without one by)
FLY_ENVELOPE = {"quadrotor": "quadrotor_groundair.toml", "fixedwing": "fixedwing_field.toml"}


class EnvelopeFileError(ValueError):
    """A constraint-set file is missing, corrupt or inconsistent."""


def default_envelope_path(airframe: str) -> Path:
    return ENVELOPE_DIR / f"{airframe}_field.toml"


def fly_envelope_path(airframe: str) -> Path:
    return ENVELOPE_DIR / FLY_ENVELOPE[airframe]


def fly_envelope(path: Path | str | None, airframe: str) -> EnvelopeSpec:
    """The constraint set `skyherd fly` flies: `path` (--envelope), else the airframe's."""
    return load_envelope(path or fly_envelope_path(airframe))[0]


def flight_envelope_record(path: Path | str | None, airframe: str) -> tuple[EnvelopeSpec, dict]:
    """The flight's constraint set (`path`, else the airframe's), checked for its airframe, and
    config.json's record of it (path, name, version, rows); ValueError saying what to do."""
    path = path or fly_envelope_path(airframe)
    try:
        spec, _ = load_envelope(path)
    except ValueError as e:  # EnvelopeFileError
        raise ValueError(f"{e}; fix the file or pass another --envelope") from None
    if spec.airframe != airframe:
        raise ValueError(f"--envelope {path} is for a {spec.airframe}; this flight is a {airframe}")
    return spec, {"path": str(Path(path).resolve()), **spec.describe()}


def check_mean_wind(path: Path | str | None, airframe: str, wind_ned, asked: str) -> None:
    """ValueError when the mean wind `wind_ned` [m/s] (`--wind asked`) is above the wind limit
    ([guards] wind_limit_mps) of the flight's constraint set (`fly_envelope`): the net's
    envelope assumes braking that such a wind takes away. Wind that rises later (--fault
    wind@T:...) is the net's to judge in flight."""
    try:
        spec = fly_envelope(path, airframe)
    except ValueError as e:  # EnvelopeFileError
        raise ValueError(f"{e}; fix it or pass another --envelope") from None
    speed = (wind_ned[0] ** 2 + wind_ned[1] ** 2) ** 0.5
    limit = spec.guards.wind_limit_mps
    if limit is not None and speed > limit:
        raise ValueError(
            f"--wind {asked}: {speed:.1f} m/s is above the {spec.airframe}'s wind limit "
            f"{limit:g} m/s ({spec.name} {spec.version}, [guards] wind_limit_mps); fly in "
            f"{limit:g} m/s or less, or with a constraint set stated for this wind (--envelope)"
        )


def load_envelope(path: Path | str) -> tuple[EnvelopeSpec, dict[str, Any]]:
    """Read a constraint-set file → (spec, supervisor table): the [supervisor] table with the
    [guards] added as SupervisorParams fields (None = off)."""
    path = Path(path)
    try:
        text = path.read_text(encoding="utf-8")
    except (OSError, UnicodeDecodeError) as e:
        raise EnvelopeFileError(f"cannot read constraint set {path}: {e}") from e
    try:
        doc = tomllib.loads(text)
    except tomllib.TOMLDecodeError as e:
        raise EnvelopeFileError(f"constraint set {path} is not valid TOML: {e}") from e
    try:
        spec = parse_envelope(doc, source=str(path))
        sup = doc.get("supervisor", {})
        if not isinstance(sup, dict):
            raise ValueError("[supervisor] must be a table")
        for k in GUARD_KEYS:
            if k in sup:
                raise ValueError(f"[supervisor] {k}: a guard; state it in [guards]")
        return spec, {**sup, **dataclasses.asdict(spec.guards)}
    except (KeyError, TypeError, ValueError) as e:
        msg = e.args[0] if e.args else str(e)
        raise EnvelopeFileError(f"constraint set {path}: {msg}") from e


def parse_envelope(doc: dict[str, Any], source: str = "") -> EnvelopeSpec:
    head = _table(doc, "envelope")
    for key in ("name", "version", "airframe"):
        if not isinstance(head.get(key), str) or not head[key]:
            raise ValueError(f"[envelope] {key} must be a non-empty string")
    if head["airframe"] not in AIRFRAMES:
        raise ValueError(
            f"[envelope] airframe must be one of {AIRFRAMES}, got {head['airframe']!r}"
        )
    dyn = fill_dataclass(Dynamics, doc.get("dynamics", {}), "dynamics")
    lim = fill_dataclass(Limits, doc.get("limits", {}), "limits")
    _check_limits(dyn, lim)  # before the zones: their circles need valid circle_sides
    fence = doc.get("fence", {})
    if not isinstance(fence, dict):
        raise ValueError("[fence] must be a table")
    inc = tuple(
        _zone(z, "fence.inclusion", lim.circle_sides, False) for z in fence.get("inclusion", [])
    )
    exc = tuple(
        _zone(z, "fence.exclusion", lim.circle_sides, True) for z in fence.get("exclusion", [])
    )
    if not inc and lim.home_radius_m <= 0:
        raise ValueError("no inclusion fence and no home radius: the envelope would be unbounded")
    guards = parse_guards(doc.get("guards"))
    spec = EnvelopeSpec(head["name"], head["version"], head["airframe"], dyn, lim, inc, exc, source,
                        guards)  # fmt: skip
    check_spec(spec)
    return spec


GUARD_KEYS = tuple(f.name for f in dataclasses.fields(Guards))
OFF = "off"
GUARD_RANGES: dict[str, tuple[float, float]] = {  # plausible values when on (SI)
    "gps_jump_m": (0.5, 500.0),
    "wind_limit_mps": (1.0, 60.0),
    "link_timeout_s": (0.1, 60.0),
    "camera_timeout_s": (0.1, 60.0),
}


def parse_guards(table: Any) -> Guards:
    """[guards]: every key of Guards stated, each a number in its range (on) or "off".

    A missing key is an error naming it: a guard is never off by default. "off" is a word
    and not 0, because 0 reads as a threshold (a 0 m jump, a 0 s timeout) and was the silent
    default that left the GPS guard off in `skyherd fly`."""
    if not isinstance(table, dict):
        raise ValueError(
            f"missing [guards] table: state every guard ({', '.join(GUARD_KEYS)}), "
            f'each a number or "{OFF}"'
        )
    unknown = sorted(set(table) - set(GUARD_KEYS))
    if unknown:
        raise ValueError(f"[guards] unknown key {unknown[0]!r}; known: {', '.join(GUARD_KEYS)}")
    vals: dict[str, float | None] = {}
    for k in GUARD_KEYS:
        if k not in table:
            raise ValueError(f'[guards] {k} is missing: state it, a number or "{OFF}"')
        v = table[k]
        if v == OFF:
            vals[k] = None
            continue
        lo, hi = GUARD_RANGES[k]
        if isinstance(v, bool) or not isinstance(v, int | float) or not lo <= v <= hi:
            raise ValueError(f'[guards] {k} must be within [{lo:g}, {hi:g}] or "{OFF}", got {v!r}')
        vals[k] = float(v)
    return Guards(**vals)


def _table(doc: dict, key: str) -> dict:
    t = doc.get(key)
    if not isinstance(t, dict):
        raise ValueError(f"missing [{key}] table")
    return t


def fill_dataclass(cls, table: Any, where: str):
    """Build a frozen dataclass from a TOML table: unknown keys and wrong types are errors
    (checked by pydantic in runio.schema; one line naming the table and the key)."""
    return _fill_dataclass(cls, table, where)


# Plausible ranges of every number of a constraint set (SI). Outside = a typo or a unit
# mix-up (degrees for radians, cm for m), refused with the key's name.
RANGES: dict[str, tuple[float, float]] = {
    "dynamics.dt_s": (1e-3, 1.0),
    "dynamics.tau_s": (1e-3, 30.0),
    "dynamics.decel_h_mps2": (0.0, 30.0),
    "dynamics.decel_v_mps2": (0.05, 30.0),
    "dynamics.react_s": (0.01, 10.0),  # a zero reaction time is never true
    "dynamics.bank_max_rad": (0.0, 1.4),
    "dynamics.sink_reserve_m": (0.0, 1000.0),
    "limits.ceiling_m": (1.0, 10_000.0),
    "limits.floor_m": (0.0, 9_999.0),
    "limits.speed_h_mps": (0.1, 150.0),
    "limits.climb_mps": (0.05, 50.0),
    "limits.descent_mps": (0.05, 50.0),
    "limits.accel_h_mps2": (0.05, 50.0),
    "limits.accel_v_mps2": (0.05, 50.0),
    "limits.tilt_cmd_rad": (0.01, 1.5),
    "limits.attitude_max_rad": (0.01, 1.5),
    "limits.state_speed_factor": (1.0, 5.0),
    "limits.home_radius_m": (0.0, 100_000.0),
    "limits.margin_m": (0.0, 10_000.0),
    "limits.near_m": (0.0, 10_000.0),
    "limits.breach_tolerance_m": (0.0, 100.0),
    "limits.circle_sides": (3, 256),
    "limits.speed_sides": (4, 64),
}
MAX_FENCE_M = 100_000.0  # a fence vertex farther from home than this is a unit error [m]


def check_spec(spec: EnvelopeSpec) -> None:
    """Validate an envelope's own values (also one built in code or from MAVLink fence
    items): ValueError with a one-line reason naming the key."""
    _check_limits(spec.dynamics, spec.limits)
    lim = spec.limits
    for z in (*spec.inclusions, *spec.exclusions):
        far = float(np.abs(z.points).max()) if len(z.points) else 0.0
        if not far <= MAX_FENCE_M:
            raise ValueError(
                f"fence {z.name}: a vertex {far:.0f} m from home (> {MAX_FENCE_M:.0f} m)"
            )
    if spec.inclusions:
        pts = np.concatenate([z.points for z in spec.inclusions])
        half = 0.5 * float(np.min(pts.max(axis=0) - pts.min(axis=0)))
        if lim.margin_m >= half:
            raise ValueError(
                f"limits.margin_m ({lim.margin_m:g} m) must be below half the fence's narrowest "
                f"extent ({half:.1f} m): nothing would be allowed"
            )
    if lim.margin_m >= 0.5 * (lim.ceiling_m - lim.floor_m):
        raise ValueError(
            f"limits.margin_m ({lim.margin_m:g} m) must be below half the altitude band "
            f"({0.5 * (lim.ceiling_m - lim.floor_m):g} m)"
        )
    if lim.margin_m + spec.dynamics.sink_reserve_m >= lim.ceiling_m - lim.floor_m - lim.margin_m:
        raise ValueError(
            f"dynamics.sink_reserve_m ({spec.dynamics.sink_reserve_m:g} m) leaves no altitude "
            f"between the floor's and the ceiling's margins; lower it or widen the band"
        )


def _check_limits(dyn: Dynamics, lim: Limits) -> None:
    vals = {f"dynamics.{k}": getattr(dyn, k) for k in ("dt_s", "tau_s", "decel_h_mps2",
            "decel_v_mps2", "react_s", "bank_max_rad", "sink_reserve_m")}  # fmt: skip
    vals.update({f"limits.{f.name}": getattr(lim, f.name) for f in dataclasses.fields(lim)})
    for k, (lo, hi) in RANGES.items():
        v = vals[k]
        if not (isinstance(v, int | float) and math.isfinite(v) and lo <= v <= hi):
            raise ValueError(f"{k} must be within [{lo:g}, {hi:g}], got {v}")
    if dyn.dt_s > dyn.tau_s:
        raise ValueError(f"dynamics.dt_s ({dyn.dt_s:g} s) must not exceed tau_s ({dyn.tau_s:g} s)")
    if dyn.decel_h_mps2 == 0 and dyn.bank_max_rad == 0:
        raise ValueError("dynamics: set decel_h_mps2 (can stop) or bank_max_rad (loiters)")
    if not lim.ceiling_m > lim.floor_m:
        raise ValueError(
            f"limits.ceiling_m ({lim.ceiling_m}) must be above floor_m ({lim.floor_m})"
        )


def _zone(t: Any, where: str, sides: int, exclusion: bool) -> Zone:
    if not isinstance(t, dict) or not isinstance(t.get("name"), str):
        raise ValueError(f"[[{where}]] entries need a name")
    name = t["name"]
    if "points_ne" in t:
        try:
            pts = np.array(t["points_ne"], dtype=float)
        except (TypeError, ValueError) as e:
            raise ValueError(
                f"[[{where}]] {name}: points_ne must be [[north, east], ...] in m"
            ) from e
        return polygon_zone(name, pts)
    if "center_ne" in t and "radius_m" in t:
        c = np.array(t["center_ne"], dtype=float)
        if c.shape != (2,):
            raise ValueError(f"[[{where}]] {name}: center_ne must be [north, east]")
        return circle_zone(
            f"{name} (circle r {t['radius_m']:g} m)", c, float(t["radius_m"]), sides, exclusion
        )
    raise ValueError(f"[[{where}]] {name}: give points_ne, or center_ne and radius_m")
