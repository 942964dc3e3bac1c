"""Run folders: `runs/<UTC time>-<command>/` with config, events, metrics and plots.

Everything is written so that a kill mid-run leaves what was already written readable:
whole files by write-to-temp-and-rename, streams by append + flush.
"""

from __future__ import annotations

import contextlib
import csv
import dataclasses
import datetime as dt
import enum
import io
import json
import os
import platform
import sys
from pathlib import Path
from typing import Any

import numpy as np

from skyherd.runio.space import Appender, warn


@contextlib.contextmanager
def atomic_file(path: Path, mode: str = "wb", **open_kw):
    """A file opened for writing whole: written to a temporary file beside `path`, synced, then
    renamed over it, so that readers see the old or the new content, never a part. `open_kw`
    go to `open` (encoding, or an `opener` that sets the file's mode as it is made)."""
    path = Path(path)
    tmp = path.with_name(f".{path.name}.tmp{os.getpid()}")
    try:
        with open(tmp, mode, **open_kw) as f:
            yield f
            f.flush()
            os.fsync(f.fileno())
        os.replace(tmp, path)
    except BaseException:  # a full disk, the caller's error, a signal: no temporary file kept
        with contextlib.suppress(OSError):
            tmp.unlink()
        raise


def owner_only(path: str, flags: int) -> int:
    """`open`'s opener for a secret (a key file): made readable and writable by its owner only,
    as it is created (`atomic_file(path, opener=owner_only)`: never a moment readable by others)."""
    return os.open(path, flags, 0o600)


def atomic_write_bytes(path: Path, data: bytes) -> None:
    """Write a whole file so that readers see the old or the new content, never a part."""
    with atomic_file(path) as f:
        f.write(data)


def atomic_write_text(path: Path, text: str) -> None:
    atomic_write_bytes(path, text.encode("utf-8"))


def try_write_text(path: Path, text: str) -> str | None:
    """`atomic_write_text` for a run's end files (summary.md, companion.json, sim_stats.json):
    None when written; on a full disk or a read-only folder, why not (warned on stderr), never
    an exception, so that the flight's ending is still reported."""
    try:
        atomic_write_text(path, text)
    except OSError as e:
        why = f"{path}: not written ({e.strerror or e})"
        warn(why)
        return why
    return None


_LEAVES = frozenset({float, int, str, bool, type(None)})  # plain JSON values, kept as they are


def to_jsonable(obj: Any) -> Any:
    """Dataclasses, enums, numpy values and paths → plain JSON values."""
    t = type(obj)
    if t in _LEAVES:
        return obj  # the common leaf, first (a decision record holds dozens of them)
    if t is np.float64:
        return float(obj)  # the next most common (numpy arithmetic on a vehicle's state)
    # plain dicts and lists (a record's own): their leaves are kept without a call each
    if t is dict:
        return {k if type(k) is str else str(k): v if type(v) in _LEAVES else to_jsonable(v)
                for k, v in obj.items()}  # fmt: skip
    if t is list:
        return [v if type(v) in _LEAVES else to_jsonable(v) for v in obj]
    if dataclasses.is_dataclass(obj) and not isinstance(obj, type):
        return {f.name: to_jsonable(getattr(obj, f.name)) for f in dataclasses.fields(obj)}
    if isinstance(obj, enum.Enum):
        return obj.value if isinstance(obj.value, int | float | str) else obj.name
    if isinstance(obj, dict):
        return {str(k): to_jsonable(v) for k, v in obj.items()}
    if isinstance(obj, list | tuple):
        return [to_jsonable(v) for v in obj]
    if isinstance(obj, np.ndarray):
        return obj.tolist()
    if isinstance(obj, np.generic):
        return obj.item()
    if isinstance(obj, Path):
        return str(obj)
    return obj


def strict_json(obj: Any) -> Any:
    """`to_jsonable`, then NaN and ±inf → None: values that strict JSON readers accept
    (Python's json writes NaN, which Foxglove, jq and browsers reject)."""
    return _finite(to_jsonable(obj))


def _finite(v: Any) -> Any:
    if isinstance(v, float):
        return v if np.isfinite(v) else None
    if isinstance(v, dict):
        return {k: _finite(x) for k, x in v.items()}
    if isinstance(v, list):
        return [_finite(x) for x in v]
    return v


def versions() -> dict[str, str]:
    """Versions of Python and the packages a run depends on (importlib.metadata, imported
    here: ~0.05 CPU s that a process writing no config.json does not spend)."""
    from importlib import metadata

    out = {"python": sys.version.split()[0], "platform": platform.platform()}
    for pkg in (
        "skyherd",
        "numpy",
        "torch",
        "pymavlink",
        "mavsdk",
        "jsbsim",
        "pybullet",
        "opencv-python-headless",
        "eclipse-zenoh",
        "cvxpy",
        "osqp",
        "gymnasium",
        "mcap",
        "foxglove-sdk",
        "pydantic",
    ):
        try:
            out[pkg] = metadata.version(pkg)
        except metadata.PackageNotFoundError:
            pass
    return out


def cut_to_whole_lines(path: Path) -> int:
    """Cut an append-only stream (metrics.csv, events.jsonl) back to its last whole line: a
    kill mid-write can leave part of one. The bytes cut (0: it ended on a whole line)."""
    with open(path, "rb+") as f:
        size = end = f.seek(0, os.SEEK_END)
        while end > 0:
            step = min(1 << 16, end)
            f.seek(end - step)
            nl = f.read(step).rfind(b"\n")
            if nl >= 0:
                end = end - step + nl + 1
                break
            end -= step
        if end < size:
            f.truncate(end)
            f.flush()
            os.fsync(f.fileno())
    return size - end


def filter_jsonl(path: Path, keep) -> int:
    """Rewrite a JSON-lines file (written whole: temporary file, then rename) with the records
    for which `keep(record)` is true; a line that is not JSON goes. The records dropped."""
    dropped = 0
    with open(path, encoding="utf-8") as src, atomic_file(path, "w", encoding="utf-8") as dst:
        for line in src:
            try:
                ok = keep(json.loads(line))
            except ValueError:
                ok = False
            if ok:
                dst.write(line)
            else:
                dropped += 1
    return dropped


class JsonlWriter:
    """Append-only JSON-lines stream, flushed per record (events.jsonl). A full disk or a
    read-only folder cuts it (runio.space: a warning, `appender.dropped` counts the rest)."""

    def __init__(self, path: Path):
        self.path = Path(path)
        self.appender = Appender(self.path)

    def write(self, record: dict[str, Any]) -> None:
        self.write_many([record])

    def write_many(self, records: list[dict[str, Any]]) -> None:
        """Several records, flushed once (a tick's decisions of every vehicle)."""
        self.appender.write(
            "".join(json.dumps(to_jsonable(r), sort_keys=True) + "\n" for r in records)
        )

    def close(self) -> None:
        self.appender.close()


class CsvWriter:
    """Append-only CSV with a fixed header, flushed per row (metrics.csv). A full disk or a
    read-only folder cuts it (runio.space: a warning, `appender.dropped` counts the rest)."""

    def __init__(self, path: Path, columns: list[str]):
        self.path = Path(path)
        self.columns = list(columns)
        new = not self.path.exists() or self.path.stat().st_size == 0
        self.appender = Appender(self.path)
        self._buf = io.StringIO()
        self._w = csv.writer(self._buf)
        if new:
            self._w.writerow(self.columns)
            self._flush()

    def write(self, row: dict[str, Any]) -> None:
        self.write_rows([row])

    def write_rows(self, rows: list[dict[str, Any]]) -> None:
        """Several rows, flushed once (a tick's samples of every vehicle)."""
        for row in rows:  # a key outside the header is left out; a missing column is empty
            self._w.writerow([to_jsonable(row.get(k, "")) for k in self.columns])
        self._flush()

    def write_values(self, values: list) -> None:
        """One row given as its cells in the header's order, plain values (str, int, float, bool
        or None) that are written as they are: no dict, no conversion per cell (world.csv's row
        at every camera instant)."""
        self._w.writerow(values)
        self._flush()

    def _flush(self) -> None:
        self.appender.write(self._buf.getvalue())
        self._buf.seek(0)
        self._buf.truncate()

    def close(self) -> None:
        self.appender.close()


class RunFolder:
    """One run's folder. `config` is written at once and is enough to repeat the run."""

    def __init__(self, command: str, root: Path | str = "runs", now: dt.datetime | None = None):
        now = now or dt.datetime.now(dt.UTC)
        stamp = now.strftime("%Y%m%dT%H%M%SZ")
        base = Path(root) / f"{stamp}-{command}"
        path, n = base, 1
        while path.exists():
            n += 1
            path = base.with_name(f"{base.name}-{n}")
        path.mkdir(parents=True)
        self.path = path
        self.command = command

    @classmethod
    def reopen(cls, path: Path | str) -> RunFolder:
        """An existing run folder, to go on writing in it (a resumed drill campaign)."""
        folder = cls.__new__(cls)
        folder.path = Path(path)
        folder.command = json.loads((folder.path / "config.json").read_text())["command"]
        return folder

    def write_config(self, config: dict[str, Any]) -> Path:
        full = {"command": self.command, "versions": versions(), **to_jsonable(config)}
        p = self.path / "config.json"
        atomic_write_text(p, json.dumps(full, indent=2, sort_keys=True) + "\n")
        return p

    def events(self) -> JsonlWriter:
        return JsonlWriter(self.path / "events.jsonl")

    def metrics(self, columns: list[str]) -> CsvWriter:
        return CsvWriter(self.path / "metrics.csv", columns)

    def write_summary(self, markdown: str) -> Path:
        p = self.path / "summary.md"
        atomic_write_text(p, markdown)
        return p

    def file(self, name: str) -> Path:
        return self.path / name

    @staticmethod
    def open(command: str, args: Any = None, root: Path | str = "runs", **kw: Any):
        """The lifecycle of a run (runio.run): `with RunFolder.open(cmd, args, root) as run:`.
        The folder is made on first use; summary.md says how the run ended."""
        from skyherd.runio.run import open_run

        return open_run(command, args, root, **kw)


MISSING = "—"


def markdown_table(headers: list[str], rows: list[list[Any]], missing: str = "not measured") -> str:
    """A GitHub-style table; also readable as plain text on a terminal.

    A cell that is None or NaN is shown as "—", never as "nan", and a line under the table
    says why (`missing`: e.g. "no decision was made: the run aborted before the hand-over");
    a "|" in a cell is written "\\|", as GitHub escapes it."""
    # a literal pipe in a cell is escaped (GitHub's \|): it would otherwise split the cell
    cells = [[str(h).replace("|", "\\|") for h in headers]]
    cells += [[_fmt(c).replace("|", "\\|") for c in r] for r in rows]
    widths = [max(len(r[i]) for r in cells) for i in range(len(headers))]
    line = lambda r: "| " + " | ".join(c.ljust(w) for c, w in zip(r, widths)) + " |"  # noqa: E731
    sep = "|" + "|".join("-" * (w + 2) for w in widths) + "|"
    out = "\n".join([line(cells[0]), sep] + [line(r) for r in cells[1:]]) + "\n"
    if any(c == MISSING for r in cells[1:] for c in r):
        out += f"\n{MISSING} = {missing}\n"
    return out


def is_missing(c: Any) -> bool:
    """None or a NaN number (a value that was not measured)."""
    if c is None:
        return True
    try:
        return isinstance(c, float | np.floating) and bool(np.isnan(c))
    except TypeError:
        return False


def _fmt(c: Any) -> str:
    if is_missing(c):
        return MISSING
    if isinstance(c, float):
        return f"{c:.3g}" if abs(c) < 1e-3 or abs(c) >= 1e4 else f"{c:.3f}".rstrip("0").rstrip(".")
    return str(c)


def args_dict(args: Any) -> dict[str, Any]:
    """Command-line arguments as a JSON-ready dict (internal `_` entries dropped)."""
    return {k: to_jsonable(v) for k, v in vars(args).items() if not k.startswith("_")}
