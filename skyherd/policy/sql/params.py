"""Frozen hyper-parameters of the swarm Q-learning experiments (printed and saved with each run).

Symbols follow the seed paper: learning rate α, discount γ, exploration ε (greedy with
probability 1 − ε), knowledge-sharing period N (episodes).
"""

from __future__ import annotations

import enum
from dataclasses import asdict, dataclass, replace

import numpy as np


class Algorithm(enum.Enum):
    """The three learners compared in the seed."""

    SQL = "sql"  # Algorithm 1: independent per-agent Q-learning, team bonus, no sharing
    SQL_D = "sql-d"  # decomposition (reach ROI, then a formation slot) without sharing
    SQL_SIE = "sql-sie"  # Algorithm 2: decomposition + knowledge sharing every N episodes


@dataclass(frozen=True)
class GridParams:
    """The grid world (cells are 1-based (x, y), x to the right, y up)."""

    size: int = 50
    """M: the grid is M×M cells."""
    n_agents: int = 9
    """K: number of agents and of formation targets (4, 9 or 16 for the built-in layouts)."""
    obstacle_fraction: float = 0.02
    """Share of all cells holding an obstacle (never in the ROI or on a start cell)."""
    map_seed: int = 0
    """Seed of the obstacle placement (the same map for every learner and learner seed)."""

    def __post_init__(self) -> None:
        if not (self.size >= 2 and self.n_agents >= 1 and self.map_seed >= 0):
            raise ValueError("grid needs size >= 2, n_agents >= 1 and map_seed >= 0")
        if not 0.0 <= self.obstacle_fraction < 0.5:  # False for NaN too
            raise ValueError(f"obstacle_fraction must be in [0, 0.5), got {self.obstacle_fraction}")


@dataclass(frozen=True)
class SQLHyper:
    """Learning hyper-parameters shared by SQL, SQL-D and SQL-SIE."""

    alpha: float = 0.1
    """α: Q-learning step size (eq. Q ← Q + α (r + γ max Q' − Q))."""
    gamma: float = 0.9
    """γ: discount factor."""
    eps_start: float = 1.0
    """ε at episode 0."""
    eps_decay: float = 0.999
    """ε multiplied by this after every episode ..."""
    eps_min: float = 0.05
    """... down to this floor."""
    max_steps: int = 1000
    """Step limit per episode (one step = every active agent moves once)."""
    episodes: int = 10_000
    """Training episodes per run."""
    share_every: int = 20
    """N: SQL-SIE knowledge sharing period in episodes (ignored by SQL and SQL-D)."""
    r_step: float = 0.0
    """Reward for an ordinary step."""
    r_collision: float = -1.0
    """Reward for bumping into an obstacle (the agent stays)."""
    r_goal: float = 10.0
    """Reward for reaching a free target (SQL, SQL-SIE phase 2) or entering the ROI (phase 1)."""
    bonus_all: float = 10.0
    """SQL team bonus for every agent when all agents reached targets."""
    bonus_reached: float = -1.0
    """SQL team bonus for an agent that reached a target when not all did."""
    bonus_missed: float = -2.0
    """SQL team bonus for an agent that did not reach a target."""

    def __post_init__(self) -> None:
        checks = {
            "alpha in (0, 1]": 0.0 < self.alpha <= 1.0,
            "gamma in [0, 1)": 0.0 <= self.gamma < 1.0,
            "0 <= eps_min <= eps_start <= 1": 0.0 <= self.eps_min <= self.eps_start <= 1.0,
            "eps_decay in (0, 1]": 0.0 < self.eps_decay <= 1.0,
            "max_steps >= 1": self.max_steps >= 1,
            "episodes >= 1": self.episodes >= 1,
            "share_every >= 0": self.share_every >= 0,
        }
        bad = [k for k, ok in checks.items() if not ok]
        if bad:
            raise ValueError(f"bad SQL hyper-parameters: {', '.join(bad)}")

    def epsilons(self, start: int, count: int, stop_decay: bool = False) -> np.ndarray:
        """ε for episodes start .. start+count−1, shape (count,).

        stop_decay False: max(ε_min, ε_0 · decay^e). True (published loop): ε_0 multiplied by
        decay after each episode while ε > ε_min, by repeated products as the loop does, so
        it settles on the first value ≤ ε_min (0.999, 0.05: 0.04996 from episode 2995 on).
        """
        if not stop_decay:
            e = np.arange(start, start + count, dtype=np.float64)
            return np.maximum(self.eps_min, self.eps_start * self.eps_decay**e)
        out = np.empty(count)
        eps = self.eps_start
        for e in range(start + count):
            if e >= start:
                out[e - start] = eps
            if eps > self.eps_min:
                eps *= self.eps_decay
            elif e >= start:
                out[e - start + 1 :] = eps
                break
        return out


TIES = ("first", "random")
TEAM_BONUS = ("blend", "add")
ROI_PHASE = ("pretrained", "online")
ASSIGN = ("q-argmax", "nearest")
STEP_COUNT = ("published", "own")
ASSIGN_CELL = ("agents-1-2", "own")
WALK_DRAWS = ("per-move", "none")
WALK_END = ("step-onto", "on-flag")
EPS_SCHEDULE = ("stop-decay", "clip")
Q_FORM = ("blend", "delta")
ROI_TABLE = ("fixed", "per-run")


@dataclass(frozen=True)
class Rules:
    """Which variant of each rule the learners follow (saved with every run).

    Two named sets: `Rules.published()` — what the public MATLAB implementation of the seed
    study does — and `Rules.intended()` — what the paper describes. Each field is one switch
    and can be changed on its own (`dataclasses.replace`).
    """

    name: str = "intended"
    """Label of the set these switches came from (informational)."""
    ties: str = "random"
    """Greedy ties among equal Q values: "first" = lowest action index (MATLAB `max`, order
    up, down, left, right: with zero tables a systematic drift upward); "random" = uniform."""
    team_bonus: str = "add"
    """SQL end-of-episode team bonus on each agent's last (s, a): "blend" =
    Q ← (1 − α) Q + α r_team (the published `Qvalues_update_swarm_final`); "add" =
    Q ← Q + α r_team (the bonus added to the last transition's reward)."""
    roi_phase: str = "online"
    """SQL-D / SQL-SIE phase 2: "pretrained" = per-target tables pre-trained before the run
    (published `Q_Learning_ROI`: start in the ROI corner, reward 1, ε ← 0.995 ε), walked
    greedily to the target within the agent's next turn (one global step), passing through
    other agents; "online" = the per-target tables learned during the run with the same ε,
    one move per global step, other agents block."""
    assign: str = "nearest"
    """Target claimed on entering the ROI: "q-argmax" = the published `flag_assignment`:
    argmax over (action, free target) of the pre-trained table at the entry cell, first
    index, mapped to a target by MATLAB's ceil(idx / K) (exact for K = 4; for larger K it
    favours the lowest-id free targets, i.e. targets nearly in id order); "nearest" = the
    free target nearest to the entry cell (Manhattan, lowest id on ties)."""
    step_count: str = "own"
    """Per-agent step count of SQL-D / SQL-SIE: "published" = phase-1 moves plus the length
    of the most recent ROI walk of ANY agent when this agent's turn came in the last step
    (the published `total_step = episode_step + ROI_step`, ROI_step shared by all agents);
    "own" = the agent's own moves (phase 1 + its own phase 2)."""
    assign_cell: str = "own"
    """Cell whose pre-trained values `assign="q-argmax"` reads: "agents-1-2" = the published
    `Q_matrix_ROI(currentState(1), currentState(2), :, ...)` with `currentState` the whole
    K×2 position matrix, i.e. MATLAB's linear (column-major) elements 1 and 2: the cell
    (x of agent 1, x of agent 2) — for K = 1 agent 1's own (x, y). Outside the ROI that cell's
    values are all 0, so the first free target is taken. "own" = the claiming agent's cell.
    Only read by assign="q-argmax"."""
    walk_draws: str = "none"
    """Random draws of the pre-trained ROI walk (its ε is 0): "per-move" = one uniform draw
    per move, unused, as the published `action_selection_ROI` calls `rand` before comparing
    with ε = 0; "none" = no draw. Changes no rule, only which random numbers the later
    ε-greedy choices get (needed to replay the published code's random stream). Only read by
    roi_phase="pretrained"."""
    walk_end: str = "on-flag"
    """When a pre-trained ROI walk is done: "step-onto" = only after a move onto the target
    (the published loop `while collect == 0` with collect = "the attempted move's cell is
    the flag"), so an agent whose walk starts on its own flag first moves (off and back,
    or, pressing a wall, for the whole 1000-move budget while standing on it); "on-flag" =
    as soon as the agent stands on it (0 moves). Only a map with a flag on the ROI's edge
    row or column can start a walk on a flag (the study's formations cannot). Only read by
    roi_phase="pretrained"."""
    eps_schedule: str = "clip"
    """ε per episode: "stop-decay" = the published loop `if ε > ε_min, ε ← ε·decay` after each
    episode (repeated products; it stops at the first ε ≤ ε_min, 0.04996 for 0.999 and
    0.05); "clip" = max(ε_min, ε_0·decay^e)."""
    q_form: str = "delta"
    """Floating-point form of every Q update: "blend" = (1 − α)·Q + α·target (the published
    `Qvalues_update*.m`); "delta" = Q + α·(target − Q). Equal in exact arithmetic; the
    roundings differ, which can flip a first-index tie between values equal up to rounding."""
    roi_table: str = "per-run"
    """Where the pre-trained ROI tables come from: "fixed" = one table per formation (ROI,
    flags) and pre-training setting, pre-trained once from `RoiPretrain.seed` alone, saved
    and loaded (`roitable.fixed_roi_table`), as the published `SQL_D.m` / `SQL_SIE.m` load
    one `Q_matrix_ROI*.mat` made once by `Q_Learning_ROI.m`; every run of every learner seed
    walks the same table, and the run's random stream starts at its first episode. "per-run"
    = new tables pre-trained inside every run from the run's own random stream before its
    first episode (skyherd's behaviour before issue 29). Only read by roi_phase="pretrained"."""

    def __post_init__(self) -> None:
        for field, allowed in (
            ("ties", TIES),
            ("team_bonus", TEAM_BONUS),
            ("roi_phase", ROI_PHASE),
            ("assign", ASSIGN),
            ("step_count", STEP_COUNT),
            ("assign_cell", ASSIGN_CELL),
            ("walk_draws", WALK_DRAWS),
            ("walk_end", WALK_END),
            ("eps_schedule", EPS_SCHEDULE),
            ("q_form", Q_FORM),
            ("roi_table", ROI_TABLE),
        ):
            if getattr(self, field) not in allowed:
                raise ValueError(
                    f"rule {field} must be one of {allowed}, got {getattr(self, field)!r}"
                )
        if self.assign == "q-argmax" and self.roi_phase != "pretrained":
            raise ValueError(
                'assign="q-argmax" reads the pre-trained tables: needs roi_phase="pretrained"'
            )

    @staticmethod
    def published(ties: str = "first") -> Rules:
        """The public MATLAB implementation's rules."""
        return Rules(
            "published", ties, "blend", "pretrained", "q-argmax", "published",
            "agents-1-2", "per-move", "step-onto", "stop-decay", "blend", "fixed",
        )  # fmt: skip

    @staticmethod
    def intended(ties: str = "random") -> Rules:
        """The paper's description (skyherd's original kernels)."""
        return Rules(
            "intended", ties, "add", "online", "nearest", "own", "own", "none", "on-flag",
            "clip", "delta", "per-run",
        )  # fmt: skip

    @staticmethod
    def named(name: str, ties: str | None = None, switches: dict[str, str] | None = None) -> Rules:
        """`Rules.published()` or `Rules.intended()` by name; `ties` overrides its default
        (the set is then labelled e.g. "intended-first-ties"); `switches` {field: value}
        override other fields (labelled e.g. "published-assign_cell-own")."""
        sets = {"published": Rules.published, "intended": Rules.intended}
        if name not in sets:
            raise ValueError(f"rule set must be one of {sorted(sets)}, got {name!r}")
        rules = sets[name]()
        label = name
        if ties is not None and ties != rules.ties:
            rules, label = sets[name](ties), f"{name}-{ties}-ties"
        for field, value in (switches or {}).items():
            if field in ("name", "ties") or field not in Rules.__dataclass_fields__:
                raise ValueError(f"no rule switch {field!r} (ties has its own option)")
            if getattr(rules, field) != value:
                rules, label = replace(rules, **{field: value}), f"{label}-{field}-{value}"
        return replace(rules, name=label)  # its own label in tables


@dataclass(frozen=True)
class RoiPretrain:
    """Pre-training of the per-target ROI tables (published `Q_Learning_ROI.m`)."""

    episodes: int = 10_000
    max_steps: int = 1000
    eps_decay: float = 0.995
    eps_min: float = 0.05
    reward: float = 1.0
    """Reward on reaching the target (the published ROI trainer uses 1, not 10)."""
    seed: int = 0
    """Seed of the fixed tables (`Rules.roi_table` "fixed"): their pre-training draws from
    this seed's stream only, never from a run's. Not read by "per-run"."""

    def __post_init__(self) -> None:
        if not (self.episodes >= 1 and self.max_steps >= 1 and self.seed >= 0):
            raise ValueError("ROI pre-training needs episodes >= 1, max_steps >= 1, seed >= 0")
        if not (0.0 < self.eps_decay <= 1.0 and 0.0 <= self.eps_min <= 1.0):
            raise ValueError("ROI pre-training needs eps_decay in (0, 1], eps_min in [0, 1]")


@dataclass(frozen=True)
class PlanParams:
    """How a formation's lock-step plan is learned when none is given (`skyherd fly --mission
    formation` without --policy-file): SQL-SIE on the built-in layout of K agents, the intended
    rules, from one learner seed."""

    grid: GridParams = GridParams(n_agents=4)
    """The grid world: K (grid.n_agents) must have a built-in layout (layout.STARTS: 4, 9, 16)."""
    hyper: SQLHyper = SQLHyper()
    """Learning hyper-parameters (the study's defaults)."""
    seed: int = 0
    """Learner seed (`--sql-seed`): the same seed, the same plan."""

    def __post_init__(self) -> None:
        if self.seed < 0:
            raise ValueError(f"the learner seed must be >= 0, got {self.seed}")

    def describe(self) -> dict:
        """Where a learned plan came from (config.json's "plan")."""
        return {"source": "trained", "algorithm": Algorithm.SQL_SIE.value, "seed": self.seed,
                "grid": asdict(self.grid), "hyper": asdict(self.hyper)}  # fmt: skip
