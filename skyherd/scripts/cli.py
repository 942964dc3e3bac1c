"""`skyherd` console script: one sub-command per module in `scripts/`.

Each sub-command module exposes `add_arguments(parser)` and `run(args) -> int`.
Exit codes: 0 success, 1 the job ran and failed, 2 bad usage or configuration.
"""

from __future__ import annotations

import signal

_EARLY: list[int] = []  # signals that came while this process imported its modules
_EARLY_SIGNALS = (signal.SIGINT, signal.SIGTERM, signal.SIGHUP)


def _keep_early(signum: int, _frame) -> None:
    _EARLY.append(signum)


if __name__ == "__main__":  # `python -m skyherd.scripts.cli` (fly's children, the tests): a signal
    for _sig in _EARLY_SIGNALS:  # during the imports is kept and acted on in `main`
        signal.signal(_sig, _keep_early)

import argparse  # noqa: E402
import importlib  # noqa: E402
import os  # noqa: E402
import re  # noqa: E402
import sys  # noqa: E402
from typing import NoReturn  # noqa: E402

if sys.argv[1:2] == ["fly"]:  # `fly` runs OpenBLAS as its children do (runio.launch.CHILD_ENV),
    os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")  # set before numpy loads it: ~0.1 CPU s

from skyherd.runio.constants import API_REMOTE_BASE, LOOPBACK, ZENOH_BASE  # noqa: E402

# name → (module, one-line help). Modules are imported only when their command runs,
# so `skyherd --help` stays fast and one broken sub-command cannot break the others.
COMMANDS: dict[str, tuple[str, str]] = {
    "sitl": ("skyherd.scripts.sitl", "run one simulated vehicle with its MAVLink endpoints"),
    "fly": ("skyherd.scripts.fly", "fly a mission end to end (the main job)"),
    "sim": ("skyherd.scripts.sim", "the world: vehicle, UGV team and camera on one clock"),
    "companion": (
        "skyherd.scripts.companion",
        "the onboard computer: camera → policy → safety net → MAVLink",
    ),
    "drill": ("skyherd.scripts.drill", "geofence and envelope-violation drills"),
    "train": ("skyherd.scripts.train", "train the learners (sql, irl, ab)"),
    "teleop": ("skyherd.scripts.teleop", "fly or demonstrate from the keyboard"),
    "watch": ("skyherd.scripts.watch", "watch a flight's camera frames with detections"),
    "certs": (
        "skyherd.scripts.certs",
        "certificates and Zenoh configurations of a closed two-host flight",
    ),
    "record": ("skyherd.scripts.record", "flight.mcap (Foxglove, PlotJuggler) from a run folder"),
    "educate": (
        "skyherd.scripts.educate",
        "teach a curriculum of lessons; a modular policy that explains",
    ),
    "evaluate": (
        "skyherd.scripts.evaluate",
        "the pre-registered evaluation of educated policies (100 fresh composite episodes)",
    ),
    "explain": (
        "skyherd.scripts.explain",
        "a run's decisions as a readable timeline (module, reason, net)",
    ),
    "transfer": (
        "skyherd.scripts.transfer",
        "a train irl/ab run's policies on the groundsim UGV behaviours (transfer.md)",
    ),
    "camstream": (
        "skyherd.scripts.camstream",
        "a frame source on its own: UGVs on a route and a hovering UAV's camera on Zenoh",
    ),
    "reproduce": ("skyherd.scripts.reproduce", "reproduce a published study in one command (sql)"),
    "study": (
        "skyherd.scripts.study",
        "skyherd's own studies: the lost-UGV search, aerial shepherding",
    ),
}


# name → examples shown under each sub-command's --help (each one parses: tests/scripts/test_cli_conventions.py)
EXAMPLES: dict[str, tuple[str, ...]] = {
    "sitl": (f"skyherd sitl --speedup 1    # one quadrotor in real time; MAVSDK: udpin://{LOOPBACK}:{API_REMOTE_BASE}",
             "skyherd sitl --airframe fixedwing --instance 1 --personality ardupilot"),
    "fly": ("skyherd fly --speedup 0    # make run: the main job, as fast as the machine goes",
            "skyherd fly --speedup 0 --wind 5 --fault gps_glitch@30:20,0,0:5 --cut-link 40:2",
            "skyherd fly --airframe fixedwing --speedup 0    # the orbit over the team",
            f"skyherd fly --connect udpin:{LOOPBACK}:{API_REMOTE_BASE}    # an outside PX4 SITL"),
    "sim": ("skyherd sim --speedup 10 --free-run    # the world alone, not waiting for a companion",),
    "companion": (f"skyherd companion --connect udpin:{LOOPBACK}:{API_REMOTE_BASE} --free-run    # beside `skyherd sitl`",),
    "drill": ("skyherd drill    # every named drill of the quadrotor",
              "skyherd drill --airframe all --campaign 100 --seed 98",
              "skyherd drill --airframe fixedwing --campaign 1000 --drill 664    # one drill of it again"),
    "train": ("skyherd train sql --quick", "skyherd train ab --quick"),
    "teleop": ("skyherd teleop --episodes 2    # keyboard; demonstrations into runs/",),
    "watch": ("skyherd watch --instance 0 --frames 100    # the camera of `skyherd fly --instance 0`",
              "skyherd watch --signing-key runs/<run>/signing.key    # only the flight's authentic frames"),
    "certs": ("skyherd certs --router-host 192.168.1.10 --out flight-tls",),
    "record": ("skyherd record runs/20261206T045157Z-fly    # flight.mcap from a run folder",),
    "educate": ("skyherd educate --quick    # a smoke run of the default curriculum",),
    "evaluate": ("skyherd evaluate runs/T-educate/educated_seed0.npz --ab skyherd/policy/models/groundair_ab.npz",),
    "explain": ("skyherd explain runs/20261206T045157Z-fly --t 30    # what the policy did at t = 30 s",),
    "transfer": ("skyherd transfer runs/T-train-ab --episodes 10    # transfer.md in that folder",),
    "camstream": (f"skyherd camstream --frames 100 --rate 30    # listens on tcp/{LOOPBACK}:{ZENOH_BASE}; then skyherd watch",),
    "reproduce": ("skyherd reproduce sql --quick", "skyherd reproduce sql --rules published intended"),
    "study": ("skyherd study search --episodes 50    # the lost-UGV search, 50 unseen episodes each",
              "skyherd study shepherd --seeds 100 --agents 20"),
}  # fmt: skip


QUICK_MEANING = (
    "a smoke run: the whole job on a small budget (minutes of CPU at most), to see "
    "it work, not for results"
)  # --quick in every command that has it


def quick_help(sets: str) -> str:
    """--quick's help: its one meaning, what it sets, and that an option given wins."""
    return f"{QUICK_MEANING}: {sets}; an option given on the command line wins"


def apply_quick(args: argparse.Namespace, budget: dict, argv: list[str] | None = None) -> list[str]:
    """With --quick, `budget`'s value for every option not given on the command line (`argv`,
    else args._argv, else sys.argv); returns the options it set, as "--flag value"."""
    if not getattr(args, "quick", False):
        return []
    given = set(argv if argv is not None else getattr(args, "_argv", None) or sys.argv[1:])
    changed = []
    for k, v in budget.items():
        flag = f"--{k.replace('_', '-')}"
        if not any(a == flag or a.startswith(flag + "=") for a in given):
            setattr(args, k, v)
            shown = " ".join(map(str, v)) if isinstance(v, list | tuple) else v
            changed.append(f"{flag} {shown}")
    return changed


def examples_epilog(lines: tuple[str, ...]) -> str:
    return "examples:\n" + "\n".join(f"  {ln}" for ln in lines)


from skyherd.runio.process import exit_now  # noqa: E402
from skyherd.runio.run import Interrupted, RunAborted, UsageError  # noqa: E402  (one definition, in runio)

__all__ = ["COMMANDS", "UsageError", "build_parser", "main"]


class DefaultsFormatter(argparse.RawDescriptionHelpFormatter):
    """Every option's help ends with its default, unless the help already states it as
    "(default X)" (flags and options whose default is None show none); the description and the
    examples under it keep their lines."""

    def _get_help_string(self, action: argparse.Action) -> str:
        text = action.help or ""
        d = action.default
        if (
            not action.option_strings
            or d is None
            or d is argparse.SUPPRESS
            or (isinstance(d, list | tuple | str) and len(d) == 0)  # nothing to show
            or action.nargs == 0  # store_true / store_false / count-like flags
            or "%(default)" in text
            or re.search(r"\(default:? [^)]+\)", text)
        ):
            return text
        shown = " ".join(map(str, d)) if isinstance(d, list | tuple) else str(d)
        # already said in the text ("default 1: ..."), or marked where it belongs: never twice
        if re.search(rf"\bdefault:? {re.escape(shown)}\b", text):
            return text
        if "(default)" in text:  # "PX4 modes (default) or ...": the value where it is marked
            return text.replace("(default)", f"(default: {shown})", 1)
        if f"({shown})" in text:  # the older "(value)" convention
            return text.replace(f"({shown})", f"(default: {shown})")
        return f"{text} (default: {shown})".strip()


class Parser(argparse.ArgumentParser):
    """The parser of `skyherd` and of every sub-command (sub-parsers are made of this class,
    so every level shows its defaults)."""

    def __init__(self, *a, **kw):
        kw.setdefault("formatter_class", DefaultsFormatter)
        super().__init__(*a, **kw)
        self.set_defaults(_parser=self)  # the deepest parser that matched reports errors

    def add_argument(self, *a, **kw):
        action = super().add_argument(*a, **kw)
        if (
            not action.help
            and action.option_strings
            and action.nargs != 0
            and action.default is not None
        ):
            action.help = "(default: %(default)s)"  # no help text: still its default
        return action


class CheckParser(Parser):
    """A parser that raises UsageError (its one-line message) instead of printing its usage and
    exiting: how a parent checks a child's argument list with the child's own parser."""

    def error(self, message: str) -> NoReturn:
        raise UsageError(message)


def check_with(prog: str, add_arguments, check, argv: list[str]) -> str | None:
    """Parse `argv` with the parser `add_arguments` builds and run `check(args)` on it, starting
    nothing: None if it passes, else the one-line reason (`scripts.sim.check_args`)."""
    parser = CheckParser(prog=prog)
    add_arguments(parser)
    try:
        check(parser.parse_args(argv))
    except UsageError as e:
        return " ".join(str(e).split())  # one line, whatever the check said
    return None


def usage(fn, *args):
    """`fn(*args)`, its ValueError (a bad option's one-line reason) a UsageError: exit 2."""
    try:
        return fn(*args)
    except ValueError as e:
        raise UsageError(str(e)) from None


def save_copy(policy, path, what: str) -> None:
    """--save-policy: `policy` (anything with save(path)) also at `path`, its folder made."""
    path.parent.mkdir(parents=True, exist_ok=True)
    policy.save(path)
    print(f"saved {what} policy → {path}")


class _Version(argparse.Action):
    """--version: the package version and the code's git commit (looked up only when asked)."""

    def __init__(
        self, option_strings, dest=argparse.SUPPRESS, default=argparse.SUPPRESS, help=None
    ):
        super().__init__(option_strings, dest=dest, default=default, nargs=0, help=help)

    def __call__(self, parser, namespace, values, option_string=None):
        from skyherd.runio.provenance import code_version

        v = code_version()
        commit = v.get("git_commit")
        extra = (
            f" (git {commit[:12]}{', modified' if v.get('git_dirty') else ''})" if commit else ""
        )
        print(f"skyherd {v.get('package_version') or 'unknown'}{extra}")
        parser.exit(0)


def build_parser(only: str | None = None) -> argparse.ArgumentParser:
    parser = Parser(
        prog="skyherd",
        description="skyherd: one UAV keeps a group of UGVs in view, behind a safety net.",
    )
    parser.add_argument("--version", action=_Version, help="print the version and exit")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    for name, (module_name, help_text) in COMMANDS.items():
        p = sub.add_parser(name, help=help_text, description=help_text,
                           epilog=examples_epilog(EXAMPLES[name]) if name in EXAMPLES else None)  # fmt: skip
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
    args, extra = parser.parse_known_args(argv)
    if extra:  # a typo in a sub-command's option: that sub-command's usage, not the top one
        args._parser.error(f"unrecognized arguments: {' '.join(extra)}")
    if getattr(args, "_module", None) is None:
        parser.print_help()
        return 2
    args._argv = list(argv)  # the command line as given (config.json, --quick)
    signum = _early_signal()
    if signum is not None:
        from skyherd.runio.signals import interrupted

        rc, why = interrupted(Interrupted(signum))
        print(f"skyherd {args.command}: INTERRUPTED: {why} before it started; nothing was done",
              file=sys.stderr)  # fmt: skip
        return rc
    try:
        return int(args._module.run(args) or 0)
    except UsageError as e:
        print(f"skyherd {args.command}: {e}", file=sys.stderr)
        return 2
    except RunAborted as e:
        print(f"skyherd {args.command}: {e}", file=sys.stderr)
        return 1
    except KeyboardInterrupt as e:
        from skyherd.runio.signals import interrupted

        rc, why = interrupted(e)
        print(f"skyherd {args.command}: INTERRUPTED: {why}", file=sys.stderr)
        return rc


def _early_signal() -> int | None:
    """The first signal kept while `python -m skyherd.scripts.cli` imported its modules (None: none);
    the usual handlers are back from here on (SIGINT: KeyboardInterrupt; others: default)."""
    if signal.getsignal(signal.SIGINT) is _keep_early:
        for sig in _EARLY_SIGNALS:
            h = signal.default_int_handler if sig == signal.SIGINT else signal.SIG_DFL
            signal.signal(sig, h)
    return _EARLY[0] if _EARLY else None


def skyherd_cmd(*args: str) -> list[str]:
    """A sub-command of this installation's `skyherd`, as a child process's argv (the children
    of `skyherd fly`: runio.launch)."""
    return [sys.executable, "-m", "skyherd.scripts.cli", *args]


def console() -> NoReturn:
    """The `skyherd` console script (pyproject [project.scripts]): `main`, then `exit_now`."""
    exit_now(main())


if __name__ == "__main__":  # the children of `skyherd fly` (skyherd_cmd)
    exit_now(main())
