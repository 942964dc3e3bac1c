"""`skyherd train abs-dl`: Apprenticeship Bootstrapping via deep learning with a safety net.

Trains ABS-DL (policy.absdl: one network per sub-task from sub-task demonstrations, fused by
relevance gating) and the baseline network on composite demonstrations, both shielded by the
flown SafetyNet; by default also ABS-DL without the shield (to report what the shield changes);
then evaluates them, the noise-free demonstrator and the kept discrete AB policy on unseen
composite episodes, every policy flown through the net. Writes the run folder (config.json with
the parameters, curves.png, scores.png, metrics.csv, summary.md, the policy files).
"""

from __future__ import annotations

import argparse
import dataclasses
import inspect
import re
import shutil
import sys
from pathlib import Path

from skyherd.scripts.cli import UsageError, quick_help


def _field_help() -> dict[str, str]:
    """The one-line comment beside each AbsdlParams field (its help text)."""
    from skyherd.policy.absdl.params import AbsdlParams

    src = inspect.getsource(AbsdlParams)
    return dict(re.findall(r"^\s+(\w+): [^=]+= [^#]+# (.+)$", src, re.M))


def add_arguments(parser: argparse.ArgumentParser, learner: str = "abs-dl") -> None:
    from skyherd.policy.absdl.params import QUICK, AbsdlParams
    from skyherd.policy.models import DEFAULT_POLICY

    helps = _field_help()
    for f in dataclasses.fields(AbsdlParams):
        flag = "--" + f.name.replace("_", "-")
        if f.type in ("bool", bool):
            parser.add_argument(flag, action=argparse.BooleanOptionalAction, default=f.default,
                                help=helps.get(f.name, "") + f" (default: {'on' if f.default else 'off'})")  # fmt: skip
        elif f.name == "hidden":
            parser.add_argument(flag, default=",".join(map(str, f.default)),
                                help=helps.get(f.name, "") + " (comma-separated)")  # fmt: skip
        else:
            typ = type(f.default)
            parser.add_argument(flag, type=typ, default=f.default, help=helps.get(f.name, ""))
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
    from skyherd.policy.absdl.params import QUICK, AbsdlParams

    given = set(getattr(args, "_argv", None) or sys.argv[1:])
    kw = {}
    for f in dataclasses.fields(AbsdlParams):
        v = getattr(args, f.name)
        flag = "--" + f.name.replace("_", "-")
        if args.quick and f.name in QUICK and not any(a.split("=")[0] == flag for a in given):
            v = QUICK[f.name]
        if f.name == "hidden":
            try:
                v = tuple(int(x) for x in str(v).split(",") if x)
            except ValueError:
                raise UsageError(f"--hidden must be comma-separated widths, got {v!r}") from None
        kw[f.name] = v
    try:
        return AbsdlParams(**kw)
    except ValueError as e:
        raise UsageError(f"{e}; see `skyherd train abs-dl --help`") from None


def run(args: argparse.Namespace) -> int:
    import matplotlib

    matplotlib.use("Agg")
    from skyherd.runio import RunFolder

    p = params_from(args)
    from skyherd.policy.dqn import PolicyFileError, load_policy

    try:
        ab = load_policy(args.ab_policy)
    except PolicyFileError as e:
        raise UsageError(f"{e}; pass --ab-policy FILE (a `skyherd train ab` policy)") from None
    recorded = _recorded(args.demos)
    print(f"skyherd train abs-dl: {p}")
    if recorded:
        print(f"recorded demonstrations: {', '.join(sorted(recorded))} from {args.demos}")
    with RunFolder.open("train-abs-dl", args, root=args.runs_dir) as run:
        run.config(params=dataclasses.asdict(p))
        print(f"run folder: {run.path}")
        if recorded:
            from skyherd.runio import file_facts

            run.config(demo_files={n: file_facts(args.demos / f"{n}.npz") for n in recorded})
        return _train(run, args, p, ab, recorded)


def _recorded(folder: Path | None) -> dict:
    """Network name → recorded Demonstration from FOLDER/<name>.npz (UsageError on bad files)."""
    if folder is None:
        return {}
    from skyherd.policy.absdl.train import NETWORKS
    from skyherd.policy.demos import DemoFileError, load_demo

    out = {}
    for name in NETWORKS:
        path = folder / f"{name}.npz"
        if not path.exists():
            continue
        try:
            demo = load_demo(path)
        except DemoFileError as e:
            raise UsageError(
                f"{e}; record it again with `skyherd teleop --scenario {name}`"
            ) from None
        if demo.meta["scenario"] != name:
            raise UsageError(
                f"{path} records the {demo.meta['scenario']!r} scenario, not {name!r}: rename it"
            )
        out[name] = demo
    if not out:
        raise UsageError(f"--demos {folder}: no lateral.npz, climb.npz, descend.npz or composite.npz; "
                         "record one with `skyherd teleop --scenario lateral --out DIR/lateral.npz`")  # fmt: skip
    return out


def _train(run, args, p, ab, recorded) -> int:
    import numpy as np
    from tqdm import tqdm

    from skyherd.policy.absdl import report
    from skyherd.policy.absdl.demonstrator import Demonstrator
    from skyherd.policy.absdl.evaluate import discrete_actor, evaluate, within
    from skyherd.policy.absdl.train import train, work_units
    from skyherd.policy.demos import scripted_expert

    variants = [p] + ([dataclasses.replace(p, shield=False)] if args.shield_comparison else [])
    n_eval = 5 + (1 if args.shield_comparison else 0)
    total = sum(work_units(v, recorded) for v in variants) + n_eval * p.eval_episodes
    bar = run.closing(tqdm(total=total, desc="abs-dl", unit="step", disable=None))

    def tick(what: str) -> None:
        bar.set_postfix_str(what, refresh=False)
        bar.update(1)

    results = [train(v, tick, recorded) for v in variants]
    res = results[0]
    fused_path, base_path = run.file("absdl_fused.npz"), run.file("composite_baseline.npz")
    res.fused.save(fused_path)
    res.baseline.save(base_path)
    run.describe("absdl_fused.npz", "ABS-DL: sub-task networks fused (fly with --policy)")
    run.describe("composite_baseline.npz", "the network trained on composite demonstrations")
    if args.save_policy is not None:
        shutil.copyfile(fused_path, args.save_policy)
        print(f"saved the fused policy to {args.save_policy}")
    report.plot_curves(res.losses, run.file("curves.png"))
    run.describe("curves.png", "training loss per epoch of every fit")

    seeds = range(p.eval_seed, p.eval_seed + p.eval_episodes)
    expert = Demonstrator("composite", p.demonstrator(noisy=False))
    dexp = scripted_expert("composite")  # the discrete AB's demonstrator, without imperfection
    actors = [
        ("expert (PD, noise-free)", expert, lambda s: expert.reset(np.random.default_rng(s))),
        ("ABS-DL (sub-task demos, fused)", res.fused, None),
        ("composite-demo network", res.baseline, None),
        ("discrete AB (kept file)", discrete_actor(ab), None),
        ("discrete scripted expert", discrete_actor(dexp), None),
    ]
    if args.shield_comparison:
        actors.insert(4, ("ABS-DL trained without shield", results[1].fused, None))
    scores = [evaluate(n, a, seeds, r, lambda: tick("evaluate")) for n, a, r in actors]
    bar.close()
    report.plot_scores(scores, run.file("scores.png"))
    run.describe("scores.png", "evaluation means ± std")
    rows = report.score_rows(scores)
    w = run.metrics(list(rows[0]))
    for row in rows:
        w.write(row)

    ex, fu, ba, di = (s.mean for s in scores[:4])
    checks = [
        ("ABS-DL all-in-view within 2 % of the composite-demo network",
         within(fu["all_in_view_frac"], ba["all_in_view_frac"], 0.02),
         f"{fu['all_in_view_frac']:.3f} vs {ba['all_in_view_frac']:.3f}"),
        ("ABS-DL footprint ratio closer to the expert's than discrete AB's",
         abs(fu["footprint_ratio"] - ex["footprint_ratio"])
         < abs(di["footprint_ratio"] - ex["footprint_ratio"]),
         f"{fu['footprint_ratio']:.2f} vs expert {ex['footprint_ratio']:.2f}, AB {di['footprint_ratio']:.2f}"),
        ("ABS-DL decisions the net changes below 10 %", fu["changed"] < 0.10,
         f"{100 * scores[1].changed / scores[1].decisions:.2f} % vs AB "
         f"{100 * scores[3].changed / scores[3].decisions:.1f} %"),
        ("ABS-DL mean commanded jerk below discrete AB's", fu["jerk_proposed"] < di["jerk_proposed"],
         f"{fu['jerk_proposed']:.2f} vs {di['jerk_proposed']:.2f} m/s³"),
    ]  # fmt: skip
    demo_rows = []
    for v, r in zip(variants, results):
        for name, st in r.demo_shield.items():
            if v.shield:
                demo_rows.append([name, st.decisions, f"{st.changed} ({100 * st.fraction:.2f} %)",
                                  ", ".join(f"{k} {n}" for k, n in sorted(st.verdicts.items()))])  # fmt: skip
    lines = [
        f"ABS-DL on {p.eval_episodes} unseen composite episodes (seeds {p.eval_seed}–"
        f"{p.eval_seed + p.eval_episodes - 1}), every policy flown through the SafetyNet:\n",
        report.score_table(scores),
        "\nMust-show checks:\n",
        report.markdown_table(
            ["check", "holds", "numbers"], [[c, "yes" if ok else "NO", n] for c, ok, n in checks]
        ),  # fmt: skip
        "\nDemonstrations certified by the shield (training data):\n",
        report.markdown_table(["sub-task", "decisions", "net changed", "verdicts"], demo_rows),
        f"\nSamples per network (demos + DAgger): {res.samples}",
        f"\nParameters: `{p}`",
    ]
    if recorded:
        lines.insert(-1, f"\nRecorded demonstrations (no DAgger): {', '.join(sorted(recorded))}")
    text = "\n".join(lines)
    run.summary(text)
    print(text)
    return 0
