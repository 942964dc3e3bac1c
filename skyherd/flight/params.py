"""A small typed parameter store: PX4-style names → float, each with default, range and meaning.

Airframe-neutral: the multirotor and fixed-wing autopilots each pass their own list of
`ParamSpec`. Values keep the unit PX4 uses for that name (`unit` says which: a few PX4
parameters are in degrees); an autopilot converts to SI once, where it reads them.
Names are at most 16 characters (MAVLink `param_id`). The order of the specs is the
order of `names()`, which a MAVLink endpoint uses as `param_index`.
"""

from __future__ import annotations

import difflib
import math
import tomllib
from collections.abc import Iterable, Mapping
from dataclasses import dataclass
from pathlib import Path

from skyherd.flight.autopilot_api import Result

MAX_NAME_LEN = 16  # MAVLink param_id length


@dataclass(frozen=True)
class ParamSpec:
    """One parameter: `name` (≤ 16 chars), `default`, inclusive `[min, max]`, `unit`, meaning."""

    name: str
    default: float
    min: float
    max: float
    description: str
    unit: str = ""

    def __post_init__(self) -> None:
        if not self.name or len(self.name) > MAX_NAME_LEN:
            raise ValueError(f"parameter name must be 1..{MAX_NAME_LEN} chars: {self.name!r}")
        if not (self.min <= self.default <= self.max):
            raise ValueError(
                f"{self.name}: default {self.default} outside [{self.min}, {self.max}]"
            )


class ParamStore:
    """Current values of a fixed set of parameters.

    `revision` increases on every accepted change, so users can cache derived values.
    """

    def __init__(self, specs: Iterable[ParamSpec], values: Mapping[str, float] | None = None):
        self._specs: dict[str, ParamSpec] = {}
        for s in specs:
            if s.name in self._specs:
                raise ValueError(f"duplicate parameter {s.name}")
            self._specs[s.name] = s
        self._values: dict[str, float] = {n: float(s.default) for n, s in self._specs.items()}
        self.revision = 0
        if values:
            self.update(values)

    # ---- reading
    def names(self) -> list[str]:
        """Parameter names in declaration order (stable: MAVLink param_index)."""
        return list(self._specs)

    def spec(self, name: str) -> ParamSpec | None:
        return self._specs.get(name)

    def get(self, name: str) -> float | None:
        """Value, or None for an unknown name."""
        return self._values.get(name)

    def __getitem__(self, name: str) -> float:
        return self._values[name]

    def __contains__(self, name: str) -> bool:
        return name in self._specs

    def close_names(self, name: str, n: int = 3) -> list[str]:
        """Up to n parameter names like `name` (any case), the closest first ("did you mean")."""
        return difflib.get_close_matches(name.upper(), self.names(), n=n)

    def as_dict(self) -> dict[str, float]:
        return dict(self._values)

    # ---- writing
    def check(self, name: str, value: float) -> Result:
        """Would `set(name, value)` be accepted? No state change."""
        spec = self._specs.get(name)
        if spec is None:
            return Result.denied(f"unknown parameter {name!r}")
        try:
            v = float(value)
        except (TypeError, ValueError):
            return Result.denied(f"{name}: value {value!r} is not a number")
        if not math.isfinite(v):
            return Result.denied(f"{name}: value must be finite, got {v}")
        if not (spec.min <= v <= spec.max):
            return Result.denied(f"{name}: {v} outside [{spec.min}, {spec.max}] {spec.unit}")
        return Result.accepted()

    def set(self, name: str, value: float) -> Result:
        """Set one value; out of range, NaN or unknown names are refused with no change."""
        r = self.check(name, value)
        if r.ok:
            self._values[name] = float(value)
            self.revision += 1
        return r

    def update(self, values: Mapping[str, float]) -> None:
        """Set several values; raises ValueError (naming the first bad one) before changing any."""
        for n, v in values.items():
            r = self.check(n, v)
            if not r.ok:
                raise ValueError(r.reason)
        for n, v in values.items():
            self._values[n] = float(v)
        self.revision += 1

    def reset_defaults(self) -> None:
        self._values = {n: float(s.default) for n, s in self._specs.items()}
        self.revision += 1

    # ---- files
    def load_toml(self, path: Path | str) -> None:
        """Overrides from a TOML file: a `[params]` table of NAME = value. ValueError if bad."""
        try:
            data = tomllib.loads(Path(path).read_text())
        except (OSError, tomllib.TOMLDecodeError) as e:
            raise ValueError(f"cannot read parameter file {path}: {e}") from e
        from skyherd.runio.schema import validate_mapping  # pydantic: names known, values numbers

        try:
            table = validate_mapping(data.get("params", {}), float, self.names(), "params")
        except ValueError as e:
            raise ValueError(f"{path}: {e}") from e
        self.update(table)

    def dumps_toml(self) -> str:
        """All values as a TOML `[params]` table, with range, unit and meaning as comments."""
        lines = ["[params]"]
        for n, s in self._specs.items():
            lines.append(
                f"{n} = {self._values[n]!r}  # [{s.min}, {s.max}] {s.unit}: {s.description}"
            )
        return "\n".join(lines) + "\n"


def check_assignments(store: ParamStore, items: Iterable[str], airframe: str) -> None:
    """`NAME=VALUE` items (`--param`) against a built-in autopilot's table (names, numbers,
    ranges), before the autopilot exists; ValueError naming the item and what to do."""
    for item in items:
        name, eq, value = item.partition("=")
        if not eq:
            raise ValueError(f"--param {item!r}: expected NAME=VALUE, e.g. COM_OF_LOSS_T=3")
        res = store.check(name.strip(), value.strip())
        if not res.ok:
            raise ValueError(f"--param {item}: {res.reason}{_hint(store, name.strip(), airframe)}")


def _hint(store: ParamStore, name: str, airframe: str) -> str:
    """What to do about an unknown parameter name: the close names, or where the table is."""
    if name in store:
        return ""
    close = store.close_names(name)
    if close:
        return f"; did you mean {' or '.join(close)}?"
    return f"; the built-in {airframe}'s {len(store.names())} parameters: `skyherd sitl` and a ground station list them"


def apply_assignments(autopilot, items: Iterable[str]) -> None:
    """`NAME=VALUE` items set on a built-in autopilot at start (`set_param`); ValueError
    naming the first item it refuses."""
    for item in items:
        name, _, value = item.partition("=")
        try:
            res = autopilot.set_param(name.strip(), float(value))
        except ValueError:
            res = None
        if res is None or not res.ok:
            why = res.reason if res is not None else f"{value!r} is not a number"
            raise ValueError(f"--param {item}: {why}")
