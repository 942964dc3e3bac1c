"""`skyherd train abs-dl`: Apprenticeship Bootstrapping via deep learning with a safety net
(policy/absdl/experiment.py). Writes the run folder (config.json with the parameters, curves.png,
scores.png, metrics.csv, summary.md, the policy files)."""

from __future__ import annotations

import argparse
import dataclasses
import shutil
from pathlib import Path

from skyherd.scripts.cli import UsageError, apply_quick, quick_help
from skyherd.scripts.options import add_options, field_docs


def add_arguments(parser: argparse.ArgumentParser, learner: str = "abs-dl") -> None:
    from skyherd.policy.absdl.params import QUICK, AbsdlParams
    from skyherd.policy.models import DEFAULT_POLICY

    add_options(parser, AbsdlParams, skip=("hidden",))
    parser.add_argument("--hidden", default=",".join(map(str, AbsdlParams.hidden)),
                        help=field_docs(AbsdlParams)["hidden"] + " (comma-separated)")  # fmt: skip
    parser.add_argument(
        "--shield-comparison", action=argparse.BooleanOptionalAction, default=True,
        help="also train ABS-DL without the shield and report what the net changes (default: on)",
    )  # fmt: skip
    parser.add_argument("--ab-policy", type=Path, default=DEFAULT_POLICY,
                        help="the discrete AB policy to compare with")  # fmt: skip
    parser.add_argument(
        "--demos", type=Path, default=None,
        help="folder of recorded demonstrations <scenario>.npz (lateral, climb, descend, "
        "composite; e.g. from skyherd teleop: keyboard, MANUAL_CONTROL, or --continuous stick "
        "velocities, skyherd-demo/2) used instead of the "
        "scripted demonstrator for the networks they name (default: none)",
    )  # fmt: skip
    parser.add_argument("--runs-dir", type=Path, default=Path("runs"), help="where run folders go")
    parser.add_argument("--save-policy", type=Path, default=None,
                        help="also copy the fused ABS-DL policy to this file")  # fmt: skip
    quick = ", ".join(f"--{k.replace('_', '-')} {v}" for k, v in QUICK.items())
    parser.add_argument("--quick", action="store_true",
                        help=quick_help(f"under a minute of CPU: {quick}"))  # fmt: skip
    parser.set_defaults(learner_name=learner)


def params_from(args: argparse.Namespace):
    """The run's AbsdlParams: the options, with --quick's budget where no option was given (on a
    copy: config.json keeps the options as given)."""
    from skyherd.policy.absdl.params import QUICK, AbsdlParams

    budgeted = argparse.Namespace(**vars(args))
    apply_quick(budgeted, QUICK)
    try:
        return AbsdlParams.of(budgeted)
    except ValueError as e:
        raise UsageError(f"{e}; see `skyherd train abs-dl --help`") from None


def run(args: argparse.Namespace) -> int:
    import matplotlib

    matplotlib.use("Agg")
    from skyherd.policy.absdl.experiment import load_recorded
    from skyherd.policy.dqn import PolicyFileError, load_policy
    from skyherd.runio import RunFolder, file_facts

    p = params_from(args)
    try:
        ab = load_policy(args.ab_policy)
    except PolicyFileError as e:
        raise UsageError(f"{e}; pass --ab-policy FILE (a `skyherd train ab` policy)") from None
    try:
        recorded = {} if args.demos is None else load_recorded(args.demos)
    except ValueError as e:  # a bad file, one of another scenario, none at all
        raise UsageError(str(e)) from None
    print(f"skyherd train abs-dl: {p}")
    if recorded:
        print(f"recorded demonstrations: {', '.join(sorted(recorded))} from {args.demos}")
    with RunFolder.open("train-abs-dl", args, root=args.runs_dir) as run:
        run.config(params=dataclasses.asdict(p))
        print(f"run folder: {run.path}")
        if recorded:
            run.config(demo_files={n: file_facts(args.demos / f"{n}.npz") for n in recorded})
        return _train(run, args, p, ab, recorded)


def _train(run, args, p, ab, recorded) -> int:
    from tqdm import tqdm

    from skyherd.policy.absdl import experiment as X
    from skyherd.report import absdl as report

    total = X.work(p, args.shield_comparison, recorded)
    bar = run.closing(tqdm(total=total, desc="abs-dl", unit="step", disable=None))

    def tick(what: str) -> None:
        bar.set_postfix_str(what, refresh=False)
        bar.update(1)

    results, scores = X.run_in_folder(run, p, args.shield_comparison, recorded, ab, tick)
    bar.close()
    if args.save_policy is not None:
        shutil.copyfile(run.file("absdl_fused.npz"), args.save_policy)
        print(f"saved the fused policy to {args.save_policy}")
    report.plot_curves(results[0].losses, run.file("curves.png"))
    run.describe("curves.png", "training loss per epoch of every fit")
    report.plot_scores(scores, run.file("scores.png"))
    run.describe("scores.png", "evaluation means ± std")
    rows = report.score_rows(scores)
    w = run.metrics(list(rows[0]))
    for row in rows:
        w.write(row)
    text = report.summary(p, scores, X.variants(p, args.shield_comparison), results, recorded)
    run.summary(text)
    print(text)
    return 0
