"""The AB / IRL experiment of `skyherd train irl|ab`, callable without the command line.

    p = ExperimentParams(learner="ab", rules=("mean",), seeds=1)
    demos = {sc: scripted_demonstration(sc, p) for sc in needed_scenarios(p)}
    runs = run_experiment(p, expert_feature_expectations(p, demos))   # one per learner and seed
    base = {name: baseline_metrics(make, p) for name, make in baseline_factories(p).items()}

Learners: "irl" (μ_E from composite demonstrations, scenario 4) and, for `ab`, "ab_<rule>"
(μ_E^Primitive from the sub-task demonstrations (1)–(3), policy.ab). Each learner runs projection
IRL with DQN (policy.apprentice) once per seed; its chosen policy and the baselines (the
demonstrator, the ideal scripted expert, a random policy) are tested on the same composite
episodes (seeds `eval_seed`+). A run is deterministic for its seed, in this process or in a
worker process (one torch thread per run); results keep the order of the jobs.
"""

from __future__ import annotations

import dataclasses
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from skyherd.policy.ab import RULES, SUBTASKS, combine
from skyherd.policy.apprentice import ApprenticeParams, run_apprenticeship
from skyherd.policy.demos import (
    Demonstration,
    ExpertParams,
    demo_feature_expectations,
    record,
    rollout_stats,
    scripted_expert,
)
from skyherd.policy.dqn import MLPPolicy
from skyherd.policy.evaluate import Factory
from skyherd.policy.evaluate import baseline_factories as reference_factories
from skyherd.policy.groundair.env import PSI_NAMES
from skyherd.policy.irl import IRLIteration

LEARNERS = ("irl", "ab")
METRIC_COLUMNS = ["learner", "seed", "iter", "t", "dist", "seconds"] + [
    f"mu_{n}" for n in PSI_NAMES
]

# the learner, seed and IRL margin t of one finished IRL iteration (progress reports)
OnIteration = Callable[[str, int, float], None]


@dataclass(frozen=True)
class ExperimentParams:
    """Everything one `skyherd train irl|ab` experiment varies (printed, and saved in config.json)."""

    learner: str = "irl"  # "irl" or "ab"
    rules: tuple[str, ...] = ()  # AB combination rules of policy.ab.RULES (learner "ab" only)
    with_irl: bool = True  # ab: also IRL on composite demonstrations, for comparison
    seeds: int = 5  # training seeds per learner
    seed: int = 0  # first seed
    apprentice: ApprenticeParams = ApprenticeParams()  # one run (its seed field varies per run)
    expert: ExpertParams = ExpertParams(epsilon=0.05, lag=0.05)  # the scripted demonstrator
    demo_episodes: int = 20  # scripted demonstration episodes per scenario
    demo_env_seed: int = 1_000  # first environment seed of the demonstrations
    demo_rng_seed: int = 7  # seed of the demonstrator's imperfections
    eval_episodes: int = 30  # test episodes per policy
    eval_seed: int = 100_000  # first environment seed of the test episodes (never trained on)

    def __post_init__(self) -> None:
        if self.learner not in LEARNERS:
            raise ValueError(f"learner must be one of {LEARNERS}, got {self.learner!r}")
        bad = [r for r in self.rules if r not in RULES]
        if bad:
            raise ValueError(f"unknown AB rule(s) {', '.join(bad)}; choose from {', '.join(RULES)}")
        if (self.learner == "ab") != bool(self.rules):
            raise ValueError(
                f"learner 'ab' needs one or more combination rules of {RULES} "
                "(and only 'ab' takes them)"
            )
        if self.seeds < 1 or self.eval_episodes < 1 or self.demo_episodes < 1:
            raise ValueError("seeds, eval_episodes and demo_episodes must be >= 1")

    @property
    def gamma(self) -> float:
        """The discount of μ, of the DQN and of the test metrics."""
        return self.apprentice.dqn.gamma

    @property
    def learners(self) -> list[str]:
        """The learners trained, in job order: "irl" first when trained, then "ab_<rule>"."""
        ab = [f"ab_{r}" for r in self.rules] if self.learner == "ab" else []
        return (["irl"] if self.learner == "irl" or self.with_irl else []) + ab

    @property
    def main_learner(self) -> str:
        """The learner the command is named after ("irl", or the first AB rule's)."""
        return "irl" if self.learner == "irl" else f"ab_{self.rules[0]}"

    @classmethod
    def of(cls, o, learner: str) -> ExperimentParams:
        """The experiment of `skyherd train irl|ab`'s options: any object with them as
        attributes (an argparse namespace; `rules` a comma-separated list, `no_irl` for "ab"
        only); ValueError (one line) if they are refused."""
        from skyherd.policy.dqn import DQNParams
        from skyherd.policy.irl import IRLParams

        if min(o.seeds, o.irl_iters, o.eval_episodes, o.mu_episodes) < 1 or o.dqn_steps < 100:
            raise ValueError(
                "need --seeds >= 1, --dqn-steps >= 100, --irl-iters >= 1, --eval-episodes >= 1"
            )
        if not (0 <= o.demo_epsilon <= 1 and 0 <= o.demo_lag <= 1 and 0 < o.gamma < 1):
            raise ValueError("--demo-epsilon/--demo-lag must be in [0, 1] and --gamma in (0, 1)")
        rules = tuple(r for r in getattr(o, "rules", "").split(",") if r) if learner == "ab" else ()
        hyper = ApprenticeParams(
            dqn=DQNParams(total_steps=o.dqn_steps, gamma=o.gamma),
            irl=IRLParams(epsilon=o.epsilon, max_iters=o.irl_iters),
            mu_episodes=o.mu_episodes,
        )
        return cls(
            learner=learner, rules=rules, with_irl=not getattr(o, "no_irl", False),
            seeds=o.seeds, seed=o.seed, apprentice=hyper,
            expert=ExpertParams(epsilon=o.demo_epsilon, lag=o.demo_lag),
            demo_episodes=o.demo_episodes, eval_episodes=o.eval_episodes,
        )  # fmt: skip


def budget_warnings(p: ExperimentParams, enough_steps: int) -> list[str]:
    """Budgets too short to learn anything, said out loud (printed and in summary.md);
    `enough_steps`: a DQN budget that does learn (the --quick one)."""
    starts, steps = p.apprentice.dqn.learning_starts, p.apprentice.dqn.total_steps
    out = []
    if steps <= starts:
        out.append(
            f"--dqn-steps {steps} is not more than the DQN's learning_starts ({starts}): "
            f"the network is never trained and every learned policy is the untrained one; "
            f"give --dqn-steps > {starts} (e.g. --quick uses {enough_steps})"
        )
    return out


def needed_scenarios(p: ExperimentParams) -> list[str]:
    """The scenarios whose demonstrations the learners need."""
    if p.learner == "irl":
        return ["composite"]
    return list(SUBTASKS) + (["composite"] if p.with_irl else [])


def recorded_demos(folder: Path | None, p: ExperimentParams) -> tuple[dict, dict]:
    """The recorded demonstrations `folder`/<scenario>.npz (e.g. from `skyherd teleop`) of the
    scenarios the learners need (none without a folder) and their files' facts (config.json);
    ValueError (one line, with what to do) for a missing or bad file."""
    from skyherd.policy.demos import DemoFileError, load_demo
    from skyherd.runio import file_facts

    demos, files = {}, {}
    for sc in needed_scenarios(p) if folder is not None else ():
        try:
            demos[sc] = load_demo(folder / f"{sc}.npz")
        except DemoFileError as e:
            raise ValueError(f"{e}; record it with `skyherd teleop --scenario {sc}`") from None
        files[sc] = file_facts(folder / f"{sc}.npz")
    return demos, files


def scripted_demonstration(scenario: str, p: ExperimentParams) -> Demonstration:
    """The scripted demonstrator's episodes of one scenario."""
    ex = scripted_expert(scenario, p.expert, seed=p.demo_rng_seed)
    meta = {"expert": dataclasses.asdict(p.expert)}
    return record(scenario, ex, p.demo_episodes, p.demo_env_seed, "scripted", meta)


def expert_feature_expectations(
    p: ExperimentParams, demos: dict[str, Demonstration]
) -> dict[str, np.ndarray]:
    """learner → μ_E (k,): composite demonstrations for "irl", policy.ab.combine for "ab_<rule>"."""
    mu: dict[str, np.ndarray] = {}
    if "irl" in p.learners:
        mu["irl"] = demo_feature_expectations(demos["composite"], p.gamma)
    for r in p.rules:
        mu[f"ab_{r}"] = combine(demos, r, p.gamma)
    return mu


@dataclass
class LearnerRun:
    """One learner trained on one seed and tested."""

    learner: str
    seed: int
    metrics: dict[str, float]  # mean test metrics (policy.demos.rollout_stats)
    train_s: float  # wall time of the training [s]
    train_cpu_s: float  # CPU time of the training [s]
    chosen: int  # index of the flown policy among the IRL iterations' policies
    converged: bool
    t0: float  # IRL margin of the random start policy ‖μ_E − μ⁽⁰⁾‖₂
    history: list[IRLIteration]
    mixture: np.ndarray  # QP weights λ over the IRL policies (reported)
    policy: MLPPolicy  # the chosen policy, weights as numpy arrays
    params: ApprenticeParams  # with this run's seed

    def facts(self) -> dict[str, Any]:
        """JSON-ready, without the weights (results.json's "learned" entries)."""
        hist = [
            {"i": h.i, "t": h.t, "dist": h.dist, "seconds": h.seconds,
             "w": h.w.tolist(), "mu": h.mu.tolist()}
            for h in self.history
        ]  # fmt: skip
        return {
            "learner": self.learner, "seed": self.seed, "metrics": self.metrics,
            "train_s": self.train_s, "train_cpu_s": self.train_cpu_s, "chosen": self.chosen,
            "converged": self.converged, "t0": self.t0, "history": hist,
            "mixture": self.mixture.tolist(), "meta": self.policy.meta,
            "params": dataclasses.asdict(self.params),
        }  # fmt: skip

    def labelled_policy(self) -> MLPPolicy:
        """A copy of the policy whose meta also names the learner, the seed and the test."""
        pol = MLPPolicy(self.policy.weights, self.policy.biases, self.policy.meta)
        pol.meta.update({"learner": self.learner, "seed": self.seed, "eval": self.metrics})
        return pol

    def event(self) -> dict[str, Any]:
        """The events.jsonl record of the finished run."""
        return {"event": "trained", "learner": self.learner, "seed": self.seed,
                "train_s": self.train_s, "metrics": self.metrics, "chosen": self.chosen}  # fmt: skip

    def metric_rows(self) -> list[dict[str, Any]]:
        """metrics.csv rows (METRIC_COLUMNS), one per IRL iteration."""
        return [
            {"learner": self.learner, "seed": self.seed, "iter": h.i, "t": h.t, "dist": h.dist,
             "seconds": h.seconds} | {f"mu_{n}": v for n, v in zip(PSI_NAMES, h.mu.tolist())}
            for h in self.history
        ]  # fmt: skip


@dataclass(frozen=True)
class Job:
    learner: str
    seed: int
    mu_expert: np.ndarray  # (k,)


def jobs(p: ExperimentParams, mu_expert: dict[str, np.ndarray]) -> list[Job]:
    """Every (learner, seed), seed-major: the order of the results."""
    return [Job(name, p.seed + s, mu) for s in range(p.seeds) for name, mu in mu_expert.items()]


def train_learner(
    job: Job, p: ExperimentParams, on_iteration: OnIteration | None = None, progress: bool = False
) -> LearnerRun:
    """Train one learner on one seed (one torch thread, as in a worker) and test it."""
    import torch

    torch.set_num_threads(1)
    hyper = dataclasses.replace(p.apprentice, seed=job.seed)
    tell = (lambda it: on_iteration(job.learner, job.seed, float(it.t))) if on_iteration else None
    cpu0 = time.process_time()
    res = run_apprenticeship(job.mu_expert, hyper, on_iteration=tell, progress=progress)
    cpu_s = time.process_time() - cpu0
    _, m = rollout_stats(res.policy, "composite", p.eval_episodes, p.eval_seed, p.gamma)
    t0 = float(np.linalg.norm(res.irl.mu_expert - res.irl.mu0))
    return LearnerRun(job.learner, job.seed, m, res.seconds, cpu_s, res.chosen, res.irl.converged,
                      t0, res.irl.history, res.mixture, res.policy, hyper)  # fmt: skip


def _train_in_worker(task: tuple[Job, ExperimentParams, Any]) -> LearnerRun:
    job, p, ticks = task  # ticks: a manager queue, read by the parent
    return train_learner(job, p, lambda learner, seed, t: ticks.put((learner, seed, t)))


def run_experiment(
    p: ExperimentParams,
    mu_expert: dict[str, np.ndarray],
    workers: int = 1,
    on_iteration: OnIteration | None = None,
    on_result: Callable[[LearnerRun, list[LearnerRun]], None] | None = None,
    progress: bool = False,
) -> list[LearnerRun]:
    """Every job of `jobs(p, mu_expert)`, here (workers 1) or on `workers` processes; the same
    results either way, in job order. on_iteration(learner, seed, t) after each IRL iteration;
    on_result(run, finished so far in job order) after each run. progress: DQN bars (workers 1)."""
    todo = jobs(p, mu_expert)
    if workers <= 1:
        done: list[LearnerRun] = []
        for job in todo:
            done.append(train_learner(job, p, on_iteration, progress))
            if on_result:
                on_result(done[-1], list(done))
        return done
    return _run_pool(todo, p, workers, on_iteration, on_result)


def _run_pool(todo, p, workers, on_iteration, on_result) -> list[LearnerRun]:
    """Each IRL iteration in a worker reaches on_iteration through a queue, so progress moves
    while a run is under way."""
    import multiprocessing as mp
    import queue
    from concurrent.futures import FIRST_COMPLETED, ProcessPoolExecutor, wait

    by_index: dict[int, LearnerRun] = {}
    with mp.Manager() as mgr, ProcessPoolExecutor(max_workers=workers) as pool:
        q = mgr.Queue()
        futs = {pool.submit(_train_in_worker, (job, p, q)): i for i, job in enumerate(todo)}
        pending = set(futs)

        def drain() -> None:
            while True:
                try:
                    tick = q.get_nowait()
                except queue.Empty:
                    return
                if on_iteration:
                    on_iteration(*tick)

        while pending:
            finished, pending = wait(pending, timeout=0.5, return_when=FIRST_COMPLETED)
            drain()
            for f in finished:
                by_index[futs[f]] = f.result()
                if on_result:
                    on_result(by_index[futs[f]], [by_index[i] for i in sorted(by_index)])
    return [by_index[i] for i in range(len(todo))]


def baseline_factories(p: ExperimentParams) -> dict[str, Factory]:
    """The reference policies, seed → policy: the demonstrator, the ideal expert, random."""
    demonstrator = {
        "expert (demonstrator)": lambda s: scripted_expert("composite", p.expert, seed=s)
    }
    return demonstrator | reference_factories()


def baseline_metrics(make: Factory, p: ExperimentParams) -> list[dict[str, float]]:
    """Test metrics of a reference policy, one per training seed, on the learners' episodes."""
    return [
        rollout_stats(make(p.seed + s), "composite", p.eval_episodes, p.eval_seed, p.gamma)[1]
        for s in range(p.seeds)
    ]


def best_runs(runs: list[LearnerRun]) -> dict[str, LearnerRun]:
    """learner → its run with the highest test all-in-view fraction (the first on a tie)."""
    best: dict[str, LearnerRun] = {}
    for r in runs:
        old = best.get(r.learner)
        if old is None or r.metrics["all_in_view_frac"] > old.metrics["all_in_view_frac"]:
            best[r.learner] = r
    return best


def transfer_rows(best: dict[str, LearnerRun], episodes: int) -> list[list]:
    """The transfer table's rows (policy.evaluate.transfer_table): the best seed of each
    learner and the reference policies on the groundsim UGV behaviours, not trained on."""
    from skyherd.policy.evaluate import TRANSFER_SEED, transfer_table
    from skyherd.task.scenarios import GROUNDSIM_SCENARIOS

    pols = {f"{k} (seed {r.seed})": (lambda s, p=r.policy: p) for k, r in best.items()}
    return transfer_table(
        pols | reference_factories(), GROUNDSIM_SCENARIOS, episodes, TRANSFER_SEED
    )


@dataclass(frozen=True)
class Outcome:
    """What `run_in_folder` returns besides the files it writes."""

    runs: list[LearnerRun]  # one per learner and seed, in job order
    baselines: dict[str, list[dict[str, float]]]  # reference policy → its test metrics per seed
    best: dict[str, LearnerRun]  # learner → its best run (best_runs)
    transfer: list[list] | None  # the transfer table's rows (None: not asked for)


def run_in_folder(
    run: Any,
    p: ExperimentParams,
    demos: dict[str, Demonstration],
    workers: int = 1,
    transfer_episodes: int = 0,
    on_iteration: OnIteration | None = None,
    on_result: Callable[[LearnerRun, list[LearnerRun]], None] | None = None,
    bars: Callable[..., Any] = lambda items, **kw: items,
    progress: bool = False,
) -> Outcome:
    """The whole experiment into the run folder `run` (a runio.run.Run), in order: demos/ (the
    recorded `demos`, completed with the scripted demonstrator's), μ_E and the parameters in
    config.json, every run (metrics.csv and events.jsonl as each ends), the baselines on the
    same test episodes, policies/<learner>_seed<s>.npz, each learner's best run and the
    transfer rows (`transfer_episodes` per groundsim behaviour; 0: none). `bars`: a progress
    bar over the demonstrations and the baselines (tqdm.tqdm's signature; default none); the
    rest as run_experiment's."""
    (run.path / "demos").mkdir()
    for sc in bars(needed_scenarios(p), desc="demonstrations", unit="scenario", disable=None):
        if sc not in demos:
            demos[sc] = scripted_demonstration(sc, p)
        demos[sc].save(run.path / "demos" / f"{sc}.npz")
    mu_e = expert_feature_expectations(p, demos)
    run.config(
        learner=p.learner, experiment=p, hyper_parameters=p.apprentice, expert=p.expert,
        mu_expert={k: v.tolist() for k, v in mu_e.items()}, psi_names=PSI_NAMES,
        demos={sc: d.meta["demonstrator"] for sc, d in demos.items()},
    )  # fmt: skip
    events, metrics = run.events(), run.metrics(METRIC_COLUMNS)

    def ended(r: LearnerRun, done: list[LearnerRun]) -> None:
        for row in r.metric_rows():
            metrics.write(row)
        events.write(r.event())
        if on_result:
            on_result(r, done)

    runs = run_experiment(p, mu_e, workers, on_iteration, ended, progress)
    facs = bars(baseline_factories(p).items(), desc="baselines", unit="policy", disable=None)
    base = {name: baseline_metrics(make, p) for name, make in facs}
    (run.path / "policies").mkdir()
    for r in runs:
        r.labelled_policy().save(run.path / "policies" / f"{r.learner}_seed{r.seed}.npz")
    best = best_runs(runs)
    rows = transfer_rows(best, transfer_episodes) if transfer_episodes > 0 else None
    return Outcome(runs, base, best, rows)
