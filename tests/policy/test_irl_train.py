"""`skyherd train irl|ab` end to end with a tiny budget: run folder, tables, plots, policy files."""

import json

import numpy as np
import pytest

from skyherd.policy import load_policy
from skyherd.scripts.cli import main


@pytest.mark.slow
def test_train_ab_end_to_end_tiny(tmp_path, capsys):
    out = tmp_path / "runs"
    saved = tmp_path / "p.npz"
    rc = main(
        [
            "train",
            "ab",
            "--seeds",
            "1",
            "--dqn-steps",
            "600",
            "--irl-iters",
            "2",
            "--eval-episodes",
            "2",
            "--mu-episodes",
            "3",
            "--transfer-episodes",
            "1",
            "--demo-episodes",
            "2",
            "--rules",
            "mean,per_feature",
            "--runs-dir",
            str(out),
            "--save-policy",
            str(saved),
        ]
    )
    assert rc == 0
    (run,) = list(out.iterdir())
    for name in (
        "config.json",
        "summary.md",
        "metrics.csv",
        "events.jsonl",
        "irl_t.png",
        "compare.png",
        "results.json",
        "demos/lateral.npz",
        "demos/composite.npz",
        "policies/irl_seed0.npz",
        "policies/ab_mean_seed0.npz",
        "policies/ab_per_feature_seed0.npz",
    ):
        assert (run / name).exists(), name
    cfg = json.loads((run / "config.json").read_text())
    assert set(cfg["mu_expert"]) == {"irl", "ab_mean", "ab_per_feature"}
    summary = (run / "summary.md").read_text()
    assert "expert (demonstrator)" in summary and "random" in summary and "÷ IRL" in summary
    assert "groundsim:camouflage" in summary  # the transfer table
    lines = (run / "metrics.csv").read_text().splitlines()
    assert len(lines) == 1 + 3 * 2  # header + 3 learners × 2 iterations
    assert "" not in lines[1].split(",")  # every column filled, μ included
    pol = load_policy(saved)
    assert pol.meta["learner"] == "ab_mean" and pol(np.full(14, 0.5, np.float32)) in range(7)


@pytest.mark.slow
def test_train_ab_is_deterministic_for_a_seed_in_process_and_in_a_pool(tmp_path):
    """Two runs of one small config with one seed (the DQN trained: steps > learning_starts)
    give identical weights and results, in the command's process or in worker processes
    (docs/learning.md's tables rest on this)."""
    args = ["train", "ab", "--seeds", "1", "--seed", "3", "--dqn-steps", "1300", "--irl-iters",
            "2", "--eval-episodes", "2", "--mu-episodes", "2", "--transfer-episodes", "0",
            "--demo-episodes", "2", "--rules", "mean"]  # fmt: skip
    runs = []
    for name, workers in (("a", "1"), ("b", "2")):
        out = tmp_path / name
        assert main([*args, "--workers", workers, "--runs-dir", str(out)]) == 0
        (run,) = out.iterdir()
        runs.append(run)
    first = {p.name: np.load(p) for p in sorted((runs[0] / "policies").glob("*.npz"))}
    assert set(first) == {"irl_seed3.npz", "ab_mean_seed3.npz"}
    keep = ("learner", "seed", "metrics", "chosen", "t0", "mixture")  # not the timings

    def facts(run):
        r = json.loads((run / "results.json").read_text())
        learned = sorted([[x[k] for k in keep] for x in r["learned"]])
        hist = {x["learner"]: [(h["t"], h["mu"]) for h in x["history"]] for x in r["learned"]}
        return learned, hist, r["baselines"]

    for run in runs[1:]:
        for name, a in first.items():
            b = np.load(run / "policies" / name)
            for k in a.files:
                if k != "meta":
                    np.testing.assert_array_equal(a[k], b[k], err_msg=f"{run.name} {name} {k}")
        assert facts(run) == facts(runs[0])


def test_train_irl_from_teleop_style_demo_folder(tmp_path):
    from skyherd.policy.demos import record, scripted_expert

    demos = tmp_path / "demos"
    demos.mkdir()
    record("composite", scripted_expert("composite"), 1, 5, "teleop:keyboard").save(
        demos / "composite.npz"
    )
    rc = main(
        [
            "train",
            "irl",
            "--seeds",
            "1",
            "--dqn-steps",
            "300",
            "--irl-iters",
            "1",
            "--eval-episodes",
            "1",
            "--mu-episodes",
            "2",
            "--transfer-episodes",
            "0",
            "--demos",
            str(demos),
            "--out",
            str(tmp_path / "r"),
        ]
    )
    assert rc == 0
    (run,) = list((tmp_path / "r").iterdir())
    cfg = json.loads((run / "config.json").read_text())
    assert cfg["demos"] == {"composite": "teleop:keyboard"}


def test_train_bad_usage(tmp_path):
    assert main(["train", "ab", "--rules", "median", "--out", str(tmp_path)]) == 2
    assert main(["train", "irl", "--seeds", "0", "--out", str(tmp_path)]) == 2
    assert main(["train", "irl", "--demos", str(tmp_path / "none"), "--out", str(tmp_path)]) == 2
    with pytest.raises(SystemExit):
        main(["train", "irl", "--help"])


def test_committed_policy_keeps_the_team_in_view():
    """The policy the repo keeps (AB, trained without composite demos) on fresh composite seeds."""
    from pathlib import Path

    from skyherd.policy.demos import rollout_stats

    path = (
        Path(__file__).resolve().parents[2] / "skyherd" / "policy" / "models" / "groundair_ab.npz"
    )
    assert path.stat().st_size < 2_000_000
    pol = load_policy(path)
    assert pol.meta["learner"].startswith("ab_") and pol.obs_dim == 14 and pol.n_actions == 7
    _, m = rollout_stats(pol, "composite", 10, 300_000, 0.97)
    assert m["all_in_view_frac"] >= 0.9 and m["ugv_losses"] <= 1.0
    _, mr = rollout_stats(lambda o: 0, "composite", 10, 300_000, 0.97)  # hover only
    assert m["all_in_view_frac"] > mr["all_in_view_frac"] + 0.3
