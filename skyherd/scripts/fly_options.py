"""The formation's and the orbit's options of `skyherd fly`, kept apart from their missions so
that `skyherd fly` (the ground-air default) imports neither mission's code to parse its line."""

from __future__ import annotations

from skyherd.runio.constants import GCS_REMOTE_PORT

AGENT_CHOICES = (1, 4, 9, 16)


def add_formation_arguments(group) -> None:
    """Options of the formation mission (added to `skyherd fly` in an argument group)."""
    group.add_argument("--agents", type=int, choices=AGENT_CHOICES, default=9,
                       help="K: vehicles and formation targets (1, 4, 9 or 16; default 9; 1 needs --policy-file); "
                       "the vehicles are instances N, N+1, ... with N = --instance, skipping 10 (PX4 layout: its "
                       f"companion port is the ground stations' {GCS_REMOTE_PORT})")  # fmt: skip
    group.add_argument(
        "--sql-seed",
        type=int,
        default=0,
        help="seed of the in-process SQL-SIE training (default 0)",
    )
    group.add_argument(
        "--cell-m", type=float, default=2.0, help="grid cell size on the field [m] (default 2)"
    )
    group.add_argument("--sims", type=int, default=0, metavar="G",
                       help="simulator processes the K vehicles are shared among (1..K; default 0: one per "
                       "CPU core, at most K): each steps its vehicles in turn, each vehicle in lockstep with "
                       "the companion, so the flight is the same for any G")  # fmt: skip
    group.add_argument("--policy-file", default=None,
                       help="a plan_K<K>.json from `skyherd train sql` (default: train SQL-SIE in-process, "
                       "10,000 episodes, a few seconds)")  # fmt: skip


def add_orbit_arguments(group) -> None:
    """The orbit's options (all prefixed --orbit-, so they sit beside the other missions')."""
    group.add_argument("--orbit-scenario", choices=["lateral", "composite"], default="lateral",
                       help="UGV team behaviour (policy.groundair.scenarios), default lateral")  # fmt: skip
    group.add_argument("--orbit-duration", type=float, default=None,
                       help="established orbit time before landing [s] (default 90)")  # fmt: skip
    group.add_argument(
        "--orbit-no-land", action="store_true", help="end in the orbit instead of landing"
    )
