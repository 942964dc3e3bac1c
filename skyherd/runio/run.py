"""A run's lifecycle: the folder appears when the command first writes to it (never for a usage
error), config.json says how to repeat it, and summary.md always says how it ended.

    with RunFolder.open("watch", args, root=args.runs_dir) as run:
        run.config(zenoh=params)                   # merged into config.json
        metrics = run.metrics([...])               # closed at the end, whatever happens
        run.at_end(lambda: plot(run))              # plots from what was recorded, on any ending
        ...
        run.summary(table)                         # the body of summary.md
        if nothing_arrived:
            run.fail("no frame arrived")           # the job ran and failed (exit 1)

Endings written at the top of summary.md:
  completed                 the block finished
  failed: <reason>          the block called run.fail
  aborted: <Error>: <text>  an exception left the block (traceback in error.txt; re-raised)
  interrupted (Ctrl-C)      KeyboardInterrupt (re-raised)
A `UsageError` (bad usage or configuration, exit 2) removes a folder that holds nothing but
what this module wrote. While the run is going, summary.md says "running", so a folder left by
a kill -9 says that too.
"""

from __future__ import annotations

import datetime as dt
import json
import shutil
import signal
import time
import traceback
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any

from skyherd.runio.decisions import DecisionLog
from skyherd.runio.provenance import code_version, command_line
from skyherd.runio.runfolder import (
    CsvWriter,
    JsonlWriter,
    RunFolder,
    atomic_write_text,
    to_jsonable,
    versions,
)
from skyherd.runio.space import RESERVE_BYTES, free_bytes


class UsageError(Exception):
    """Bad usage or configuration: reported on one line, exit code 2, no run folder."""


class Interrupted(KeyboardInterrupt):
    """A signal that ends a run as Ctrl-C does (SIGINT, SIGTERM, SIGHUP); exit 128 + signum."""

    def __init__(self, signum: int):
        self.signum = int(signum)
        self.name = signal.Signals(signum).name
        super().__init__(f"interrupted ({self.name})")


class RunAborted(Exception):
    """Marks an exception that ended a run (`run_path` holds the folder with its summary)."""


MIN_FREE_BYTES = 2 * RESERVE_BYTES  # a flight starts only with this much free [bytes]


def open_run_folder(command: str, root: Path | str) -> RunFolder:
    """The flight's run folder under `root`; UsageError (exit 2, nothing started) when it cannot
    be written or its disk is nearly full."""
    free = free_bytes(root) if Path(root).exists() else None
    if free is not None and free < MIN_FREE_BYTES:
        raise UsageError(f"--runs-dir {root}: {free // 1024} KiB free, a flight needs at least "
                         f"{MIN_FREE_BYTES // 1024} KiB for its records: free some space or pass "
                         "another --runs-dir")  # fmt: skip
    try:
        return RunFolder(command, root=root)
    except OSError as e:
        raise UsageError(f"--runs-dir {root}: cannot make the run folder ({e.strerror or e}): "
                         "pass a writable --runs-dir") from None  # fmt: skip


def given_or_new_run_folder(command: str, run_dir: str | None, root: Path | str):
    """(`run_dir`, None): the folder `skyherd fly` made for its children (UsageError unless it
    is a folder), or a new run folder of `command` under `root` (open_run_folder): (its path,
    it)."""
    if run_dir is None:
        folder = open_run_folder(command, root)
        return folder.path, folder
    if not Path(run_dir).is_dir():
        raise UsageError(f"--run-dir {run_dir} is not a folder")
    return Path(run_dir), None


FILE_NOTES = {
    "config.json": "everything needed to repeat the run (command line, arguments, code commit, versions, input files with SHA-256)",
    "summary.md": "how the run ended, the results, this list",
    "error.txt": "the traceback of the error that aborted the run",
    "events.jsonl": "safety-net events (switches with their reasons), one JSON object per line",
    "metrics.csv": "one row per step or frame",
    "decisions.jsonl": "every pilot decision: φ(s), proposed and certified command, verdict, reason, mode",
    "telemetry.tlog": "MAVLink log (pymavlink, MAVExplorer)",
    "flight.mcap": "the flight for Foxglove / PlotJuggler: camera, pose, setpoints, UGVs, φ(s), decisions, events, fence",
}


class Run:
    """One run of a command (see the module docstring). Created by `RunFolder.open`."""

    def __init__(self, command: str, args: Any = None, root: Path | str = "runs",
                 argv: list[str] | None = None, title: str | None = None):  # fmt: skip
        self.command, self.root = command, Path(root)
        self.title = title or f"skyherd {command.replace('-', ' ')}"
        self.argv = argv if argv is not None else getattr(args, "_argv", None)
        self.started = dt.datetime.now(dt.UTC)
        self._t0 = time.monotonic()
        self._folder: RunFolder | None = None
        self._config: dict[str, Any] = {}
        if args is not None:
            self._config["args"] = {k: to_jsonable(v) for k, v in vars(args).items()
                                    if not k.startswith("_")}  # fmt: skip
        self._body = ""
        self._notes: dict[str, str] = {}
        self._closers: list[Any] = []
        self._finalisers: list[tuple[str, Callable[[], Any]]] = []
        self._failed: str | None = None
        self._code_version: dict[str, Any] | None = None
        self.outcome: str | None = None  # "completed" | "failed" | "aborted" | "interrupted"
        self.reason = ""

    # -- the folder, made on first use -------------------------------------------------
    @property
    def created(self) -> bool:
        return self._folder is not None

    @property
    def path(self) -> Path:
        if self._folder is None:
            self._folder = RunFolder(self.command, root=self.root, now=self.started)
            self._write_config()
            self._write_summary("running", "still running, or the process was killed")
        return self._folder.path

    def file(self, name: str) -> Path:
        return self.path / name

    def describe(self, name: str, note: str) -> None:
        """What a file of the folder holds (listed in summary.md)."""
        self._notes[name] = note

    def config(self, **entries: Any) -> None:
        """Add entries to config.json (written at once if the folder exists)."""
        self._config.update(to_jsonable(entries))
        if self._folder is not None:
            self._write_config()

    def _code(self) -> dict[str, Any]:
        """The code's version, looked up once per run (a git call)."""
        if self._code_version is None:
            self._code_version = code_version()
        return self._code_version

    def _write_config(self) -> None:
        full = {"command": self.command, "command_line": command_line(self.argv),
                "started_utc": self.started.isoformat(timespec="seconds"),
                "code": self._code(), "versions": versions(), **self._config}  # fmt: skip
        atomic_write_text(
            self.path / "config.json",
            json.dumps(full, indent=2, sort_keys=True, default=str) + "\n",
        )

    # -- streams, closed at the end ----------------------------------------------------
    def events(self) -> JsonlWriter:
        return self._keep(JsonlWriter(self.file("events.jsonl")))

    def metrics(self, columns: list[str], name: str = "metrics.csv") -> CsvWriter:
        return self._keep(CsvWriter(self.file(name), columns))

    def decisions(self) -> DecisionLog:
        return self._keep(DecisionLog(self.file("decisions.jsonl")))

    def _keep(self, w):
        self._closers.append(w)
        return w

    def closing(self, obj):
        """Close `obj` (anything with close()) at the end of the run, before the finalisers."""
        return self._keep(obj)

    # -- results and endings -----------------------------------------------------------
    def summary(self, markdown: str) -> None:
        """The body of summary.md (results); the ending is added above it."""
        self._body = markdown
        self._write_summary("running", "still running, or the process was killed")

    def fail(self, reason: str) -> None:
        """The job ran and failed (a drill failed, nothing arrived): ends 'failed: reason'."""
        self._failed = reason

    def at_end(self, fn: Callable[[], Any], name: str = "") -> None:
        """Run `fn` at the end on every ending (plots from what was recorded); an error in it is
        noted in summary.md, never raised."""
        self._finalisers.append((name or getattr(fn, "__name__", "finaliser"), fn))

    def _write_summary(self, outcome: str, reason: str) -> None:
        if self._folder is None:
            return
        wall = time.monotonic() - self._t0
        head = f"**Ended: {outcome}**" + (f": {reason}" if reason else "")
        if outcome == "running":
            head = f"**Running** ({reason})"
        files = sorted(p.name for p in self._folder.path.iterdir() if not p.name.startswith("."))
        files = sorted(set(files) | {"summary.md"})
        rows = "\n".join(f"| `{f}` | {self._notes.get(f, FILE_NOTES.get(f, ''))} |" for f in files)
        md = (f"# {self.title}\n\n{head}\n\n"
              f"Command: `{command_line(self.argv)}`  \n"
              f"Started {self.started.isoformat(timespec='seconds')}, wall time {wall:.1f} s.\n\n"
              f"{self._body.rstrip()}\n\n## Files\n\n| file | what it holds |\n|---|---|\n{rows}\n")  # fmt: skip
        atomic_write_text(self._folder.path / "summary.md", md)

    def _finish(self, outcome: str, reason: str) -> None:
        self.outcome, self.reason = outcome, reason
        for c in self._closers:
            try:
                c.close()
            except Exception:  # noqa: BLE001 - closing must not hide the ending
                pass
        problems = []
        for name, fn in self._finalisers:
            try:
                fn()
            except Exception as e:  # noqa: BLE001 - a broken plot must not hide the ending
                problems.append(f"- {name} failed: {type(e).__name__}: {e}")
        if problems:
            self._body = self._body.rstrip() + "\n\nAt the end:\n" + "\n".join(problems) + "\n"
        self._write_summary(outcome, reason)

    def _discard(self) -> None:
        """After a usage error: remove the folder if it holds only what this module wrote."""
        if self._folder is None:
            return
        own = {"config.json", "summary.md"}
        if {p.name for p in self._folder.path.iterdir()} <= own:
            shutil.rmtree(self._folder.path, ignore_errors=True)
            self._folder = None


@contextmanager
def open_run(command: str, args: Any = None, root: Path | str = "runs", *,
             argv: list[str] | None = None, title: str | None = None) -> Iterator[Run]:  # fmt: skip
    """The lifecycle of one run (module docstring)."""
    run = Run(command, args, root, argv, title)
    try:
        yield run
    except UsageError:
        for c in run._closers:
            try:
                c.close()
            except Exception:  # noqa: BLE001
                pass
        run._discard()
        raise
    except KeyboardInterrupt:
        run.path  # noqa: B018 - an interrupted run always leaves its summary
        run._finish("interrupted", "Ctrl-C")
        raise
    except BaseException as e:
        text = f"{type(e).__name__}: {e}".strip().rstrip(":")
        run.path  # noqa: B018
        atomic_write_text(run.file("error.txt"), "".join(traceback.format_exception(e)))
        run._finish("aborted", text.splitlines()[0] if text else type(e).__name__)
        raise RunAborted(f"aborted: {text}; see {run.path / 'summary.md'}") from e
    else:
        if run._failed is not None:
            run._finish("failed", run._failed)
        elif run.created:
            run._finish("completed", "")
        else:
            run.outcome = "completed"
