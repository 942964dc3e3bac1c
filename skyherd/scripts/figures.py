"""The README's figures, produced by commands rather than copied by hand (`make figures`,
`python -m skyherd.scripts.figures`).

Flies the main job (`skyherd fly --speedup 0`, what `make run` flies) and a flight the judge
fails (the same with a forced disarm in the air), copies the figures of the first into
docs/figures/, screenshots both run folders' report.html in headless Chromium (when the
machine has it: Debian's `chromium`), and writes docs/figures/figures.json: for every figure
the command that drew it, its SHA-256, when and at what load. The README's block between
`<!-- figures:begin -->` and `<!-- figures:end -->` is rewritten from that file
(`readme_block`), so its words are the script's too. tests/test_docs.py checks that every
figure the README shows is listed with its hash, and re-flies the command to check that the
drawn figures are byte for byte what it draws today.
"""

from __future__ import annotations

import argparse
import os
import subprocess
import sys
from pathlib import Path

from skyherd.report.figures import OUT, ROOT, command_text, make_figures, write_readme


def fly(argv: tuple[str, ...], runs: Path, instance: int) -> Path:
    """One flight of `skyherd fly` (a child process, as a user runs it); its run folder."""
    before = set(runs.iterdir()) if runs.exists() else set()
    cmd = [sys.executable, "-m", "skyherd.scripts.cli", *argv, "--instance", str(instance),
           "--runs-dir", str(runs)]  # fmt: skip
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    r = subprocess.run(cmd, capture_output=True, text=True, env=env, timeout=900)
    made = sorted(set(runs.iterdir()) - before)
    if len(made) != 1:
        raise RuntimeError(f"{command_text(argv)}: exit {r.returncode}, no run folder: "
                           f"{(r.stderr or r.stdout)[-500:]}")  # fmt: skip
    return made[0]


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="python -m skyherd.scripts.figures", description=__doc__,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)  # fmt: skip
    ap.add_argument("--out", type=Path, default=OUT, help="where the figures go (docs/figures)")
    ap.add_argument("--instance", type=int, default=0, help="the flights' vehicle instance N")
    ap.add_argument("--no-readme", action="store_true", help="leave README.md as it is")
    args = ap.parse_args(argv)
    made = make_figures(args.out, lambda argv_, runs: fly(argv_, runs, args.instance))
    if not args.no_readme:
        write_readme(made)
    print(f"figures: {', '.join(made['figures'])} in {args.out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
