"""One fixed ROI table per formation (Rules.roi_table "fixed", the published code's one
`Q_matrix_ROI*.mat`), saved and loaded, and the study's small-K results from fixed seeds."""

import json
from collections import Counter
from dataclasses import replace

import numpy as np
import pytest

from skyherd.policy.sql import roitable
from skyherd.policy.sql.envfile import generate_env
from skyherd.policy.sql.layout import make_layout
from skyherd.policy.sql.metrics import study_summary
from skyherd.policy.sql.params import Algorithm, RoiPretrain, Rules, SQLHyper
from skyherd.policy.sql.roitable import (
    STUDY_AGENTS,
    TABLES_DIR,
    fixed_roi_table,
    pretrained_roi_tables,
    table_key,
    table_path,
)
from skyherd.policy.sql.sweep import RunSpec, run_one
from skyherd.policy.sql.train import rng_state, train


def test_the_saved_tables_are_their_seeds_pretraining_bit_for_bit():
    saved = sorted(TABLES_DIR.glob("*.npz"))
    # per K: table seed 0 and the first walkable seed (one file where they are the same, K = 4)
    counts = Counter(int(p.name[1:].split("_")[0]) for p in saved)
    assert counts == {k: 1 if k == 4 else 2 for k in STUDY_AGENTS}
    for path in saved:
        with np.load(path) as f:
            key, q2 = json.loads(str(f["key"])), f["q2"]
        lay = generate_env(len(key["flags"]), 0).layout()
        rules, pre = Rules.published(), RoiPretrain(seed=key["pretrain"]["seed"])
        assert table_key(lay, SQLHyper(), rules, pre) == key and table_path(key) == path
        fresh = pretrained_roi_tables(lay, SQLHyper(), rules, rng_state(pre.seed), pre)
        np.testing.assert_array_equal(fresh, q2)
        np.testing.assert_array_equal(fixed_roi_table(lay, SQLHyper(), rules, pre), q2)
        assert q2.shape == (len(key["flags"]), len(key["roi_cells"]), 4) and q2.max() > 0


def test_published_runs_walk_one_fixed_table_and_per_run_pretrains_their_own():
    lay = generate_env(4, 0).layout()
    h, pub = SQLHyper(episodes=200), Rules.published()
    table = fixed_roi_table(lay, h, pub, RoiPretrain())
    for alg in (Algorithm.SQL_D, Algorithm.SQL_SIE):
        for seed in (0, 1):
            np.testing.assert_array_equal(train(alg, lay, h, seed, rules=pub).q_target, table)
    per_run = replace(pub, roi_table="per-run")
    q0 = train(Algorithm.SQL_D, lay, h, 0, rules=per_run).q_target
    q1 = train(Algorithm.SQL_D, lay, h, 1, rules=per_run).q_target
    pre = RoiPretrain()
    np.testing.assert_array_equal(q1, pretrained_roi_tables(lay, h, per_run, rng_state(1), pre))
    assert not np.array_equal(q0, q1)  # a new table in every run, from the run's stream
    # the switch changes the run's stream too: pre-training no longer draws from it first
    a = train(Algorithm.SQL_D, lay, h, 1, rules=pub).metrics.steps
    b = train(Algorithm.SQL_D, lay, h, 1, rules=per_run).metrics.steps
    assert not np.array_equal(a, b)
    # a caller cannot change the kept table through the copy it got
    table[:] = -1.0
    assert fixed_roi_table(lay, h, pub, RoiPretrain()).max() > 0


def test_an_unsaved_key_is_pretrained_from_its_own_seed_and_a_bad_file_is_refused(
    tmp_path, monkeypatch
):
    lay = make_layout(8, [(1, 1), (1, 3)], [(7, 8), (8, 8)], 6)
    h, pub = SQLHyper(), Rules.published()
    pre = RoiPretrain(episodes=300, seed=5)
    assert not table_path(table_key(lay, h, pub, pre)).exists()
    got = fixed_roi_table(lay, h, pub, pre)
    np.testing.assert_array_equal(got, pretrained_roi_tables(lay, h, pub, rng_state(5), pre))
    other = fixed_roi_table(lay, h, pub, replace(pre, seed=6))
    assert not np.array_equal(got, other)
    # a saved file whose stored key is not the one its name says: a clear error
    monkeypatch.setattr(roitable, "TABLES_DIR", tmp_path)
    monkeypatch.setattr(roitable, "_LOADED", {})
    pre7 = replace(pre, seed=7)
    path = roitable.save_table(lay, h, pub, pre7)
    assert path.parent == tmp_path
    np.testing.assert_array_equal(
        fixed_roi_table(lay, h, pub, pre7), pretrained_roi_tables(lay, h, pub, rng_state(7), pre7)
    )
    monkeypatch.setattr(roitable, "_LOADED", {})
    with np.load(path) as f:
        q2 = f["q2"]
    np.savez_compressed(path, q2=q2, key=np.array(json.dumps({"size": 9})))
    with pytest.raises(ValueError, match="saved key does not match its name"):
        fixed_roi_table(lay, h, pub, pre7)


def test_the_switch_and_the_settings_are_checked():
    assert Rules.published().roi_table == "fixed" and Rules.intended().roi_table == "per-run"
    r = Rules.named("published", switches={"roi_table": "per-run"})
    assert r.roi_table == "per-run" and r.name == "published-roi_table-per-run"
    with pytest.raises(ValueError, match="roi_table"):
        Rules(roi_table="loaded")
    for bad in ({"episodes": 0}, {"seed": -1}, {"eps_decay": 0.0}, {"eps_min": float("nan")}):
        with pytest.raises(ValueError, match="ROI pre-training"):
            RoiPretrain(**bad)


@pytest.mark.parametrize(
    "K,seed,expected",
    [
        # docs/sql.md, "SQL-D with one fixed ROI table": the K = 9 table's seed-0 run
        (9, 0, (111.718, 0.999, 0.987, 1077, 290)),
        (4, 0, (106.683, 1.0, 1.0, 925, 276)),
    ],
)
def test_a_published_sql_d_result_is_reproduced_from_its_seed(K, seed, expected):
    """The study's protocol (10,000 episodes, the generated map of the seed, the published
    rules with the fixed table): the tail metric, success, all on targets, convergence and
    first all-reached episode of one run, exactly."""
    res = run_one(RunSpec("sql-d", K, 0, seed, Rules.published()))
    s = study_summary(res.steps, res.success, 1000, 100)
    assert (
        s.tail_metric, s.tail_success, s.tail_on_target, s.convergence, s.first_all_reached
    ) == expected  # fmt: skip


def test_walk_holes_name_the_entry_cells_whose_greedy_walk_never_arrives():
    """The published pre-training starts every episode in the ROI's corner, so far entry cells
    of the flags next to it stay unvisited: there the first-index walk presses a wall."""
    lay = generate_env(16, 0).layout()
    pub, h = Rules.published(), SQLHyper()
    holes0 = roitable.walk_holes(lay, fixed_roi_table(lay, h, pub, RoiPretrain()))
    assert holes0 == [((43, 49), 8), ((43, 50), 8), ((49, 43), 12), ((50, 43), 12)]
    q11 = pretrained_roi_tables(lay, h, pub, rng_state(11), RoiPretrain(seed=11))
    assert roitable.walk_holes(lay, q11) == []
    tiny = make_layout(6, [(1, 1)], [(6, 6)], 5)  # a 2×2 ROI: entry cells (5,5) (6,5) (5,6)
    zero = np.zeros((1, 4, 4))  # ties → up: (5,5)→(5,6) and (5,6) press the top wall
    assert roitable.walk_holes(tiny, zero) == [((5, 5), 0), ((5, 6), 0)]


def test_reproduce_takes_a_table_seed_and_labels_its_runs(capsys):
    import argparse

    from skyherd.policy.sql.reproduce import specs_of
    from skyherd.scripts import reproduce
    from skyherd.scripts.cli import main

    p = argparse.ArgumentParser()
    reproduce.add_arguments(p)
    args = p.parse_args(["sql", "--learners", "sql-d", "--agents", "9", "--roi-table-seed", "3"])
    specs = specs_of(args)
    assert {s.rules.name for s in specs} == {"published-table3"}
    assert {s.pretrain.seed for s in specs} == {3} and specs[0].key.startswith("published-table3")
    args = p.parse_args(["sql", "--rules", "published", "intended", "--roi-table-seed", "0"])
    assert {s.rules.name for s in specs_of(args)} == {"published", "intended"}
    # auto (the default): per K the first table seed whose walks all arrive; intended rules
    # walk no fixed table and keep their name
    args = p.parse_args(["sql", "--learners", "sql-d", "--rules", "published", "intended"])
    specs = specs_of(args)
    assert {(s.n_agents, s.rules.name, s.pretrain.seed) for s in specs} == {
        (9, "published-table1", 1), (16, "published-table11", 11),
        (9, "intended", 0), (16, "intended", 0)}  # fmt: skip
    assert "K = 16: ROI table seed 11 (0 walk holes" in capsys.readouterr().out
    for bad in ("-1", "first"):
        assert main(["reproduce", "sql", "--roi-table-seed", bad]) == 2
        assert "--roi-table-seed must be auto or an integer >= 0" in capsys.readouterr().err


def test_the_walkable_seed_is_the_first_table_without_a_hole():
    lay = generate_env(9, 0).layout()
    h, pub = SQLHyper(), Rules.published()
    assert roitable.search_walkable_seed(lay, h, pub, RoiPretrain()) == (1, 0)
    zero_holes = roitable.walk_holes(lay, fixed_roi_table(lay, h, pub, RoiPretrain(seed=1)))
    assert zero_holes == [] and roitable.walk_holes(
        lay, fixed_roi_table(lay, h, pub, RoiPretrain())
    )
    # none without a hole among the seeds tried: the first with the fewest
    seed, holes = roitable.walkable_seed(
        generate_env(25, 0).layout(), h, pub, RoiPretrain(), limit=3
    )
    assert (seed, holes) == (2, 7)  # seeds 0, 1, 2: 19, 14, 7 holes (docs/sql.md)


def test_the_saved_walkable_seeds_are_the_searchs_and_their_tables_holes():
    """walkable.json (write_tables) answers `reproduce sql --roi-table-seed auto` without the
    search (K = 25, 36: all 200 seeds): one entry searched again, every entry's holes counted."""
    h, pub, pre = SQLHyper(), Rules.published(), RoiPretrain()
    saved = {k: roitable.saved_walkable_seed(generate_env(k, 0).layout(), h, pub, pre)
             for k in STUDY_AGENTS}  # fmt: skip
    assert saved == {4: (0, 0), 9: (1, 0), 16: (11, 0), 25: (175, 4), 36: (191, 18)}
    lay = generate_env(9, 0).layout()
    assert roitable.search_walkable_seed(lay, h, pub, pre) == saved[9]
    assert roitable.walkable_seed(lay, h, pub, pre) == saved[9]
    for k, (seed, holes) in saved.items():
        lay = generate_env(k, 0).layout()
        table = fixed_roi_table(lay, h, pub, replace(pre, seed=seed))
        assert len(roitable.walk_holes(lay, table)) == holes
    assert roitable.saved_walkable_seed(lay, h, pub, pre, limit=3) is None  # another search
