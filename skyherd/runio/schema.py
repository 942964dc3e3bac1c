"""Configuration files validated by a schema library (pydantic), with one-line errors that
name the table and the key: `[limits] ceiling_m must be a finite number, got 'high'`.

    fill_dataclass(Limits, doc["limits"], "limits")     a frozen dataclass from a TOML table
    validate_mapping(table, float, known, "params")     NAME = number tables

Strict types: an integer field takes no float or bool, a number field no string, a boolean no
0/1; NaN and ±inf are refused; unknown keys are errors (a typo never passes silently).
"""

from __future__ import annotations

import dataclasses
import json
import math
import types
import typing
from collections.abc import Iterable
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    from pydantic import ValidationError

# pydantic's ConfigDict. pydantic itself (~0.1 s of CPU to import) is imported by the first
# table validated (_validated), not by `import skyherd.runio`: every program imports runio,
# and `skyherd sim` validates no table unless given --param.
STRICT = {"extra": "forbid", "allow_inf_nan": False, "strict": True}


class ConfigError(ValueError):
    """A configuration table that does not match its schema (one-line message)."""


def _json(table: Any) -> str:
    # JSON keeps strict checking simple (arrays → tuples); inf/nan survive as Infinity/NaN
    return json.dumps(table, allow_nan=True, default=str)


def _one_line(e: ValidationError, where: str, known: Iterable[str] = ()) -> str:
    err = e.errors()[0]
    loc = ".".join(str(p) for p in err["loc"])
    if err["type"] == "extra_forbidden":
        return f"[{where}] unknown key {loc!r}; known: {', '.join(sorted(known))}"
    more = f" (and {e.error_count() - 1} more)" if e.error_count() > 1 else ""
    what = _WHAT.get(err["type"], err["msg"].lower())
    return f"[{where}] {loc} {what}, got {err.get('input')!r}{more}"


_WHAT = {  # pydantic error type → the words of the message
    "float_type": "must be a finite number",
    "float_parsing": "must be a finite number",
    "finite_number": "must be a finite number",
    "int_type": "must be an integer",
    "int_from_float": "must be an integer",
    "bool_type": "must be true/false",
    "string_type": "must be a string",
    "tuple_type": "must be an array",
    "list_type": "must be an array",
    "missing": "is missing an element",
    "too_long": "has too many elements",
}


def fill_dataclass(cls: type, table: Any, where: str):
    """An instance of the dataclass `cls` from `table` (defaults for missing keys)."""
    if not isinstance(table, dict):
        raise ConfigError(f"[{where}] must be a table, got {type(table).__name__}")
    hints = typing.get_type_hints(cls)
    fields = {f.name: (hints[f.name], f.default if f.default is not dataclasses.MISSING
                       else f.default_factory())  # type: ignore[misc]
              for f in dataclasses.fields(cls) if f.init}  # fmt: skip
    values = _validated(f"{cls.__name__}Table", fields, table, where)
    return cls(**{k: getattr(values, k) for k in table})


def validate_mapping(table: Any, value_type: type, known: Iterable[str], where: str) -> dict:
    """A NAME = value table whose names must be in `known` and values of `value_type`."""
    known = list(known)
    if not isinstance(table, dict):
        raise ConfigError(f"[{where}] must be a table, got {type(table).__name__}")
    values = _validated(
        f"{where}Table", {k: (value_type | None, None) for k in known}, table, where
    )
    out = {k: getattr(values, k) for k in table}
    if value_type is float and not all(math.isfinite(v) for v in out.values()):
        raise ConfigError(f"[{where}] values must be finite numbers")
    return out


_EXACT_INT = 2**53  # an integer a float field takes as the same number


def _plain(typ, value) -> tuple[bool, Any]:
    """(True, the value) when `value` is one that the strict check of `typ` takes as it is (an
    integer in a number field: as a float), for the types the configuration tables use (float,
    int, str, bool, and each or None); else (False, None): pydantic decides, and words the error."""
    if typing.get_origin(typ) in (typing.Union, types.UnionType):
        args = typing.get_args(typ)
        if value is None:
            return type(None) in args, None
        rest = [a for a in args if a is not type(None)]
        return _plain(rest[0], value) if len(rest) == 1 else (False, None)
    kind = type(value)
    if typ is float and (kind is int and abs(value) <= _EXACT_INT):
        return True, float(value)
    if typ is float:
        return kind is float and math.isfinite(value), value
    if typ in (int, str, bool):
        return kind is typ, value
    return False, None


def _validated(name: str, fields: dict, table: Any, where: str):
    """`table` checked by a strict pydantic model of `fields` (name → (type, default)); its
    values as the model's attributes. ConfigError (one line) if it does not match. A table whose
    every key is known and every value plain (_plain) needs no model: pydantic (~0.07 CPU s to
    import and build the first) is imported only for the others, which it checks and words."""
    if isinstance(table, dict) and all(k in fields for k in table):
        values = {}
        for k, v in table.items():
            ok, values[k] = _plain(fields[k][0], v)
            if not ok:
                break
        else:
            return types.SimpleNamespace(**values)
    from pydantic import ValidationError, create_model

    model = create_model(name, __config__=STRICT, **fields)  # type: ignore[call-overload]
    try:
        return model.model_validate_json(_json(table))
    except ValidationError as e:
        raise ConfigError(_one_line(e, where, fields)) from e
