"""Which airframes exist, and how to build one with its autopilot.

`make_autopilot("quadrotor" | "fixedwing", ...)` returns an object implementing
`flight.autopilot_api.Autopilot`. Autopilot modules are imported only when asked for, so a
missing or broken airframe cannot break the others.
"""

from __future__ import annotations

import importlib
from pathlib import Path

from skyherd.flight.autopilot_api import Autopilot
from skyherd.flight.clock import SimClock
from skyherd.flight.geo import DEFAULT_HOME, Home
from skyherd.flight.params import ParamStore

PX4_STANDIN = Path(__file__).parent / "airframes" / "px4_standin.toml"  # docs/quadrotor.md

# name → (module, class)
AIRFRAMES: dict[str, tuple[str, str]] = {
    "quadrotor": ("skyherd.flight.multirotor.autopilot", "MultirotorAutopilot"),
    "fixedwing": ("skyherd.flight.fixedwing.autopilot", "FixedWingAutopilot"),
}


class AirframeUnavailable(Exception):
    """The airframe is unknown or its autopilot is not available in this installation."""


def airframe_names() -> list[str]:
    return list(AIRFRAMES)


def autopilot_class(airframe: str) -> type:
    """The autopilot class for `airframe`; AirframeUnavailable if it cannot be imported."""
    if airframe not in AIRFRAMES:
        raise AirframeUnavailable(
            f"unknown airframe {airframe!r}: choose one of {airframe_names()}"
        )
    module_name, cls_name = AIRFRAMES[airframe]
    try:
        module = importlib.import_module(module_name)
        return getattr(module, cls_name)
    except (ImportError, AttributeError) as e:
        raise AirframeUnavailable(f"airframe {airframe!r} is not available yet ({e})") from e


def param_store(airframe: str) -> ParamStore:
    """The built-in autopilot's parameter table for `airframe` at its defaults (names, ranges,
    units), without building the autopilot; AirframeUnavailable for an unknown airframe."""
    if airframe == "quadrotor":
        from skyherd.flight.multirotor.params import MULTIROTOR_PARAMS as specs
    elif airframe == "fixedwing":
        from skyherd.flight.fixedwing.fw_params import FW_PARAM_SPECS as specs
    else:
        raise AirframeUnavailable(
            f"unknown airframe {airframe!r}: choose one of {airframe_names()}"
        )
    return ParamStore(specs)


def make_autopilot(
    airframe: str,
    clock: SimClock | None = None,
    home: Home = DEFAULT_HOME,
    seed: int = 0,
    instance: int = 0,
    faults=None,
    params_file: Path | str | None = None,
) -> Autopilot:
    """A ready autopilot for `airframe` on `clock`, at `home`, on the ground, disarmed.

    faults: a flight.faults.FaultPlan played on the simulation clock (None: calm, perfect);
    its random draws come from a Generator seeded with `seed`. params_file: a TOML file
    with a `[params]` table of overrides (e.g. flight/airframes/px4_standin.toml);
    ValueError names a bad file or value.
    """
    cls = autopilot_class(airframe)
    clock = clock if clock is not None else SimClock()
    if airframe == "quadrotor":
        return cls(home=home, clock=clock, seed=seed, faults=faults, params_file=params_file)
    overrides = None
    if params_file is not None:
        store = param_store("fixedwing")
        store.load_toml(params_file)
        overrides = store.as_dict()
    return cls(
        clock=clock, home=home, instance=instance, seed=seed, faults=faults, params=overrides
    )


def warm_up(airframe: str) -> None:
    """numba's kernels of `airframe`'s physics and autopilot compiled (a fresh installation:
    about 3.5 CPU s for the quadrotor) or loaded from their cache: one step of a throwaway
    autopilot. `skyherd sim` does it before its vehicle answers anyone, so that the compilation
    does not fall inside a lockstep tick, where the companion's wall-clock patience runs (a
    user's first flight under load aborted: "no tick mark from the vehicle for 60 s"). The
    quadrotor's are compiled ahead of time first when they are not yet (multirotor.compiled:
    then numba's compiler does not start in this process at all)."""
    if airframe == "quadrotor":
        from skyherd.flight.multirotor.compiled import ensure_built

        ensure_built()
    make_autopilot(airframe).step()
