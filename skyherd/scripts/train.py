"""`skyherd train {sql,irl,ab,abs-dl,shepherd}`: each learner's command lives in its own module."""

from __future__ import annotations

import argparse
import importlib

LEARNERS: dict[str, tuple[str, str]] = {
    "sql": (
        "skyherd.scripts.train_sql",
        "Swarm Q-learning / SQL-SIE formation-control experiments",
    ),
    "irl": (
        "skyherd.scripts.train_irl",
        "apprenticeship learning by projection IRL on composite demos",
    ),
    "ab": ("skyherd.scripts.train_irl", "Apprenticeship Bootstrapping from sub-task demos only"),
    "abs-dl": (
        "skyherd.scripts.train_absdl",
        "ABS-DL: deep sub-task networks fused, continuous actions, shielded by the safety net",
    ),
    "shepherd": (
        "skyherd.scripts.train_shepherd",
        "the shepherd's learned selector (collect / drive) from Strömbom's demonstrations",
    ),
}


EXAMPLES: dict[str, tuple[str, ...]] = {
    "sql": ("skyherd train sql --quick    # a smoke run: K = 4, 2000 episodes",
            "skyherd train sql --experiment compare --agents 9 16 --seeds 0 1 2"),
    "irl": ("skyherd train irl --quick",),
    "ab": ("skyherd train ab --quick", "skyherd train ab --save-policy ab.npz"),
    "abs-dl": ("skyherd train abs-dl --quick --save-policy absdl.npz",),
    "shepherd": ("skyherd train shepherd --out /tmp/selector.json    # the kept file stays as it is",),
}  # fmt: skip


def add_arguments(parser: argparse.ArgumentParser) -> None:
    from skyherd.scripts.cli import examples_epilog

    sub = parser.add_subparsers(dest="learner", metavar="LEARNER", required=True)
    for name, (module_name, help_text) in LEARNERS.items():
        p = sub.add_parser(name, help=help_text, description=help_text,
                           epilog=examples_epilog(EXAMPLES[name]))  # fmt: skip
        module = importlib.import_module(module_name)
        module.add_arguments(p, learner=name)
        p.set_defaults(_learner_module=module)


def run(args: argparse.Namespace) -> int:
    return int(args._learner_module.run(args) or 0)
