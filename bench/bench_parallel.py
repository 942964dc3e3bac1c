"""The parent's cost of handing out many jobs (runio.parallel.map_unordered, the drill campaign's
runner): this tree against a baseline revision's runio/parallel.py, alternated in one run.

    .venv/bin/python bench/bench_parallel.py [--jobs 2000 8000 20000] [--baseline 3ba8649]
                                             [--backend process|ray] [--workers 2]

The jobs are trivial (x -> x*x), so what is measured is the bookkeeping a campaign of 10^5
drills pays on top of its drills: the parent's CPU time (time.process_time) and the wall time
per job count, each count run by the baseline then this tree (and the next count the other way
round). The baseline's module is taken from git (`git show REV:skyherd/runio/parallel.py`) into
a temporary folder. Prints a table and the ratio baseline / this tree of the parent's CPU.
"""

from __future__ import annotations

import argparse
import importlib.util
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from skyherd.runio import parallel
from skyherd.runio.runfolder import markdown_table

ROOT = Path(__file__).resolve().parents[1]


def square(x: int) -> int:
    return x * x


def baseline_module(rev: str, folder: Path):
    src = subprocess.run(["git", "show", f"{rev}:skyherd/runio/parallel.py"], cwd=ROOT,
                         capture_output=True, text=True, check=True).stdout  # fmt: skip
    path = folder / "parallel_baseline.py"
    path.write_text(src)
    spec = importlib.util.spec_from_file_location("parallel_baseline", path)
    module = importlib.util.module_from_spec(spec)
    sys.modules["parallel_baseline"] = module
    spec.loader.exec_module(module)
    return module


def cost(module, n: int, backend: str, workers: int) -> tuple[float, float]:
    c0, w0 = time.process_time(), time.monotonic()
    got = sum(
        1 for _ in module.map_unordered(square, range(n), backend, workers, say=lambda s: None)
    )
    assert got == n, (got, n)
    return time.process_time() - c0, time.monotonic() - w0


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--jobs", type=int, nargs="+", default=[2000, 8000, 20000],
                    help="job counts (default 2000 8000 20000)")  # fmt: skip
    ap.add_argument("--baseline", default="3ba8649",
                    help="git revision of the baseline (default 3ba8649: all jobs submitted at once)")  # fmt: skip
    ap.add_argument("--backend", default="process", choices=("process", "ray"),
                    help="default process")  # fmt: skip
    ap.add_argument("--workers", type=int, default=2, help="default 2")
    args = ap.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        base = baseline_module(args.baseline, Path(tmp))
        rows = []
        for i, n in enumerate(args.jobs):
            order = (("baseline", base), ("this", parallel))
            got = {}
            for name, module in order if i % 2 == 0 else order[::-1]:
                got[name] = cost(module, n, args.backend, args.workers)
            (bc, bw), (tc, tw) = got["baseline"], got["this"]
            rows.append([n, f"{bc:.2f}", f"{bw:.2f}", f"{tc:.2f}", f"{tw:.2f}", f"{bc / tc:.1f}x"])
            print(f"{n} jobs done", file=sys.stderr, flush=True)
    print(markdown_table(["jobs", f"{args.baseline}: parent CPU s", "wall s", "this: parent CPU s",
                          "wall s", "CPU baseline / this"], rows))  # fmt: skip


if __name__ == "__main__":
    main()
