"""Not built yet (see the open issues)."""

from __future__ import annotations

import argparse


def add_arguments(parser: argparse.ArgumentParser, learner: str) -> None:
    pass


def run(args: argparse.Namespace) -> int:
    print("not built yet")
    return 1
