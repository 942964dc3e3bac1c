"""The pre-trained per-target ROI tables of the published rules: one fixed table per formation.

The published `SQL_D.m` / `SQL_SIE.m` load one `Q_matrix_ROI*.mat`, made once by
`Q_Learning_ROI.m`, and every run walks it (`Rules.roi_table` "fixed"). Here a table is a pure
function of its key — the ROI and flag cells, the pre-training settings (`RoiPretrain`, its
`seed` included), α, γ and the tie and update rules it was trained with — and is pre-trained
from `RoiPretrain.seed`'s own random stream, never from a run's. The study's formations
(K = 4, 9, 16, 25, 36 on the 50×50 grid, default settings) are saved in `roi_tables/` and
loaded; any other key is pre-trained once per process and kept. Writing the saved files:

    .venv/bin/python -c "from skyherd.policy.sql.roitable import write_tables; write_tables()"

(K = 4 … 36, and each K's searched walkable seed into `walkable.json`;
`print(*holes_lines(STUDY_AGENTS, 20), sep="\\n")` lists each table seed's walk holes instead of
writing anything).

`pretrained_roi_tables` is the pre-training itself (`Q_Learning_ROI.m`), also used by the
"per-run" switch with the run's stream.
"""

from __future__ import annotations

import hashlib
import json
from dataclasses import asdict
from pathlib import Path

import numpy as np

from skyherd.policy.sql import kernels
from skyherd.policy.sql.layout import Layout
from skyherd.policy.sql.params import RoiPretrain, Rules, SQLHyper

TABLES_DIR = Path(__file__).with_name("roi_tables")
"""Saved fixed tables, one `.npz` per key (`table_path`)."""
STUDY_AGENTS = (4, 9, 16, 25, 36)
"""The formations whose fixed tables are saved (published rules, default settings)."""

_LOADED: dict[str, np.ndarray] = {}


def pretrained_roi_tables(
    layout: Layout, hyper: SQLHyper, rules: Rules, rng: np.ndarray, pre: RoiPretrain
) -> np.ndarray:
    """(T, R, 4) per-target ROI tables trained as the published `Q_Learning_ROI.m` does.

    Starts every episode on the ROI's lowest-x, lowest-y cell; α and γ from `hyper`, ties by
    `rules.ties`. `rng` (a kernel state) is advanced.
    """
    roi = np.flatnonzero(layout.roi_id >= 0)
    corner = int(roi.min())  # cell index grows with y then x: the (x_min, y_min) corner
    q2 = np.zeros((layout.targets.shape[0], layout.n_roi, 4))
    kernels.pretrain_roi(
        layout.next_cell, layout.roi_id, layout.targets, corner, q2, pre.episodes,
        pre.max_steps, pre.eps_decay, pre.eps_min, pre.reward, hyper.alpha, hyper.gamma,
        rules.ties == "first", rng, rules.q_form == "blend",
    )  # fmt: skip
    return q2


def table_key(layout: Layout, hyper: SQLHyper, rules: Rules, pre: RoiPretrain) -> dict:
    """Everything a fixed table depends on (obstacles never lie in the ROI: not part of it)."""
    roi = np.flatnonzero(layout.roi_id >= 0)
    return {
        "size": layout.size,
        "roi_cells": [list(layout.xy(int(s))) for s in roi],
        "flags": [list(layout.xy(int(s))) for s in layout.targets],
        "pretrain": asdict(pre),
        "alpha": hyper.alpha,
        "gamma": hyper.gamma,
        "ties": rules.ties,
        "q_form": rules.q_form,
    }


def _digest(key: dict) -> str:
    return hashlib.sha256(json.dumps(key, sort_keys=True).encode()).hexdigest()[:16]


def table_path(key: dict) -> Path:
    """Where the table of `key` is saved: roi_tables/K<T>_<digest of the key>.npz."""
    return TABLES_DIR / f"K{len(key['flags'])}_{_digest(key)}.npz"


def fixed_roi_table(layout: Layout, hyper: SQLHyper, rules: Rules, pre: RoiPretrain) -> np.ndarray:
    """The formation's fixed (T, R, 4) table (a copy): loaded if saved, else pre-trained from
    `pre.seed` once per process. The same key gives the same values bit for bit either way."""
    key = table_key(layout, hyper, rules, pre)
    d = _digest(key)
    if d not in _LOADED:
        path = table_path(key)
        if path.exists():
            with np.load(path) as f:
                if json.loads(str(f["key"])) != key:
                    raise ValueError(f"{path}: saved key does not match its name; rewrite it")
                q2 = f["q2"]
        else:
            q2 = pretrained_roi_tables(layout, hyper, rules, kernels.rng_state(pre.seed), pre)
        q2.setflags(write=False)
        _LOADED[d] = q2
    return _LOADED[d].copy()


def save_table(layout: Layout, hyper: SQLHyper, rules: Rules, pre: RoiPretrain) -> Path:
    """Pre-train the table of this key from `pre.seed` and save it (`table_path`)."""
    key = table_key(layout, hyper, rules, pre)
    q2 = pretrained_roi_tables(layout, hyper, rules, kernels.rng_state(pre.seed), pre)
    path = table_path(key)
    path.parent.mkdir(exist_ok=True)
    np.savez_compressed(path, q2=q2, key=np.array(json.dumps(key, sort_keys=True)))
    return path


def walk_holes(layout: Layout, q2: np.ndarray, ties_first: bool = True, max_moves: int = 1000):
    """Where the greedy walk of a table never arrives: [((x, y), flag id)] for every cell on
    the ROI's lower row or left column (where phase 1 enters it) and every flag whose walk from
    there does not reach the flag in `max_moves` moves (ε = 0, as the published walk)."""
    roi = np.flatnonzero(layout.roi_id >= 0)
    x0, y0 = layout.xy(int(roi.min()))
    edge = [int(s) for s in roi if layout.xy(int(s))[0] == x0 or layout.xy(int(s))[1] == y0]
    holes = []
    for k, flag in enumerate(layout.targets):
        for s in edge:
            c, n = s, 0
            while c != flag and n < max_moves:
                row = q2[k, layout.roi_id[c]]
                a = kernels.greedy_first(row) if ties_first else int(np.argmax(row))
                c, n = kernels.roi_step(c, a, layout.next_cell, layout.roi_id), n + 1
            if c != flag:
                holes.append((layout.xy(s), k))
    return holes


WALKABLE_SEARCH = 200
"""Table seeds `walkable_seed` tries (0 .. this - 1)."""
WALKABLE_INDEX = TABLES_DIR / "walkable.json"
"""The searched seeds of the saved formations (`write_tables`): {digest of `search_key`:
{"agents": K, "seed": …, "holes": …}}, so `walkable_seed` does not search them again."""


def search_key(layout: Layout, hyper: SQLHyper, rules: Rules, pre: RoiPretrain,
               limit: int) -> dict:  # fmt: skip
    """Everything `search_walkable_seed` depends on: a table's key without its seed, the walk's
    tie rule (in the key) and the seeds tried."""
    key = table_key(layout, hyper, rules, pre)
    key["pretrain"].pop("seed")
    return {**key, "search_limit": limit}


def search_walkable_seed(layout: Layout, hyper: SQLHyper, rules: Rules, pre: RoiPretrain,
                         limit: int = WALKABLE_SEARCH) -> tuple[int, int]:  # fmt: skip
    """The first table seed whose greedy walks all arrive (`walk_holes` finds none), and its
    hole count (0); if none of seeds 0..limit-1 has none, the first with the fewest holes.

    The published code walks one table whose walks arrived (its runs: 0 walk failures); this
    picks such a table from a property of the table alone, before any learning run uses it.
    Pre-trains up to `limit` tables (K = 25, 36: all 200, minutes)."""
    from dataclasses import replace

    best = (0, 10**9)
    for seed in range(limit):
        q2 = pretrained_roi_tables(layout, hyper, rules, kernels.rng_state(seed),
                                   replace(pre, seed=seed))  # fmt: skip
        n = len(walk_holes(layout, q2, rules.ties == "first"))
        if n == 0:
            return seed, 0
        best = min(best, (seed, n), key=lambda b: (b[1], b[0]))
    return best


def walkable_seed(layout: Layout, hyper: SQLHyper, rules: Rules, pre: RoiPretrain,
                  limit: int = WALKABLE_SEARCH) -> tuple[int, int]:  # fmt: skip
    """`search_walkable_seed`'s (seed, holes): saved (`saved_walkable_seed`), else searched."""
    saved = saved_walkable_seed(layout, hyper, rules, pre, limit)
    return saved if saved is not None else search_walkable_seed(layout, hyper, rules, pre, limit)


def saved_walkable_seed(layout: Layout, hyper: SQLHyper, rules: Rules, pre: RoiPretrain,
                        limit: int = WALKABLE_SEARCH) -> tuple[int, int] | None:  # fmt: skip
    """The (seed, holes) of this search in `WALKABLE_INDEX`, None when it was not saved."""
    entry = _walkable_index().get(_digest(search_key(layout, hyper, rules, pre, limit)))
    return None if entry is None else (entry["seed"], entry["holes"])


def _walkable_index() -> dict:
    if not WALKABLE_INDEX.exists():
        return {}
    return json.loads(WALKABLE_INDEX.read_text())


def write_tables(agents: tuple[int, ...] = STUDY_AGENTS) -> list[Path]:
    """Pre-train and save the fixed ROI tables of each K in `agents` (published rules, default
    settings, the study's 50×50 grid): table seed 0 and the first walkable seed
    (`search_walkable_seed`, saved in `WALKABLE_INDEX`); returns the files written."""
    from skyherd.policy.sql.envfile import generate_env

    rules, h, out = Rules.published(), SQLHyper(), []
    index = _walkable_index()
    for k in agents:  # table seed 0 and the first walkable one (reproduce --roi-table-seed auto)
        lay = generate_env(k, 0).layout()
        seed, holes = search_walkable_seed(lay, h, rules, RoiPretrain())
        key = search_key(lay, h, rules, RoiPretrain(), WALKABLE_SEARCH)
        index[_digest(key)] = {"agents": k, "seed": seed, "holes": holes}
        for s in dict.fromkeys((0, seed)):
            out.append(save_table(lay, h, rules, RoiPretrain(seed=s)))
    WALKABLE_INDEX.write_text(json.dumps(index, indent=1, sort_keys=True) + "\n")
    return [*out, WALKABLE_INDEX]


def holes_lines(agents: tuple[int, ...], seeds: int) -> list[str]:
    """One line per K and table seed 0..seeds-1: the walk holes of that table (writes nothing)."""
    from skyherd.policy.sql.envfile import generate_env

    rules, h, out = Rules.published(), SQLHyper(), []
    for k in agents:
        lay = generate_env(k, 0).layout()
        for seed in range(seeds):
            pre = RoiPretrain(seed=seed)
            holes = walk_holes(
                lay, pretrained_roi_tables(lay, h, rules, kernels.rng_state(seed), pre)
            )
            told = ", ".join(f"({x}, {y}) → flag {f}" for (x, y), f in holes) or "none"
            out.append(f"K = {k}, table seed {seed}: {len(holes)} holes: {told}")
    return out
