"""`skyherd transfer RUN`: the transfer table of a finished `skyherd train irl|ab` run folder
(policy/evaluate.py): its learners' best policies and the baselines on the composite scenario
and every groundsim UGV behaviour, written to transfer.md and transfer.csv in the folder."""

from __future__ import annotations

import argparse
from pathlib import Path

from skyherd.scripts.cli import UsageError, usage


def add_arguments(parser: argparse.ArgumentParser) -> None:
    from skyherd.policy.evaluate import TRANSFER_SEED

    parser.add_argument("run", type=Path, help="a finished train irl / train ab run folder")
    parser.add_argument("--episodes", type=int, default=10,
                        help="episodes per policy and scenario (default: %(default)s)")  # fmt: skip
    parser.add_argument("--seed", type=int, default=TRANSFER_SEED,
                        help="first episode seed (default: %(default)s)")  # fmt: skip


def run(args: argparse.Namespace) -> int:
    from skyherd.policy.evaluate import write_transfer

    if args.episodes < 1:
        raise UsageError(f"--episodes {args.episodes}: give at least 1")
    table = usage(write_transfer, args.run, args.episodes, args.seed)
    print(table)
    return 0
