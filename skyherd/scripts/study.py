"""`skyherd study search|shepherd`: skyherd's own studies, each into a run folder (config.json,
table.md = summary.md, episodes.csv, and the shepherding study's figure).

- search: re-acquiring a lost UGV on the speed-off and camouflage scenarios, unseen seeds, the
  scripted expert and the kept policy, each without and with the search (docs/search.md);
- shepherd: the learned selector against Strömbom's hand-written shepherd on the same seeds
  (docs/shepherding.md).
"""

from __future__ import annotations

import argparse
from pathlib import Path

from skyherd.scripts.cli import UsageError, usage

STUDIES = {
    "search": "re-acquiring a lost UGV (speed-off, camouflage): expert and policy ± the search",
    "shepherd": "aerial shepherding: the learned selector against Strömbom's on the same seeds",
}


def add_arguments(parser: argparse.ArgumentParser) -> None:
    sub = parser.add_subparsers(dest="study", metavar="STUDY", required=True)
    s = sub.add_parser("search", help=STUDIES["search"], description=STUDIES["search"])  # fmt: skip
    s.add_argument(
        "--episodes", type=int, default=50, help="episodes per (pilot, scenario) (default 50)"
    )
    s.add_argument("--first-seed", type=int, default=400_000,
                   help="first episode seed (default 400000: unseen in training)")  # fmt: skip
    h = sub.add_parser("shepherd", help=STUDIES["shepherd"], description=STUDIES["shepherd"])  # fmt: skip
    h.add_argument("--seeds", type=int, default=100, help="episodes per selector (default 100)")
    h.add_argument("--first-seed", type=int, default=0, help="first seed (default 0)")
    h.add_argument("--selector-file", default=None,
                   help="the learned selector (default: the kept selector.json)")  # fmt: skip
    h.add_argument("--agents", type=int, default=10,
                   help="flock size N (default 10: the learned selector was fitted on N = 10 only)")  # fmt: skip
    h.add_argument("--neighbours", type=int, default=None,
                   help="agents in each one's local centre of mass (default: 6 for N = 10, N - 1 for "
                   "other N: 6 lets a larger flock split)")  # fmt: skip
    for p in (s, h):
        p.add_argument(
            "--runs-dir", type=Path, default=Path("runs"), help="where the run folder goes"
        )


def run(args: argparse.Namespace) -> int:
    from skyherd.runio.runfolder import RunFolder, args_dict

    if getattr(args, "episodes", 1) < 1 or getattr(args, "seeds", 1) < 1:
        raise UsageError("--episodes / --seeds must be >= 1")
    if args.study == "shepherd" and args.agents < 2:
        raise UsageError(f"--agents {args.agents}: a flock has at least 2 agents")
    folder = RunFolder(f"study-{args.study}", root=args.runs_dir)
    folder.write_config(args_dict(args))
    print(f"skyherd study {args.study}: run folder {folder.path}", flush=True)
    table = _search(args, folder.path) if args.study == "search" else _shepherd(args, folder.path)
    folder.write_summary(f"# skyherd study {args.study}\n\n{table}\n")
    print(table)
    print(f"skyherd study {args.study}: table.md, episodes.csv in {folder.path}")
    return 0


def _search(args, out: Path) -> str:
    from skyherd.policy.search import study

    return study.table(study.run(args.episodes, args.first_seed, out))


def _shepherd(args, out: Path) -> str:
    from skyherd.policy.shepherd import study
    from skyherd.policy.shepherd.rules import ShepherdParams
    from skyherd.report.shepherd import plot_shepherd

    flock = usage(study.study_flock, args.agents, args.neighbours)
    eps: dict = {}
    rows = study.run(args.seeds, args.first_seed, out, args.selector_file, flock, episodes=eps)
    sels = study.selectors(args.selector_file)
    plot_shepherd(eps, ShepherdParams(), flock, out / "shepherd_study.png", args.first_seed, sels)
    return f"flock: N = {flock.n}, {flock.neighbours} neighbours\n\n{study.table(rows)}"
