"""The README's figures (`python -m skyherd.scripts.figures`, `make figures`): which figure comes
from which command, the manifest docs/figures/figures.json (for every figure the command that
drew it, its SHA-256, when and at what load), the README's block between `<!-- figures:begin -->`
and `<!-- figures:end -->` written from it, and headless Chromium's screenshots of report.html.
tests/test_docs.py checks that every figure the README shows is listed with its hash."""

from __future__ import annotations

import hashlib
import json
import os
import re
import shutil
import subprocess
import sys
import tempfile
import time
from collections.abc import Callable
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
OUT = ROOT / "docs" / "figures"
MANIFEST = "figures.json"
BEGIN, END = "<!-- figures:begin -->", "<!-- figures:end -->"
MAIN_JOB = ("fly", "--speedup", "0")  # `make run`
FAILED = ("fly", "--speedup", "0", "--duration", "20", "--fault", "disarm@25")
DRAWN = {  # figure in docs/figures → (command, the run folder's file, what it shows)
    "groundair.png": (MAIN_JOB, "groundair.png", "the flight on one time axis"),
    "frames.png": (MAIN_JOB, "frames.png", "the companion's camera frames, annotated"),
}
SHOTS = {  # screenshot in docs/figures → (command, what it shows)
    "report_run.png": (MAIN_JOB, "report.html of `make run` in headless Chromium"),
    "report_failed.png": (
        FAILED,
        "report.html of a flight the judge fails (forced disarm in the air) in headless Chromium",
    ),  # fmt: skip
}


def command_text(argv: tuple[str, ...]) -> str:
    return "skyherd " + " ".join(argv)


def chromium() -> str | None:
    return shutil.which("chromium") or shutil.which("chromium-browser")


def screenshot(page: Path, png: Path, size=(1280, 2300)) -> None:
    """A page rendered by headless Chromium into `png` (RuntimeError if it could not)."""
    exe = chromium()
    if exe is None:
        raise RuntimeError("no chromium on this machine (Debian: apt-get install chromium)")
    r = subprocess.run([exe, "--headless", "--no-sandbox", "--disable-gpu", "--hide-scrollbars",
                        f"--screenshot={png}", f"--window-size={size[0]},{size[1]}", page.as_uri()],
                       capture_output=True, text=True, timeout=180)  # fmt: skip
    if r.returncode != 0 or not png.exists():
        raise RuntimeError(f"chromium: exit {r.returncode}: {r.stderr[-300:]}")


def sha256(path: Path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest()


def readme_block(manifest: dict) -> str:
    """The README's figures block, from figures.json (module docstring)."""
    lines = [BEGIN, f"Produced by `python -m skyherd.scripts.figures` (`make figures`) on "
             f"{manifest['date']} on a {manifest['cores']}-core machine at load "
             f"{manifest['load']}; each figure's command is on the line above it "
             f"(docs/figures/{MANIFEST} has its SHA-256).", ""]  # fmt: skip
    for name, f in manifest["figures"].items():
        lines += [f"<!-- figure: {f['command']} -->",
                  f"![{f['what']}](docs/figures/{name})", ""]  # fmt: skip
    return "\n".join(lines + [END])


def write_readme(manifest: dict, readme: Path = ROOT / "README.md") -> None:
    text = readme.read_text(encoding="utf-8")
    block = readme_block(manifest)
    if BEGIN in text and END in text:
        text = re.sub(re.escape(BEGIN) + r".*?" + re.escape(END), lambda _: block, text, flags=re.S)
    else:
        text = text.rstrip() + "\n\n## Figures\n\n" + block + "\n"
    readme.write_text(text, encoding="utf-8")


def manifest(figures: dict, out: Path) -> dict:
    """figures.json's content: every figure's entry with the SHA-256 of its file in `out`,
    the date, the machine's load and cores."""
    for name, f in figures.items():
        f["sha256"] = sha256(out / name)
    return {"date": time.strftime("%Y-%m-%d %H:%M UTC", time.gmtime()),
            "load": round(os.getloadavg()[0], 1), "cores": os.cpu_count(),
            "figures": figures}  # fmt: skip


def make_figures(out: Path, fly: Callable[[tuple[str, ...], Path], Path]) -> dict:
    """Fly MAIN_JOB and FAILED (`fly(argv, runs folder)`: `skyherd fly` as a user runs it; its
    run folder), copy the DRAWN figures of their run folders into `out`, screenshot their SHOTS (when Chromium is there; said on stderr when
    not) and write `out`/figures.json; returns the manifest."""
    out.mkdir(parents=True, exist_ok=True)
    figures = {}
    with tempfile.TemporaryDirectory() as tmp:
        runs = {}
        for argv in (MAIN_JOB, FAILED):
            print(f"figures: {command_text(argv)}", flush=True)
            runs[argv] = fly(argv, Path(tmp) / "runs")
        for name, (argv, src, what) in DRAWN.items():
            shutil.copyfile(runs[argv] / src, out / name)
            figures[name] = {"command": command_text(argv), "file": src, "what": what,
                             "check": "bytes"}  # fmt: skip
        for name, (argv, what) in SHOTS.items():
            try:
                screenshot(runs[argv] / "report.html", out / name)
            except RuntimeError as e:
                print(f"figures: no {name}: {e}", file=sys.stderr)
                continue
            figures[name] = {"command": command_text(argv), "file": "report.html", "what": what,
                             "check": "recorded"}  # fmt: skip
    made = manifest(figures, out)
    (out / MANIFEST).write_text(json.dumps(made, indent=1) + "\n", encoding="utf-8")
    return made
