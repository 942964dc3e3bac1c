"""The ABS-DL experiment of `skyherd train abs-dl`, callable without the command line.

Trains ABS-DL (policy.absdl.train: one network per sub-task from sub-task demonstrations, fused
by relevance gating) and the baseline network on composite demonstrations, both shielded by the
flown SafetyNet; with `shield_comparison` also ABS-DL without the shield (to report what the
shield changes); then evaluates them, the noise-free demonstrator and the kept discrete AB
policy on unseen composite episodes, every policy flown through the net (policy.absdl.evaluate).
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable
from pathlib import Path

import numpy as np

from skyherd.policy.absdl.demonstrator import Demonstrator
from skyherd.policy.absdl.evaluate import Score, discrete_actor, evaluate
from skyherd.policy.absdl.params import AbsdlParams
from skyherd.policy.absdl.train import NETWORKS, TrainResult, train, work_units
from skyherd.policy.demos import DemoFileError, load_demo, scripted_expert

N_EVALUATED = 5  # policies evaluated besides ABS-DL trained without the shield


def load_recorded(folder: Path) -> dict:
    """Network name → recorded Demonstration from FOLDER/<name>.npz; ValueError (with what to
    do) on a bad file, a file of another scenario, or none at all."""
    out = {}
    for name in NETWORKS:
        path = folder / f"{name}.npz"
        if not path.exists():
            continue
        try:
            demo = load_demo(path)
        except DemoFileError as e:
            raise ValueError(
                f"{e}; record it again with `skyherd teleop --scenario {name}`"
            ) from None
        if demo.meta["scenario"] != name:
            raise ValueError(
                f"{path} records the {demo.meta['scenario']!r} scenario, not {name!r}: rename it"
            )
        out[name] = demo
    if not out:
        raise ValueError(f"--demos {folder}: no lateral.npz, climb.npz, descend.npz or composite.npz; "
                         "record one with `skyherd teleop --scenario lateral --out DIR/lateral.npz`")  # fmt: skip
    return out


def variants(p: AbsdlParams, shield_comparison: bool) -> list[AbsdlParams]:
    """The trainings: ABS-DL as asked, and without the shield for the comparison."""
    return [p] + ([dataclasses.replace(p, shield=False)] if shield_comparison else [])


def work(p: AbsdlParams, shield_comparison: bool, recorded: dict) -> int:
    """Progress ticks of `train_all` and `evaluate_all` together."""
    trainings = sum(work_units(v, recorded) for v in variants(p, shield_comparison))
    return trainings + (N_EVALUATED + shield_comparison) * p.eval_episodes


def train_all(
    p: AbsdlParams, shield_comparison: bool, recorded: dict, tick: Callable[[str], None]
) -> list[TrainResult]:
    """Every variant trained (`tick(what)` per unit of work)."""
    return [train(v, tick, recorded) for v in variants(p, shield_comparison)]


def evaluate_all(
    p: AbsdlParams, results: list[TrainResult], ab, tick: Callable[[str], None]
) -> list[Score]:
    """The expert, ABS-DL, the composite-demo network, the discrete AB policy `ab`, (ABS-DL
    trained without the shield,) the discrete scripted expert on the same unseen episodes."""
    res = results[0]
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
    if len(results) > 1:
        actors.insert(4, ("ABS-DL trained without shield", results[1].fused, None))
    return [evaluate(n, a, seeds, r, lambda: tick("evaluate")) for n, a, r in actors]


def run_in_folder(
    run, p: AbsdlParams, shield_comparison: bool, recorded: dict, ab, tick: Callable[[str], None]
) -> tuple[list[TrainResult], list[Score]]:
    """The experiment into the run folder `run` (a runio.run.Run): every variant trained, ABS-DL's
    fused policy (absdl_fused.npz) and the composite-demo network (composite_baseline.npz)
    saved and described, then the evaluation; `tick(what)` per unit of `work`."""
    results = train_all(p, shield_comparison, recorded, tick)
    results[0].fused.save(run.file("absdl_fused.npz"))
    results[0].baseline.save(run.file("composite_baseline.npz"))
    run.describe("absdl_fused.npz", "ABS-DL: sub-task networks fused (fly with --policy)")
    run.describe("composite_baseline.npz", "the network trained on composite demonstrations")
    return results, evaluate_all(p, results, ab, tick)
