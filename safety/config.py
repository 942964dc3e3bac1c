"""Constraint-set files: versioned TOML, one per airframe and mission (safety/envelopes/).

Schema (every number SI; see quadrotor_field.toml for a commented example):

    [envelope]  name, version, airframe ("quadrotor" | "fixedwing")
    [dynamics]  fields of safety.envelope.Dynamics
    [limits]    fields of safety.envelope.Limits
    [supervisor] fields of safety.supervisor.SupervisorParams (optional)
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

from safety.envelope import Dynamics, EnvelopeSpec, Limits, Zone, circle_zone, polygon_zone

ENVELOPE_DIR = Path(__file__).parent / "envelopes"
AIRFRAMES = ("quadrotor", "fixedwing")


class EnvelopeFileError(ValueError):
    """A constraint-set file is missing, corrupt or inconsistent."""


def default_envelope_path(airframe: str) -> Path:
    return ENVELOPE_DIR / f"{airframe}_field.toml"


def load_envelope(path: Path | str) -> tuple[EnvelopeSpec, dict[str, Any]]:
    """Read a constraint-set file → (spec, raw [supervisor] table)."""
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
        return parse_envelope(doc, source=str(path)), dict(doc.get("supervisor", {}))
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
    _check_limits(dyn, lim)
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
    return EnvelopeSpec(head["name"], head["version"], head["airframe"], dyn, lim, inc, exc, source)


def _table(doc: dict, key: str) -> dict:
    t = doc.get(key)
    if not isinstance(t, dict):
        raise ValueError(f"missing [{key}] table")
    return t


def fill_dataclass(cls, table: Any, where: str):
    """Build a frozen dataclass from a TOML table: unknown keys and wrong types are errors."""
    if not isinstance(table, dict):
        raise ValueError(f"[{where}] must be a table")
    fields = {f.name: f for f in dataclasses.fields(cls)}
    unknown = sorted(set(table) - set(fields))
    if unknown:
        raise ValueError(f"[{where}] unknown key(s) {unknown}; known: {sorted(fields)}")
    kw = {}
    for k, v in table.items():
        default = getattr(cls(), k)
        if isinstance(default, bool):
            if not isinstance(v, bool):
                raise ValueError(f"[{where}] {k} must be true/false, got {v!r}")
        elif isinstance(default, int):
            if not isinstance(v, int) or isinstance(v, bool):
                raise ValueError(f"[{where}] {k} must be an integer, got {v!r}")
        elif isinstance(default, float):
            if not isinstance(v, int | float) or isinstance(v, bool) or not math.isfinite(v):
                raise ValueError(f"[{where}] {k} must be a finite number, got {v!r}")
            v = float(v)
        elif isinstance(default, str) and not isinstance(v, str):
            raise ValueError(f"[{where}] {k} must be a string, got {v!r}")
        kw[k] = v
    return cls(**kw)


def _check_limits(dyn: Dynamics, lim: Limits) -> None:
    positive = {
        "dynamics.dt_s": dyn.dt_s,
        "dynamics.tau_s": dyn.tau_s,
        "dynamics.decel_v_mps2": dyn.decel_v_mps2,
        "limits.speed_h_mps": lim.speed_h_mps,
        "limits.climb_mps": lim.climb_mps,
        "limits.descent_mps": lim.descent_mps,
        "limits.accel_h_mps2": lim.accel_h_mps2,
        "limits.accel_v_mps2": lim.accel_v_mps2,
        "limits.tilt_cmd_rad": lim.tilt_cmd_rad,
        "limits.attitude_max_rad": lim.attitude_max_rad,
    }
    for k, v in positive.items():
        if not v > 0:
            raise ValueError(f"{k} must be > 0, got {v}")
    for k, v in {"dynamics.decel_h_mps2": dyn.decel_h_mps2, "dynamics.react_s": dyn.react_s,
                 "dynamics.bank_max_rad": dyn.bank_max_rad, "limits.margin_m": lim.margin_m,
                 "limits.floor_m": lim.floor_m}.items():  # fmt: skip
        if v < 0:
            raise ValueError(f"{k} must be >= 0, got {v}")
    if dyn.decel_h_mps2 == 0 and dyn.bank_max_rad == 0:
        raise ValueError("dynamics: set decel_h_mps2 (can stop) or bank_max_rad (loiters)")
    if dyn.bank_max_rad >= math.pi / 2:
        raise ValueError("dynamics.bank_max_rad must be below pi/2 rad")
    if not lim.ceiling_m > lim.floor_m:
        raise ValueError(
            f"limits.ceiling_m ({lim.ceiling_m}) must be above floor_m ({lim.floor_m})"
        )
    if lim.tilt_cmd_rad >= math.pi / 2 or lim.attitude_max_rad >= math.pi / 2:
        raise ValueError("limits: tilt angles must be below pi/2 rad")
    if lim.circle_sides < 3 or lim.speed_sides < 4:
        raise ValueError("limits: circle_sides >= 3 and speed_sides >= 4")


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
