"""`skyherd train irl` / `skyherd train ab`: apprenticeship learning on the GroundAir composite
task (policy/irl_experiment.py: irl, μ_E from composite demonstrations; ab, Apprenticeship
Bootstrapping from sub-task demonstrations, one run per combination rule, IRL beside it unless
--no-irl). The run folder gets config.json, demos/, metrics.csv (per learner, seed and IRL
iteration), events.jsonl, summary.md (tables), PNG plots and policies/*.npz.
"""

from __future__ import annotations

import argparse
import sys
from dataclasses import dataclass
from pathlib import Path

from skyherd.report import irl as report
from skyherd.runio import RunFolder
from skyherd.scripts.cli import apply_quick, quick_help, save_copy, usage
from skyherd.scripts.options import add_options, opt

# --quick: a budget that shows the whole pipeline in under a minute of CPU (DQN steps above
# learning_starts, so something is learnt); any option given on the command line wins.
QUICK = {
    "seeds": 1, "dqn_steps": 3000, "irl_iters": 2, "demo_episodes": 4, "mu_episodes": 4,
    "eval_episodes": 5, "transfer_episodes": 0,
}  # fmt: skip


@dataclass(frozen=True)
class IrlOptions:
    """The options of `skyherd train irl|ab` (scripts.options: one field, one option)."""

    seeds: int = 5  # training seeds
    seed: int = 0  # first seed
    dqn_steps: int = 15_000  # env steps per DQN solve
    irl_iters: int = 6  # max projection-IRL iterations
    epsilon: float = 0.01  # IRL stop: t <= epsilon
    gamma: float = 0.97  # discount of μ and DQN
    demo_episodes: int = 20  # demo episodes per scenario
    demo_epsilon: float = 0.05  # expert random-action prob
    demo_lag: float = 0.05  # expert repeat-action prob
    demos: Path | None = None
    """folder of recorded demos (<scenario>.npz, e.g. from skyherd teleop) instead of the
    scripted expert"""
    mu_episodes: int = 20  # Monte-Carlo episodes per μ(π)
    eval_episodes: int = 30  # test episodes per policy
    transfer_episodes: int = 10  # episodes per groundsim behaviour for the transfer table (0: skip)
    workers: int = 1  # parallel training processes
    runs_dir: Path = opt(Path("runs"), aliases=("--out",))
    """where run folders go; --out is the older name"""
    save_policy: Path | None = None
    """also copy the best learned policy of this learner to this file"""


def add_arguments(parser: argparse.ArgumentParser, learner: str) -> None:
    add_options(parser, IrlOptions)
    quick = ", ".join(f"--{k.replace('_', '-')} {v}" for k, v in QUICK.items())
    parser.add_argument(
        "--quick", action="store_true",
        help=quick_help(f"about 45 s of CPU for ab: {quick}"),
    )  # fmt: skip
    if learner == "ab":
        from skyherd.policy.ab import RULES

        parser.add_argument("--rules", default=",".join(RULES), help="AB combination rules")
        parser.add_argument("--no-irl", action="store_true", help="skip the IRL comparison runs")
    parser.set_defaults(learner_name=learner)


def run(args: argparse.Namespace) -> int:
    import matplotlib

    matplotlib.use("Agg")
    from skyherd.policy.irl_experiment import ExperimentParams, budget_warnings, recorded_demos

    quick = apply_quick(args, QUICK, getattr(args, "_argv", None))  # the options it set
    p = usage(ExperimentParams.of, args, args.learner_name)
    warnings = budget_warnings(p, QUICK["dqn_steps"])
    for w in warnings:
        print(f"skyherd train {p.learner}: warning: {w}", file=sys.stderr)
    demos, demo_files = usage(recorded_demos, args.demos, p)  # before the run folder
    with RunFolder.open(f"train-{p.learner}", args, root=args.runs_dir) as run:
        print(f"run folder: {run.path}")
        return _train(run, args, p, demos, demo_files, quick, warnings)


def _train(run, args, p, demos, demo_files, quick, warnings) -> int:
    """The experiment (policy.irl_experiment.run_in_folder) with its bars, then its report."""
    from tqdm import tqdm

    from skyherd.policy import irl_experiment as X

    print(f"experiment (seed of the hyper-parameters varies per run): {p}")
    run.config(args={k: v for k, v in vars(args).items() if not k.startswith("_")},
               demo_files=demo_files, quick=quick, warnings=warnings)  # fmt: skip
    n_jobs = p.seeds * len(p.learners)
    # the bar counts IRL iterations (each a DQN solve), so it moves during a run of a learner
    bar = run.closing(tqdm(total=n_jobs * args.irl_iters, desc=f"train {p.learner}",
                           unit="iter", disable=None))  # fmt: skip
    ticks: dict[tuple[str, int], int] = {}

    def on_iteration(learner: str, seed: int, t: float) -> None:
        ticks[(learner, seed)] = ticks.get((learner, seed), 0) + 1
        bar.update(1)
        bar.set_postfix(run=f"{learner}/{seed}", t=f"{t:.3g}")

    def on_result(r, done) -> None:
        # IRL may stop before --irl-iters: count the rest as done
        bar.update(max(0, args.irl_iters - ticks.get((r.learner, r.seed), 0)))
        bar.set_postfix(last=f"{r.learner}/{r.seed} view={r.metrics['all_in_view_frac']:.3f}")
        run.summary(report.progress_note(len(done), n_jobs))

    run.summary(report.progress_note(0, n_jobs))
    out = X.run_in_folder(run, p, demos, args.workers, args.transfer_episodes, on_iteration,
                          on_result, tqdm, progress=bar.disable is False)  # fmt: skip
    bar.close()
    table = report.write(run, [r.facts() for r in out.runs], out.baselines, p.learner, args,
                         warnings, quick, out.transfer)  # fmt: skip
    print(table)
    if args.save_policy is not None:
        r = out.best[p.main_learner]
        save_copy(r.labelled_policy(), args.save_policy, f"{p.main_learner} seed {r.seed}")
    print(f"summary: {run.path / 'summary.md'}")
    return 0
