"""`skyherd train shepherd`: fit the learned selector from the Strömbom shepherd's demonstrations
(policy.shepherd.selector.train_selector) and write selector.json (docs/shepherding.md)."""

from __future__ import annotations

import argparse
import json
from dataclasses import replace
from pathlib import Path

from skyherd.policy.shepherd.selector import SELECTOR_FILE, SelectorFitParams
from skyherd.runio.runfolder import atomic_write_text
from skyherd.scripts.cli import UsageError


def add_arguments(parser: argparse.ArgumentParser, learner: str = "shepherd") -> None:
    d = SelectorFitParams()
    parser.add_argument(
        "--first-seed", type=int, default=d.seeds[0], help="first demonstration seed"
    )
    parser.add_argument(
        "--episodes",
        type=int,
        default=len(d.seeds),
        help=f"demonstration episodes (default {len(d.seeds)})",
    )
    parser.add_argument(
        "--out", type=Path, default=SELECTOR_FILE, help="the selector file to write"
    )


def run(args: argparse.Namespace) -> int:
    from skyherd.policy.shepherd.selector import train_selector

    if args.episodes < 1:
        raise UsageError(f"--episodes {args.episodes}: at least 1 demonstration episode")
    fit = replace(
        SelectorFitParams(), seeds=tuple(range(args.first_seed, args.first_seed + args.episodes))
    )
    sel, rec = train_selector(fit)
    atomic_write_text(args.out, json.dumps(sel.to_json(**rec), indent=1) + "\n")
    print(f"{args.out}: {rec['demonstrations']} decisions, train accuracy {rec['train_accuracy']}, "
          f"log-loss {rec['log_loss']}")  # fmt: skip
    return 0
