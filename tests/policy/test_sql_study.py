"""The study's metrics on hand-made series, maps from files (round trip), and
`skyherd reproduce sql` end to end on the process pool and (if installed) on local Ray."""

import csv
import json

import numpy as np
import pytest

from skyherd.policy.sql.envfile import EnvSpec, generate_env
from skyherd.policy.sql.metrics import mean_sd, study_convergence, study_metric, study_summary
from skyherd.policy.sql.params import Rules, SQLHyper
from skyherd.policy.sql.sweep import RunSpec, ray_available, run_all, run_one
from skyherd.scripts.cli import main


def test_study_metric_and_tail_on_a_hand_made_series():
    # 1000 episodes: 300 at the 1200-step cap violation (capped to 1000), then 100 steps,
    # except episode 950 (1-based) at 1500 steps and success only from episode 301 on
    steps = np.r_[np.full(300, 1200.0), np.full(700, 100.0)]
    steps[949] = 1500.0
    on = np.r_[np.zeros(300, bool), np.ones(700, bool)]
    on[949] = False
    assert study_metric(steps)[0] == 1000.0 and study_metric(steps)[400] == 100.0
    s = study_summary(steps, on)
    # tail = last 100 episodes: 99 × 100 + 1000 = 10,900 → 109; 99 of 100 below the cap
    assert s.tail_metric == pytest.approx(109.0) and s.tail_success == pytest.approx(0.99)
    assert s.tail_on_target == pytest.approx(0.99) and s.first_all_reached == 301
    assert study_summary(steps, np.zeros(1000, bool)).first_all_reached is None
    assert s.convergence == study_convergence(study_metric(steps), 100)
    # a run flat at the cap (success 0 < 0.9) did not converge, though its average never
    # rises above 2× its final value
    flat = study_summary(np.full(1000, 1000.0), np.zeros(1000, bool))
    assert flat.convergence is None and flat.tail_success == 0.0
    assert study_convergence(np.full(1000, 1000.0), 100) == 100


def test_convergence_episode_on_a_hand_made_series():
    # 300 × 1000 then 700 × 100; final 100-episode average = 100. A window ending at episode
    # e ∈ [300, 400] holds c = 400 − e episodes of 1000: average 100 + 9c ≥ 200 ⇔ c ≥ 12 ⇔
    # e ≤ 388. So the average stays below 2 × 100 from episode 389 on.
    m = np.r_[np.full(300, 1000.0), np.full(700, 100.0)]
    assert study_convergence(m, 100) == 389
    # flat series: below 2× its final value from the first full window on
    assert study_convergence(np.full(500, 50.0), 100) == 100
    # the window matters: 10-episode window, the last 1000 ends at 300, windows ending at
    # 301..309 hold 9..1 of them: 100 + 90c ≥ 200 ⇔ c ≥ 2 ⇔ e ≤ 308 → 309
    assert study_convergence(m, 10) == 309


def test_mean_sd_is_the_population_sd():
    assert mean_sd([1.0, 3.0]) == "2.0 ± 1.0"
    assert mean_sd([None, 4.0], 0) == "4 ± 0" and mean_sd([None]) == "–"


def test_env_file_round_trip_and_checks(tmp_path):
    a, b = generate_env(9, 3), generate_env(9, 4)
    assert a != b and a == generate_env(9, 3)  # a different map per seed, reproducible
    assert len(a.obstacles) == 50 and all(not (x >= 45 and y >= 45) for x, y in a.obstacles)
    p = tmp_path / "map.json"
    p.write_text(a.to_json())
    back = EnvSpec.load(p)
    assert back == a
    la, lb = a.layout(), back.layout()
    for f in ("obstacle", "targets", "starts", "roi_id", "target_id"):
        assert np.array_equal(getattr(la, f), getattr(lb, f))
    # duplicates allowed: the map holds the distinct cells
    d = json.loads(a.to_json())
    d["obstacles"] = [[2, 2], [2, 2], [3, 5]]
    spec = EnvSpec.from_json(json.dumps(d))
    assert spec.obstacles == ((2, 2), (2, 2), (3, 5)) and spec.layout().obstacle.sum() == 2
    for bad, msg in (
        ({k: v for k, v in d.items() if k != "flags"}, "missing"),
        ({**d, "flags": d["flags"][:-1]}, "as many flags"),
        ({**d, "flags": [[1, 1]] * 9}, "different"),
        ({**d, "flags": [[10, 10], *d["flags"][1:]]}, "ROI"),
        ({**d, "obstacles": [[1, "x"]]}, "integer pairs"),
    ):
        with pytest.raises(ValueError, match=msg):
            EnvSpec.from_json(json.dumps(bad))
    with pytest.raises(ValueError, match="JSON"):
        EnvSpec.from_json("{nope")
    with pytest.raises(ValueError):  # an obstacle on a start cell
        EnvSpec.from_json(json.dumps({**d, "obstacles": [list(a.starts[0])]})).layout()


def _tiny_specs(n=2):
    h = SQLHyper(episodes=30, max_steps=200)
    return [RunSpec("sql-sie", 4, 1, s, Rules.published(), h) for s in range(n)]


def test_run_all_process_pool_matches_run_one():
    specs = _tiny_specs()
    got = dict(run_all(specs, backend="process", workers=2))
    for s in specs:
        ref = run_one(s)
        assert np.array_equal(got[s].steps, ref.steps) and got[s].env == ref.env
    assert got[specs[0]].env != got[specs[1]].env  # the seed picks the map


@pytest.mark.slow
@pytest.mark.skipif(not ray_available(), reason="Ray not installed (pip install -e '.[ray]')")
def test_run_all_on_local_ray_matches_run_one():
    specs = _tiny_specs()
    got = dict(run_all(specs, backend="ray", workers=2))
    assert set(got) == set(specs)
    for s in specs:
        assert np.array_equal(got[s].steps, run_one(s).steps)
        assert got[s].worker.split(":")[1].isdigit()  # the Ray worker process that ran it


def test_reproduce_sql_end_to_end(tmp_path):
    args = ["reproduce", "sql", "--episodes", "40", "--seeds", "2", "--agents", "4",
            "--sharing-periods", "1", "5", "--window", "10", "--backend", "process",
            "--workers", "2", "--runs-dir", str(tmp_path / "a")]  # fmt: skip
    assert main(args) == 0
    (run,) = list((tmp_path / "a").iterdir())
    rows = list(csv.DictReader(open(run / "metrics.csv")))
    assert len(rows) == 2 * 4  # (SQL, SQL-D, SQL-SIE N=1, N=5) × 2 seeds
    assert {r["seed"] for r in rows} == {"0", "1"} and all(r["worker"] for r in rows)
    ep = list(csv.DictReader(open(run / "episodes" / "published_sql-d_K4_seed1.csv")))
    assert len(ep) == 40 and ep[0]["episode"] == "1"
    md = (run / "results.md").read_text()
    assert "| published | SQL-SIE N=5 | 4 |" in md.replace("  ", " ")
    for f in ("learning_published.png", "success_published.png", "sharing_published.png"):
        assert (run / f).stat().st_size > 10_000
    # the map each seed ran on, in the --env format; feeding it back runs on that map
    m1 = EnvSpec.load(run / "maps" / "K4_seed1.json")
    assert m1 == generate_env(4, 1)
    args2 = ["reproduce", "sql", "--episodes", "40", "--seeds", "1", "--sharing-periods", "1",
             "--window", "10", "--backend", "process", "--workers", "1",
             "--env", str(run / "maps" / "K4_seed1.json"), "--runs-dir", str(tmp_path / "b"),
             "--learners", "sql-d", "--switch", "assign_cell=own"]  # fmt: skip
    assert main(args2) == 0
    (run2,) = list((tmp_path / "b").iterdir())
    assert EnvSpec.load(run2 / "maps" / "K4_seed0.json") == m1
    (row,) = list(csv.DictReader(open(run2 / "metrics.csv")))  # only SQL-D, one seed
    assert row["rules"] == "published-assign_cell-own" and row["algorithm"] == "sql-d"
    cfg = json.loads((run2 / "config.json").read_text())
    assert cfg["rules"]["published-assign_cell-own"]["assign_cell"] == "own"
    a = list(csv.DictReader(open(run / "episodes" / "published_sql-d_K4_seed1.csv")))
    b = list(
        csv.DictReader(open(run2 / "episodes" / "published-assign_cell-own_sql-d_K4_seed0.csv"))
    )
    assert a != b  # same map, other learner seed and assignment cell


def test_reproduce_bad_usage(tmp_path, capsys):
    base = ["reproduce", "sql", "--runs-dir", str(tmp_path)]
    assert main([*base, "--agents", "5"]) == 2
    assert main([*base, "--env", str(tmp_path / "missing.json")]) == 2
    (tmp_path / "bad.json").write_text('{"size": 5}')
    assert main([*base, "--env", str(tmp_path / "bad.json")]) == 2
    assert main([*base, "--switch", "bogus=1"]) == 2
    assert main([*base, "--switch", "q_form"]) == 2
    assert main([*base, "--switch", "q_form=exact"]) == 2
    err = capsys.readouterr().err
    assert "square number" in err and "missing" in err
    assert "no rule switch 'bogus'" in err and "FIELD=VALUE" in err and "'exact'" in err
    assert not any(tmp_path.iterdir()) or all(p.suffix == ".json" for p in tmp_path.iterdir())
