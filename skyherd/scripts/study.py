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

from skyherd.scripts.cli import UsageError

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
    from skyherd.groundsim.flock import FlockParams
    from skyherd.policy.shepherd import study
    from skyherd.policy.shepherd.rules import ShepherdParams
    from skyherd.policy.shepherd.selector import StrombomSelector, make_selector

    d = FlockParams()
    nb = args.neighbours if args.neighbours is not None else (
        d.neighbours if args.agents == d.n else args.agents - 1)  # fmt: skip
    try:
        flock = FlockParams(n=args.agents, neighbours=nb)
    except ValueError as e:
        raise UsageError(str(e)) from None
    eps: dict = {}
    rows = study.run(args.seeds, args.first_seed, out, args.selector_file, flock, episodes=eps)
    sels = {"strombom": StrombomSelector(), "learned": make_selector("learned", args.selector_file)}
    plot_shepherd(eps, ShepherdParams(), flock, out / "shepherd_study.png", args.first_seed, sels)
    return f"flock: N = {flock.n}, {flock.neighbours} neighbours\n\n{study.table(rows)}"


def plot_shepherd(eps, task, flock, path: Path, seed: int, sels) -> None:
    """Left: the fraction of episodes with the flock at the goal against time, per selector;
    right: seed `seed`'s shepherd and flock-centre tracks with the goal region."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    import numpy as np

    from skyherd.policy.shepherd.episode import run_episode

    fig, (a, b) = plt.subplots(1, 2, figsize=(11, 4.6))
    t = np.linspace(0, task.limit_s, 401)
    for name, es in eps.items():
        times = np.array([e.time_to_goal_s if e.success else np.inf for e in es])
        a.plot(t, [(times <= x).mean() for x in t], label=name)
    a.set_xlabel("time [s]")
    a.set_ylabel("fraction of episodes with the flock at the goal")
    a.grid(alpha=0.3)
    a.legend()
    for name, sel in sels.items():
        ep = run_episode(seed, sel, flock, task, keep_track=True)
        tr = np.array(ep.track)
        b.plot(tr[:, 2], tr[:, 1], lw=0.8, label=f"{name}: shepherd")
        b.plot(tr[:, 4], tr[:, 3], lw=1.6, label=f"{name}: flock centre")
    b.add_patch(plt.Circle(task.goal_ne[::-1], task.goal_radius_m, color="g", alpha=0.2,
                           label="goal"))  # fmt: skip
    b.set_xlabel("east [m]")
    b.set_ylabel("north [m]")
    b.set_aspect("equal")
    b.set_title(f"seed {seed}")
    b.legend(fontsize=7)
    fig.tight_layout()
    fig.savefig(path, dpi=90)
    plt.close(fig)
