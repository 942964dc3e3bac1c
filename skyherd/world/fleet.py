"""A fleet: several built-in vehicles in one simulator process (`skyherd sim --fleet FILE`).

The fleet file is a JSON list, one entry per vehicle:
`{"name": IDENTIFIER, "instance": INT >= 0, "seed": INT, "home": [LAT, LON, ALT]}` (deg, deg,
m AMSL). `write_fleet` writes it (`skyherd fly --mission formation` makes one per simulator),
`read_fleet` reads and checks it, `open_fleet` builds one World per vehicle, each writing into
run_dir/<name>/; world.sim.run_worlds steps them in turn, each in lockstep with its companion.
"""

from __future__ import annotations

import dataclasses
import json
import math
import os
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING

from skyherd.flight.geo import home_in_range
from skyherd.runio import atomic_write_text

if TYPE_CHECKING:  # the simulator itself only where worlds are opened
    from skyherd.world.sim import World, WorldParams

ENTRY = '{"name": IDENTIFIER, "instance": INT >= 0, "seed": INT, "home": [LAT, LON, ALT]}'


@dataclass(frozen=True)
class FleetVehicle:
    """One vehicle of a fleet file."""

    name: str  # its folder in the run folder
    instance: int
    seed: int
    home: tuple[float, float, float]  # lat [deg], lon [deg], alt AMSL [m]


def write_fleet(path: Path, fleet: list[FleetVehicle]) -> None:
    """The fleet file (write-to-temp and rename)."""
    entries = [{"name": v.name, "instance": v.instance, "seed": v.seed, "home": list(v.home)}
               for v in fleet]  # fmt: skip
    atomic_write_text(path, json.dumps(entries, indent=1) + "\n")


def read_fleet(path: Path) -> list[FleetVehicle]:
    """The fleet file, checked: ValueError naming the file and the entry otherwise."""
    try:
        entries = json.loads(Path(path).read_text())
    except (OSError, UnicodeDecodeError, ValueError) as e:
        raise ValueError(f"--fleet {path}: not a readable JSON file ({e})") from None
    if not isinstance(entries, list) or not entries:
        raise ValueError(f"--fleet {path}: expected a non-empty JSON list of vehicles")
    fleet = []
    for i, e in enumerate(entries):
        try:
            v = FleetVehicle(str(e["name"]), int(e["instance"]), int(e["seed"]),
                             tuple(float(x) for x in e["home"]))  # fmt: skip
            ok = (len(v.home) == 3 and all(math.isfinite(x) for x in v.home) and v.instance >= 0
                  and v.name.isidentifier() and v.instance == e["instance"] and v.seed == e["seed"])  # fmt: skip
        except (TypeError, KeyError, ValueError):
            ok = False
        if not ok:
            raise ValueError(f"--fleet {path}: vehicle {i} is not {ENTRY}")
        if len(v.home) != 3 or not home_in_range(*v.home):
            raise ValueError(
                f"--fleet {path}: vehicle {i}: latitude, longitude or altitude out of range"
            )
        fleet.append(v)
    for attr in ("name", "instance"):
        values = [getattr(v, attr) for v in fleet]
        if len(set(values)) != len(values):
            raise ValueError(f"--fleet {path}: two vehicles with the same {attr}")
    return fleet


def open_fleet(params: WorldParams, endpoint, fleet: list[FleetVehicle], run_dir: Path,
               faults: Callable[[int], object]) -> list[World]:  # fmt: skip
    """One World per vehicle (its instance, seed and home over `params` and `endpoint`, the
    fault plan `faults(seed)`), writing into run_dir/<name>/. ValueError naming the vehicle
    (every world opened so far closed) if one cannot start."""
    from skyherd.world.sim import World

    worlds: list[World] = []
    try:
        for v in fleet:
            d = run_dir / v.name
            d.mkdir(exist_ok=True)
            p = dataclasses.replace(params, instance=v.instance, seed=v.seed, home=v.home)
            cfg = dataclasses.replace(endpoint, instance=v.instance)
            worlds.append(World(p, run_dir=d, endpoint_config=cfg, faults=faults(v.seed)))
    except (OSError, ValueError) as e:
        for w in worlds:
            w.close()
        hint = (
            f"; is another vehicle using instance {v.instance}?" if isinstance(e, OSError) else ""
        )
        raise ValueError(f"--fleet {v.name}: {e}{hint}") from None
    return worlds


def sim_groups(K: int, sims: int) -> list[list[int]]:
    """Vehicles 0..K-1 shared among `sims` simulator processes (0: one per CPU core, at most K),
    in contiguous groups whose sizes differ by at most one."""
    n = sims if sims > 0 else max(1, min(K, os.cpu_count() or 1))
    base, extra = divmod(K, n)
    groups, k = [], 0
    for g in range(n):
        size = base + (1 if g < extra else 0)
        groups.append(list(range(k, k + size)))
        k += size
    return groups
