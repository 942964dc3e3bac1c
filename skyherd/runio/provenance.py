"""What config.json records so that a run can be repeated and its inputs identified: the code's
git commit (or the package version), the full command line, and files by path and SHA-256."""

from __future__ import annotations

import hashlib
import json
import shlex
import subprocess
import sys
from pathlib import Path
from typing import Any

from skyherd.runio.runfolder import to_jsonable

REPO = Path(__file__).resolve().parents[2]


def sha256_file(path: Path | str) -> str:
    h = hashlib.sha256()
    with open(path, "rb") as f:
        for block in iter(lambda: f.read(1 << 20), b""):
            h.update(block)
    return h.hexdigest()


def file_facts(path: Path | str | None) -> dict[str, Any] | None:
    """{"path": resolved path, "sha256": ..., "bytes": n} of a file; None for None; a missing
    file says so instead of raising (config.json must still be written)."""
    if path is None:
        return None
    p = Path(path).expanduser().resolve()
    if not p.is_file():
        return {"path": str(p), "sha256": None, "error": "no such file"}
    return {"path": str(p), "sha256": sha256_file(p), "bytes": p.stat().st_size}


def envelope_facts(spec: Any) -> dict[str, Any]:
    """A constraint set (safety.envelope.EnvelopeSpec, read by duck typing): name, version, the
    file it came from with its SHA-256, and a hash of its parsed contents (the same for two files
    that differ only in comments)."""
    described = dict(to_jsonable(spec.describe() if hasattr(spec, "describe") else spec))
    described.pop("source", None)  # where it was read from is not what it says
    text = json.dumps(described, sort_keys=True, default=str)
    src = getattr(spec, "source", "")
    return {
        "name": getattr(spec, "name", None),
        "version": getattr(spec, "version", None),
        "content_sha256": hashlib.sha256(text.encode()).hexdigest(),
        "file": file_facts(src) if src and Path(src).is_file() else None,
        "source": src or None,
    }


def code_version(repo: Path = REPO) -> dict[str, Any]:
    """The git commit of the code (and whether the work tree had changes), else the installed
    package version."""
    from importlib import metadata  # here: ~0.05 CPU s that most processes never spend

    out: dict[str, Any] = {}
    try:
        out["package_version"] = metadata.version("skyherd")
    except metadata.PackageNotFoundError:
        out["package_version"] = None
    try:
        commit = subprocess.run(["git", "-C", str(repo), "rev-parse", "HEAD"], capture_output=True,
                                text=True, timeout=10, check=True).stdout.strip()  # fmt: skip
        dirty = subprocess.run(["git", "-C", str(repo), "status", "--porcelain", "--untracked-files=no"],
                               capture_output=True, text=True, timeout=10).stdout.strip()  # fmt: skip
        out["git_commit"], out["git_dirty"] = commit, bool(dirty)
    except (OSError, subprocess.SubprocessError):
        out["git_commit"], out["git_dirty"] = None, None
    return out


def command_line(argv: list[str] | None = None, prog: str = "skyherd") -> str:
    """The command as a user would type it again (shell-quoted)."""
    argv = sys.argv[1:] if argv is None else argv
    return shlex.join([prog, *argv])
