"""`skyherd educate CURRICULUM`: teach a curriculum lesson by lesson; a modular policy that explains.

Each seed's course is policy/education/course.py's (teach.py: the lessons; a monolithic DQN
taught the same lessons beside it unless --no-monolith), its evaluation on unseen test episodes
policy/education/evaluation.py's, with --baselines RUN the policies of a `skyherd train ab` run.
Run folder: config.json (curriculum name/version/sha256, hyper-parameters), lessons.csv (every
lesson's re-test after every lesson, per learner and seed), events.jsonl, policies/*.npz,
decisions.jsonl (`skyherd explain RUN`), lessons.png, compare.png, results.json, summary.md.
"""

from __future__ import annotations

import argparse
from dataclasses import dataclass
from pathlib import Path

from skyherd.report import educate as report
from skyherd.runio.runfolder import RunFolder, args_dict
from skyherd.scripts.cli import UsageError, quick_help, save_copy, usage
from skyherd.scripts.options import add_options, opt


@dataclass(frozen=True)
class EducateOptions:
    """The options of `skyherd educate` (scripts.options: one field, one option)."""

    seeds: int = 5  # training seeds
    seed: int = 0  # first seed
    dqn_steps: int | None = None  # env steps per DQN solve (default 6000)
    irl_iters: int | None = None  # IRL iterations per lesson (default 1)
    test_episodes: int | None = None  # episodes per lesson re-test (default 10)
    eval_episodes: int = 10  # unseen episodes per scenario in the comparison
    baselines: tuple[Path, ...] = opt((), action="append")
    """a `skyherd train ab|irl` run folder whose policies to compare, repeatable (default none)"""
    no_monolith: bool = False  # skip the monolithic DQN
    monolith_seeds: int | None = None
    """teach the monolithic DQN on the first N seeds only (default all)"""
    workers: int = 1  # parallel seeds
    runs_dir: Path = Path("runs")  # where run folders go
    from_run: tuple[Path, ...] | None = opt(None, action="append")
    """skip teaching: report on an earlier educate run's lessons.csv and policies (e.g. with
    --baselines that finished later); repeatable: runs of the same curriculum and
    hyper-parameters on different seeds are reported together (default none)"""
    save_policy: Path | None = None
    """also copy the best educated policy (composite test) to this file"""


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("curriculum", type=Path, nargs="?", default=None,
                        help="curriculum TOML (default policy/education/curricula/groundair.toml)")  # fmt: skip
    add_options(parser, EducateOptions)
    parser.add_argument("--quick", action="store_true",
                        help=quick_help("policy.education.teach.QUICK's DQN steps, IRL iterations "
                                        "and test episodes"))  # fmt: skip


def run(args: argparse.Namespace) -> int:
    import matplotlib

    matplotlib.use("Agg")
    from tqdm import tqdm

    from skyherd.policy.education import course
    from skyherd.policy.education.curriculum import (
        DEFAULT_CURRICULUM,
        CurriculumError,
        load_curriculum,
    )
    from skyherd.policy.education.teach import curriculum_meta, params_of

    path = args.curriculum or DEFAULT_CURRICULUM
    try:
        cur = load_curriculum(path)
    except CurriculumError as e:
        raise UsageError(f"{e}; fix the curriculum file") from None
    if args.seeds < 1 or args.workers < 1 or args.eval_episodes < 1:
        raise UsageError("need --seeds >= 1, --workers >= 1, --eval-episodes >= 1")
    for b in args.baselines:
        if not (b / "policies").is_dir():
            raise UsageError(f"--baselines {b}: no policies/ folder (a `skyherd train ab` run)")
    if args.from_run is not None:
        return _report_only(args, cur)
    p = usage(params_of, args)
    rf = RunFolder("educate", root=args.runs_dir)
    print(f"skyherd educate: run folder {rf.path}")
    if cur.composite is not None and cur.composite.method == "measures":
        print(f"skyherd educate: arbiter objective {p.measures.describe()}")
    rf.write_config(
        {"curriculum": curriculum_meta(cur), "hyper_parameters": p, "args": args_dict(args)}
    )
    with tqdm(total=args.seeds, desc="educate", unit="seed") as bar:

        def on_seed(out) -> None:
            bar.update(1)
            bar.set_postfix_str(
                f"seed {out['seed']}: {out['educated'][-1]['detail'].get('arbiter', '')}"[:60]
            )

        results = course.teach_into(rf, path, p, args.seeds, args.seed, args.monolith_seeds,
                                    args.workers, on_seed)  # fmt: skip
    return _report(cur, p, args, results, {r["seed"]: rf.path / "policies" for r in results}, rf)


def _report_only(args, cur) -> int:
    """--from-run: the evaluation part of `run` on earlier runs' policies and lessons.csv."""
    from skyherd.policy.education.course import read_finished_runs

    try:
        done = read_finished_runs(args.from_run, cur.sha256)
    except ValueError as e:
        raise UsageError(f"--from-run {e}") from None
    rf = RunFolder("educate", root=args.runs_dir)
    srcs = [str(x) for x in args.from_run]
    print(f"skyherd educate: run folder {rf.path} (report on {', '.join(srcs)})")
    rf.write_config({"curriculum": done.curriculum, "hyper_parameters": done.params,
                     "args": args_dict(args), "from_run": srcs[0] if len(srcs) == 1 else srcs})  # fmt: skip
    return _report(cur, done.params, args, done.results, done.policy_dirs, rf)


def _report(cur, p, args, results, pol_dirs: dict[int, Path], rf) -> int:
    """pol_dirs: seed → the policies/ folder of its run."""
    from skyherd.policy.education.evaluation import evaluate_run, write_evaluation

    print("evaluating on unseen episodes …")
    ev = evaluate_run(results, pol_dirs, args.baselines, args.eval_episodes, p.dqn.gamma)
    write_evaluation(rf, results, ev)  # decisions.jsonl, results.json
    summary = report.summary(cur, p, args, results, ev.comparison, ev.fidelity, rf)
    rf.write_summary(summary)
    report.plots(rf, results, ev.comparison)
    if args.save_policy is not None:
        save_copy(ev.educated[ev.best_seed], args.save_policy, f"educated seed {ev.best_seed}")
    print(summary)
    return 0
