"""The seed's swarm Q-learning experiments (`skyherd train sql`), callable without the command line.

Experiments (each over every seed):
- compare:     SQL vs SQL-D vs SQL-SIE at each K of `agents` (default 9 and 16);
- sharing:     SQL-SIE with knowledge sharing every N of `sharing_periods` (1, 20, 50) episodes;
- scalability: all three learners at K = 4, 9, 16.
Identical configurations are trained once and reused across experiments.

    p = ExperimentParams(hyper=SQLHyper(episodes=2000), agents=(4,), scalability_agents=(4, 9))
    runs = list(train_all(p))   # every configuration of p.plan on every seed
    plans, refused = learned_plans(runs, p.seeds[0])
"""

from __future__ import annotations

import time
from collections.abc import Callable, Iterator
from dataclasses import asdict, dataclass, field, replace

from skyherd.policy.sql.envfile import EnvSpec
from skyherd.policy.sql.layout import Layout, build_layout
from skyherd.policy.sql.metrics import RunSummary, summarize
from skyherd.policy.sql.params import Algorithm, GridParams, Rules, SQLHyper
from skyherd.policy.sql.train import TrainResult, plan_paths, train

EXPERIMENTS = ("compare", "sharing", "scalability")
ALGORITHMS = ("sql", "sql-d", "sql-sie")


@dataclass(frozen=True)
class Config:
    """One trained configuration (run once per seed)."""

    algorithm: str
    n_agents: int
    share_every: int

    @property
    def label(self) -> str:
        n = f" N={self.share_every}" if self.algorithm == "sql-sie" else ""
        return f"{self.algorithm.upper()} K={self.n_agents}{n}"

    @property
    def key(self) -> str:
        return f"{self.algorithm}_K{self.n_agents}_N{self.share_every}"


@dataclass(frozen=True, eq=False)
class Trained:
    """One finished run: its configuration, seed, result, summary and wall time [s]."""

    config: Config
    seed: int
    result: TrainResult
    summary: RunSummary
    wall_s: float


def plan_experiments(
    experiments: tuple[str, ...],
    agents: list[int],
    scalability_agents: list[int],
    share_every: int,
    sharing_periods: list[int],
) -> dict[str, list[Config]]:
    """experiment → its configurations, in table order (SQL-SIE shares every `share_every`
    episodes in compare and scalability)."""

    def cfg(algorithm: str, k: int, n: int = share_every) -> Config:
        return Config(algorithm, k, n if algorithm == "sql-sie" else 0)

    plan: dict[str, list[Config]] = {}
    if "compare" in experiments:
        plan["compare"] = [cfg(a, k) for k in agents for a in ALGORITHMS]
    if "sharing" in experiments:
        plan["sharing"] = [cfg("sql-sie", k, n) for k in agents for n in sharing_periods]
    if "scalability" in experiments:
        plan["scalability"] = [cfg(a, k) for a in ALGORITHMS for k in scalability_agents]
    return plan


@dataclass(frozen=True)
class ExperimentParams:
    """Everything one `skyherd train sql` run varies (saved in config.json)."""

    experiments: tuple[str, ...] = EXPERIMENTS
    seeds: tuple[int, ...] = (0, 1, 2)  # learner seeds
    hyper: SQLHyper = field(default_factory=SQLHyper)  # share_every: compare / scalability N
    agents: tuple[int, ...] = (9, 16)  # K of compare and sharing
    scalability_agents: tuple[int, ...] = (4, 9, 16)  # K of scalability
    sharing_periods: tuple[int, ...] = (1, 20, 50)  # N of the sharing experiment
    rules: Rules = field(default_factory=Rules)
    map_seed: int = 0  # obstacle map seed of the built-in layouts
    window: int = 100  # moving-average window of curves and convergence [episodes]
    env: EnvSpec | None = None  # a map file's map for every run (K from the file)

    @classmethod
    def of(cls, o) -> ExperimentParams:
        """The experiment of `skyherd train sql`'s options: any object with them as attributes
        (an argparse namespace; None: the default, --quick's with `o.quick`); ValueError naming
        the option."""
        from skyherd.policy.sql.envfile import load_env_file
        from skyherd.policy.sql.layout import STARTS

        if o.episodes is not None and o.episodes < 1:
            raise ValueError("--episodes must be >= 1")
        if o.max_steps < 1:
            raise ValueError("--max-steps must be >= 1")
        if o.share_every < 1 or min(o.sharing_periods) < 1:
            raise ValueError("sharing periods must be >= 1 (SQL-D is the no-sharing learner)")
        if len(set(o.seeds)) != len(o.seeds) or min(o.seeds) < 0:
            raise ValueError("--seeds must be distinct non-negative integers")
        episodes = o.episodes or (2000 if o.quick else 10_000)
        agents = o.agents or ([4] if o.quick else [9, 16])
        scal = o.scalability_agents or ([4, 9] if o.quick else [4, 9, 16])
        env = None if o.env is None else load_env_file(o.env)
        if env is not None:
            agents = scal = [len(env.starts)]
        for k in (*agents, *scal):
            if k not in STARTS and env is None:
                raise ValueError(f"K={k} has no built-in layout; use K in {sorted(STARTS)}")
        hyper = SQLHyper(episodes=episodes, max_steps=o.max_steps, share_every=o.share_every)
        return cls(
            experiments=EXPERIMENTS if o.experiment == "all" else (o.experiment,),
            seeds=tuple(o.seeds), hyper=hyper, agents=tuple(agents),
            scalability_agents=tuple(scal), sharing_periods=tuple(o.sharing_periods),
            rules=Rules.named(o.rules, o.ties), map_seed=o.map_seed,
            window=min(o.window or (20 if o.quick else 100), episodes), env=env,
        )  # fmt: skip

    @property
    def tail(self) -> int:
        """Episodes at the end of a run whose mean is its final value."""
        return min(500, max(1, self.hyper.episodes // 5))

    @property
    def plan(self) -> dict[str, list[Config]]:
        return plan_experiments(self.experiments, list(self.agents),
                                list(self.scalability_agents), self.hyper.share_every,
                                list(self.sharing_periods))  # fmt: skip

    @property
    def configs(self) -> list[Config]:
        """Every configuration of the plan once, in first-seen order."""
        return list(dict.fromkeys(c for cs in self.plan.values() for c in cs))

    def grid(self, k: int) -> GridParams:
        return GridParams(n_agents=k, map_seed=self.map_seed)

    def layouts(self) -> dict[int, Layout]:
        """K → the layout its runs learn on (the map file's, or the built-in one)."""
        if self.env is not None:
            return {len(self.env.starts): self.env.layout()}
        ks = sorted({c.n_agents for c in self.configs})
        return {k: build_layout(self.grid(k)) for k in ks}

    def config(self, env_path: str | None, quick: bool) -> dict:
        """config.json's content (`env_path`: where the map file was read)."""
        return {
            "experiments": {e: [asdict(c) for c in cs] for e, cs in self.plan.items()},
            "seeds": list(self.seeds),
            "hyper": asdict(self.hyper),
            "grid": {k: asdict(self.grid(k)) for k in self.layouts()},
            "rules": asdict(self.rules),
            "env": env_path,
            "window": self.window,
            "tail": self.tail,
            "quick": quick,
            "agents": list(self.agents),
            "scalability_agents": list(self.scalability_agents),
        }


def train_all(
    p: ExperimentParams,
    on_episodes: Callable[[int], object] | None = None,
    on_start: Callable[[Config, int], None] | None = None,
) -> Iterator[Trained]:
    """Train every configuration on every seed, one after the other; yield each finished run
    (`on_start` before each run, `on_episodes(n)` as episodes finish)."""
    layouts = p.layouts()
    for c in p.configs:
        h = replace(p.hyper, share_every=max(c.share_every, 1))
        for seed in p.seeds:
            if on_start is not None:
                on_start(c, seed)
            t0 = time.perf_counter()
            r = train(Algorithm(c.algorithm), layouts[c.n_agents], h, seed, on_episodes, p.rules)
            wall = time.perf_counter() - t0
            yield Trained(c, seed, r, summarize(r.metrics, p.window, p.tail), wall)


def learned_plans(runs: list[Trained], seed: int) -> tuple[dict[int, list], dict[int, str]]:
    """The learned SQL-SIE formation plans of seed `seed`, one try per K (its first SQL-SIE
    run): K → plan (policy.sql.plan_paths), and K → why it has none."""
    plans: dict[int, list] = {}
    refused: dict[int, str] = {}
    for run in runs:
        k = run.config.n_agents
        if run.config.algorithm != "sql-sie" or run.seed != seed or k in plans or k in refused:
            continue
        try:
            plans[k] = plan_paths(run.result, k)
        except ValueError as e:
            refused[k] = str(e)
    return plans, refused
