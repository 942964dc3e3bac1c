"""`skyherd evaluate EDUCATED.npz... --ab AB.npz`: the pre-registered evaluation of issue 14's
composite goals (policy/education/prereg.py) on 100 fresh episodes, into a run folder:
results.json (the rule, every episode's figures, the summaries, the verdicts) and summary.md
(report/evaluate.py)."""

from __future__ import annotations

import argparse
import json
from pathlib import Path

from skyherd.scripts.cli import UsageError


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("educated", type=Path, nargs="+",
                        help="educated policy .npz files (one per seed; `skyherd educate` writes "
                             "them to RUN/policies/)")  # fmt: skip
    parser.add_argument("--ab", type=Path, required=True, help="the AB policy .npz to compare with")
    parser.add_argument("--runs-dir", type=Path, default=Path("runs"),
                        help="where the run folder goes (default runs)")  # fmt: skip


def run(args: argparse.Namespace) -> int:
    import torch
    from tqdm import tqdm

    from skyherd.policy.education import prereg
    from skyherd.report import evaluate as report
    from skyherd.runio.runfolder import RunFolder, atomic_write_text

    for f in [*args.educated, args.ab]:
        if not f.is_file():
            raise UsageError(f"{f}: no such policy file; `skyherd educate --save-policy` or "
                             "RUN/policies/ of an educate run has them")  # fmt: skip
    torch.set_num_threads(1)
    folder = RunFolder("evaluate", root=args.runs_dir)
    folder.write_config({"educated": [str(f) for f in args.educated], "ab": str(args.ab),
                         "scenario": prereg.SCENARIO, "first_seed": prereg.FIRST_SEED,
                         "episodes": prereg.N_EPISODES, "gamma": prereg.GAMMA})  # fmt: skip
    print(f"skyherd evaluate: run folder {folder.path}", flush=True)
    total = (len(args.educated) + 2) * prereg.N_EPISODES
    with tqdm(total=total, unit="ep", desc="evaluate") as bar:
        res = prereg.evaluate(list(args.educated), args.ab, on_episode=bar.update)
    atomic_write_text(folder.file("results.json"), json.dumps(res, indent=1) + "\n")
    folder.write_summary(report.summary(res, prereg.SCENARIO, len(args.educated)))
    print(report.table(res))
    print(report.verdicts(res))
    print(f"skyherd evaluate: results.json, summary.md in {folder.path}")
    return 0 if all(res["verdicts"].values()) else 1
