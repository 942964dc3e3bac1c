"""`skyherd explain RUN_FOLDER [--t SECONDS]`: a run's decisions as a short readable timeline.

Reads RUN_FOLDER/decisions.jsonl (written by `skyherd fly` and by `skyherd educate`'s test
episodes): which module acted, the arbiter's reason in concept terms, the action, and the safety
net's verdict. Consecutive identical decisions are folded into one line. With --t, the decision in
force at that simulation time, with its concept values.
"""

from __future__ import annotations

import argparse
from pathlib import Path

from skyherd.scripts.cli import UsageError


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("run", type=Path, help="a run folder with decisions.jsonl (or the file)")
    parser.add_argument(
        "--t", type=float, default=None, metavar="SECONDS",
        help="show the decision in force at this simulation time [s] in detail (default: all)",
    )  # fmt: skip
    parser.add_argument(
        "--max-lines", type=int, default=200, help="longest timeline printed (default 200)"
    )


def run(args: argparse.Namespace) -> int:
    from skyherd.policy.education.timeline import explain, read_decisions

    path = args.run / "decisions.jsonl" if args.run.is_dir() else args.run
    if not path.is_file():
        raise UsageError(
            f"{path}: no decisions.jsonl; fly with `skyherd fly` or run `skyherd educate`"
        )
    if args.max_lines < 1:
        raise UsageError("--max-lines must be >= 1")
    decisions, bad = read_decisions(path)
    if not decisions:
        raise UsageError(f"{path}: no readable decision records ({bad} unreadable lines)")
    print("\n".join(explain(decisions, bad, args.t, args.max_lines)))
    return 0
