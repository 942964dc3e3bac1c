"""`skyherd record FOLDER`: flight.mcap (Foxglove / PlotJuggler) from a run folder's files
(record.from_run says which); `--also` adds another program's folder of the same flight. For a
live recording see `skyherd watch` and docs/recording.md. Exit codes: 0 written; 1 nothing to
record in the folder; 2 bad usage."""

from __future__ import annotations

import argparse
from pathlib import Path


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("folder", type=Path, help="the run folder (runs/<time>-<command>)")
    parser.add_argument(
        "--also", type=Path, action="append", default=[], metavar="FOLDER",
        help="another folder of the same flight (repeatable)",
    )  # fmt: skip
    parser.add_argument(
        "--out", type=Path, default=None, help="output (default FOLDER/flight.mcap)"
    )
    parser.add_argument("--vehicle", default="uav0", help="vehicle name of the topics")


def run(args: argparse.Namespace) -> int:
    from skyherd.record.from_run import mcap_from_run
    from skyherd.runio import markdown_table
    from skyherd.scripts.cli import UsageError

    for f in [args.folder, *args.also]:
        if not f.is_dir():
            raise UsageError(f"{f} is not a run folder (give runs/<time>-<command>)")
    res = mcap_from_run(args.folder, args.out, also=args.also, vehicle=args.vehicle)
    rows = [[k, n] for k, n in sorted(res.counts.items())]
    rows += [[f"skipped in {k}", n] for k, n in sorted(res.skipped.items())]
    print(markdown_table(["topic", "messages"], rows or [["(none)", 0]]))
    if not res.counts:
        print(f"skyherd record: nothing to record in {args.folder}")
        return 1
    print(f"wrote {res.path}")
    return 0
