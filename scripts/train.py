"""`skyherd train`: not built yet (see the open issues)."""

from __future__ import annotations

import argparse


def add_arguments(parser: argparse.ArgumentParser) -> None:
    pass


def run(args: argparse.Namespace) -> int:
    print("skyherd train is not built yet")
    return 1
