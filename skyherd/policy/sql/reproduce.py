"""The seed study's protocol (`skyherd reproduce sql`), callable without the command line.

Runs SQL, SQL-D and SQL-SIE (sharing every N of `sharing_periods` episodes) at each K of
`agents`, for every seed and rule set; `scaling_agents` adds K for the scaling figure with the
first sharing period only. Under the published rules (Rules.roi_table "fixed") every run of a
formation walks one ROI table: its seed is given, or found per K as the first seed whose greedy
walks all arrive (policy.sql.roitable.walkable_seed: a property of the table, found before any
run). Each run is a `policy.sql.sweep.RunSpec`, done anywhere by `run_one`.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import replace

from skyherd.policy.sql.envfile import EnvSpec, generate_env
from skyherd.policy.sql.params import RoiPretrain, Rules, SQLHyper
from skyherd.policy.sql.roitable import walkable_seed
from skyherd.policy.sql.sweep import RunSpec


def table_pretrain(
    rules: Rules,
    hyper: SQLHyper,
    n_agents: int,
    env: EnvSpec | None,
    table_seed: int | None,
    say: Callable[[str], object] = print,
) -> RoiPretrain:
    """The ROI table's pre-training settings of formation K: `table_seed`, or with None the
    first walkable table seed of its layout (the map given, else the generated one)."""
    if table_seed is not None:
        return RoiPretrain(seed=table_seed)
    if rules.roi_phase != "pretrained" or rules.roi_table != "fixed":
        return RoiPretrain()  # no fixed table is walked: nothing to choose
    layout = (env if env is not None else generate_env(n_agents, 0)).layout()
    seed, holes = walkable_seed(layout, hyper, rules, RoiPretrain())
    say(f"K = {n_agents}: ROI table seed {seed} ({holes} walk holes; --roi-table-seed auto)")
    return RoiPretrain(seed=seed)


def study_specs(
    rule_sets: list[Rules],
    learners: list[str],
    seeds: int,
    agents: list[int],
    scaling_agents: list[int],
    sharing_periods: list[int],
    hyper: SQLHyper,
    env: EnvSpec | None = None,
    table_seed: int | None = None,
    say: Callable[[str], object] = print,
) -> list[RunSpec]:
    """Every run of the study, in table order (rule set, K, learner, N, seed)."""
    Ns = sharing_periods
    specs = []
    for named in rule_sets:
        for K in dict.fromkeys([*agents, *scaling_agents]):
            rules, pre = named, table_pretrain(named, hyper, K, env, table_seed, say)
            if pre.seed and rules.roi_phase == "pretrained" and rules.roi_table == "fixed":
                rules = replace(rules, name=f"{rules.name}-table{pre.seed}")  # its label in tables
            cfgs = [("sql", 0), ("sql-d", 0)]
            cfgs += [("sql-sie", n) for n in (Ns if K in agents else Ns[:1])]
            for alg, n in (c for c in cfgs if c[0] in learners):
                for seed in range(seeds):
                    specs.append(RunSpec(alg, K, n, seed, rules, hyper, pre, env=env))
    return specs


def specs_of(o, env: EnvSpec | None = None, say: Callable[[str], object] = print) -> list[RunSpec]:
    """Every run of `skyherd reproduce sql`'s options (any object with them as attributes: an
    argparse namespace) on the map `env` (None: generated per seed and K), checked: ValueError
    naming the option."""
    from skyherd.policy.sql.layout import formation

    table_seed = None
    if o.roi_table_seed != "auto":
        table_seed = int(o.roi_table_seed) if str(o.roi_table_seed).isdigit() else -1
        if table_seed < 0:
            raise ValueError("--roi-table-seed must be auto or an integer >= 0")
    switches = {}
    for sw in o.switch:
        name, eq, value = sw.partition("=")
        if not eq:
            raise ValueError(f"--switch {sw}: expected FIELD=VALUE, e.g. assign_cell=own")
        switches[name.strip()] = value.strip()
    try:
        rule_sets = [Rules.named(r, o.ties, switches) for r in o.rules]
    except ValueError as e:
        raise ValueError(f"--switch: {e}") from None
    if min(o.sharing_periods) < 1:
        raise ValueError("sharing periods must be >= 1 (SQL-D is the no-sharing learner)")
    if o.window < 1 or o.window > o.episodes:
        raise ValueError("--window must be in 1..episodes")
    for K in (*o.agents, *o.scaling_agents) if env is None else ():
        formation(K)
    hyper = SQLHyper(episodes=o.episodes, max_steps=o.max_steps)
    return study_specs(rule_sets, o.learners, o.seeds, o.agents, o.scaling_agents,
                       o.sharing_periods, hyper, env, table_seed, say)  # fmt: skip
