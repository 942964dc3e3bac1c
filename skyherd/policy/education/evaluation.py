"""The evaluation protocol of `skyherd educate`: educated policies on episodes never trained on.

`compare` tests every policy (the educated ones, those of earlier training runs, the ideal
scripted expert) on the composite scenario (seeds 300000+) and the groundsim UGV behaviours
(seeds 200000+, policy.evaluate's transfer seeds); `fidelity_totals` sums the explanation
fidelity (policy.education.fidelity) over the educated policies; `decision_episode` flies one
composite test episode and returns one decisions.jsonl record per decision, in the companion's
format (safety.supervisor.Decision.record) with no safety net: proposed = certified, verdict
"none". `evaluate_run` does all of it for an educate run's seeds.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from skyherd.flight.autopilot_api import Setpoint
from skyherd.policy.demos import ExpertParams, rollout_stats, scripted_expert
from skyherd.policy.dqn import load_policy
from skyherd.policy.education.fidelity import decision_observations, fidelity
from skyherd.policy.evaluate import TRANSFER_SEED
from skyherd.policy.groundair.env import GroundAirEnv
from skyherd.safety.supervisor import Decision, Mode, Severity
from skyherd.task.params import action_velocity_ned

EVAL_SCENARIOS = ("composite", "groundsim:route", "groundsim:speedoff", "groundsim:camouflage")
COMPOSITE_SEED = 300_000  # first seed of the composite test episodes
NO_NET = "gymnasium evaluation: no safety net"

# {learner: {scenario: [(seed or name, metrics)]}}
Comparison = dict[str, dict[str, list[tuple[Any, dict[str, float]]]]]


def eval_seed(scenario: str) -> int:
    """First environment seed of a scenario's test episodes."""
    return COMPOSITE_SEED if scenario == "composite" else TRANSFER_SEED


def run_policies(folder: Path) -> dict[str, list[tuple[str, Any]]]:
    """learner → [(file stem, policy)] of a training run folder's policies/*.npz."""
    out: dict[str, list] = {}
    for f in sorted((folder / "policies").glob("*.npz")):
        pol = load_policy(f)
        out.setdefault(str(pol.meta.get("learner", f.stem)), []).append((f.stem, pol))
    return out


def compare(educated: dict[int, Any], baselines: list[Path], episodes: int,
            gamma: float) -> Comparison:  # fmt: skip
    """Every policy on `episodes` test episodes of each EVAL_SCENARIOS scenario: the educated
    ones (seed → policy), each learner of the `baselines` run folders (labelled with the folder
    when there are several) and the ideal scripted expert."""
    learners: dict[str, list] = {"educated": list(educated.items())}
    for b in baselines:
        for k, v in run_policies(b).items():
            label = f"{k} [{b.name}]" if len(baselines) > 1 else k
            learners.setdefault(label, []).extend(v)
    out: Comparison = {
        name: {sc: [(s, rollout_stats(pol, sc, episodes, eval_seed(sc), gamma)[1])
                    for s, pol in pols] for sc in EVAL_SCENARIOS}
        for name, pols in learners.items()
    }  # fmt: skip
    out["expert (ideal)"] = {  # a fresh expert (its own random generator) per scenario
        sc: [("ideal", rollout_stats(scripted_expert("composite", ExpertParams(), 0), sc, episodes,
                                     eval_seed(sc), gamma)[1])] for sc in EVAL_SCENARIOS
    }  # fmt: skip
    return out


def best_seed(comparison: Comparison) -> int:
    """The educated seed with the highest composite all-in-view fraction (the first on a tie)."""
    return max(comparison["educated"]["composite"], key=lambda kv: kv[1]["all_in_view_frac"])[0]


def fidelity_totals(educated: dict[int, Any], episodes: int) -> dict[str, dict[str, Any]]:
    """Explanation fidelity per concept role, summed over the educated policies' decisions on
    `episodes` composite test episodes: counts, rates, and the near action rate per seed."""
    keys = ("n", "action_changed", "module_changed", "action_changed_far")
    total: dict[str, dict[str, Any]] = {}
    for pol in educated.values():
        obs = decision_observations(pol, "composite", episodes, COMPOSITE_SEED)
        for role, r in fidelity(pol, obs).items():
            t = total.setdefault(role, dict.fromkeys(keys, 0) | {"per_seed": []})
            for k in keys:
                t[k] += r[k]
            t["per_seed"].append(r["action_rate"] if r["n"] else math.nan)
    for t in total.values():
        t["action_rate"] = t["action_changed"] / max(t["n"], 1)
        t["module_rate"] = t["module_changed"] / max(t["n"], 1)
        t["action_rate_far"] = t["action_changed_far"] / max(t["n"], 1)
    return total


def decision_record(t: float, action: int, vel_ned, phi, explanation: dict) -> dict[str, Any]:
    """One decision of a gymnasium episode as the companion records it, with no safety net."""
    sp = Setpoint(vel_ned=np.asarray(vel_ned, float), yaw=0.0)
    d = Decision(command=sp, mode=Mode.AI, severity=Severity.NONE, reason=NO_NET,
                 autopilot_mode="-", ai_rejected=False, t=t, proposed=sp)  # fmt: skip
    rec = d.record(vehicle="uav0", pilot="policy", phi=phi, autopilot_mode="-",
                   explanation=explanation, action=action)  # fmt: skip
    return rec | {"verdict": "none"}  # no net judged it: neither accepted nor changed


def decision_episode(pol, seed: int = COMPOSITE_SEED) -> list[dict[str, Any]]:
    """One composite test episode of `pol` (an explaining policy), one record per decision."""
    env = GroundAirEnv("composite")
    obs, info = env.reset(seed=seed)
    out, done = [], False
    while not done:
        ex = pol.explain(obs)
        a = pol(obs)
        v = action_velocity_ned(a, env.task.uav)
        out.append(decision_record(env.steps * env.task.dt_s, a, v, info["phi"],
                                   {k: ex[k] for k in ("module", "reason", "concepts")}))  # fmt: skip
        obs, _, term, trunc, info = env.step(a)
        done = term or trunc
    return out


@dataclass(frozen=True, eq=False)
class RunEvaluation:
    """An educate run's evaluation: its educated policies (seed → policy) beside the rest."""

    educated: dict[int, Any]
    comparison: Comparison
    fidelity: dict[str, dict[str, Any]]
    best_seed: int
    decisions: list[dict[str, Any]]  # one composite test episode of the best seed's policy


def evaluate_run(
    results: list[dict[str, Any]],
    policy_dirs: dict[int, Path],
    baselines: list[Path],
    episodes: int,
    gamma: float,
) -> RunEvaluation:
    """The educated policy of every seed of `results` (policy_dirs[seed]/educated_seed<s>.npz)
    on `episodes` unseen episodes per scenario beside the `baselines` runs' policies; each
    seed's last lesson result gets the arbiter it learnt (detail "arbiter")."""
    educated = {
        r["seed"]: load_policy(policy_dirs[r["seed"]] / f"educated_seed{r['seed']}.npz")
        for r in results
    }
    for r in results:  # the arbiter each seed learnt (also when read back from lessons.csv)
        r["educated"][-1]["detail"]["arbiter"] = educated[r["seed"]].arbiter.describe()
    comparison = compare(educated, baselines, episodes, gamma)
    fid = fidelity_totals(educated, episodes)
    best = best_seed(comparison)
    return RunEvaluation(educated, comparison, fid, best, decision_episode(educated[best]))


def write_evaluation(folder: Any, results: list[dict[str, Any]], ev: RunEvaluation) -> None:
    """An educate run's evaluation `ev` of `results` (evaluate_run) into the run folder
    `folder` (runio.runfolder.RunFolder): decisions.jsonl (one composite test episode of the
    best seed's policy) and results.json."""
    import json

    from skyherd.runio.runfolder import JsonlWriter, atomic_write_text

    w = JsonlWriter(folder.file("decisions.jsonl"))
    w.write_many(ev.decisions)
    w.close()
    atomic_write_text(folder.file("results.json"), json.dumps(
        {"lessons": results, "comparison": ev.comparison, "fidelity": ev.fidelity}, indent=1,
        default=float))  # fmt: skip
