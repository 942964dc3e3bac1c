"""`skyherd` console script: one sub-command per module in `scripts/`.

Each sub-command module exposes `add_arguments(parser)` and `run(args) -> int`.
Exit codes: 0 success, 1 the job ran and failed, 2 bad usage or configuration.
"""

from __future__ import annotations

import argparse
import importlib
import sys

# name → (module, one-line help). Modules are imported only when their command runs,
# so `skyherd --help` stays fast and one broken sub-command cannot break the others.
COMMANDS: dict[str, tuple[str, str]] = {
    "sitl": ("scripts.sitl", "run one simulated vehicle with its MAVLink endpoints"),
    "fly": ("scripts.fly", "fly a mission end to end (the main job)"),
    "drill": ("scripts.drill", "geofence and envelope-violation drills"),
    "train": ("scripts.train", "train the learners (sql, irl, ab)"),
    "teleop": ("scripts.teleop", "fly or demonstrate from the keyboard"),
    "watch": ("scripts.watch", "watch a flight's camera frames with detections"),
}


class UsageError(Exception):
    """Bad usage or configuration: reported on one line, exit code 2."""


def build_parser(only: str | None = None) -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="skyherd",
        description="skyherd: one UAV keeps a group of UGVs in view, behind a safety net.",
    )
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    for name, (module_name, help_text) in COMMANDS.items():
        p = sub.add_parser(name, help=help_text, description=help_text)
        if only is None or only == name:
            module = importlib.import_module(module_name)
            module.add_arguments(p)
            p.set_defaults(_module=module)
    return parser


def main(argv: list[str] | None = None) -> int:
    argv = sys.argv[1:] if argv is None else argv
    # Import only the sub-command that runs (or none for the top-level help).
    only = next((a for a in argv if not a.startswith("-")), None)
    if only not in COMMANDS:
        only = None
    parser = build_parser(only if only else "")
    args = parser.parse_args(argv)
    if getattr(args, "_module", None) is None:
        parser.print_help()
        return 2
    try:
        return int(args._module.run(args) or 0)
    except UsageError as e:
        print(f"skyherd {args.command}: {e}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print(f"skyherd {args.command}: interrupted", file=sys.stderr)
        return 130


if __name__ == "__main__":
    sys.exit(main())
