"""The rule switches (`Rules`): on tiny hand-made maps where the published and the intended
variant of a rule give different results, both computed by hand in the comments."""

from dataclasses import replace

import numpy as np
import pytest

from skyherd.policy.sql import Algorithm, SQLHyper, greedy_rollout, make_layout
from skyherd.policy.sql.kernels import claim_target
from skyherd.policy.sql.params import Rules
from skyherd.policy.sql.train import Metrics, TrainResult, _call, pretrained_roi_tables, rng_state

UP, DOWN, LEFT, RIGHT = 0, 1, 2, 3
GREEDY = dict(eps_start=0.0, eps_min=0.0)


def _result(alg, lay, h, q1, q2, rules):
    z = np.zeros(1)
    return TrainResult(alg, lay, h, 0, Metrics(z, z, z, z, z), q1, q2, rules)


def test_rule_sets_and_their_validation():
    p, i = Rules.published(), Rules.intended()
    assert (p.ties, p.team_bonus, p.roi_phase, p.assign, p.step_count) == (
        "first", "blend", "pretrained", "q-argmax", "published"
    )  # fmt: skip
    assert (i.ties, i.team_bonus, i.roi_phase, i.assign, i.step_count) == (
        "random", "add", "online", "nearest", "own"
    )  # fmt: skip
    assert (p.assign_cell, p.walk_draws, p.walk_end, p.eps_schedule, p.q_form) == (
        "agents-1-2", "per-move", "step-onto", "stop-decay", "blend"
    )  # fmt: skip
    assert (i.assign_cell, i.walk_draws, i.walk_end, i.eps_schedule, i.q_form) == (
        "own", "none", "on-flag", "clip", "delta"
    )  # fmt: skip
    assert Rules.named("intended", "first").ties == "first" and Rules() == Rules.intended()
    assert Rules.named("intended", "first").name == "intended-first-ties"
    assert Rules.named("published", "first") == Rules.published()
    with pytest.raises(ValueError, match="ties"):
        Rules(ties="last")
    with pytest.raises(ValueError, match="pretrained"):
        Rules(assign="q-argmax", roi_phase="online")
    with pytest.raises(ValueError, match="rule set"):
        Rules.named("matlab")
    with pytest.raises(ValueError, match="q_form"):
        Rules(q_form="exact")


def test_ties_first_drifts_up_on_a_zero_table():
    # 3×3, one agent at (1,1), target (3,3). Zero table, ε = 0: "first" always takes action 0
    # (up): (1,1) → (1,2) → (1,3) → stays at the top wall; it never reaches the target.
    lay = make_layout(3, [(1, 1)], [(3, 3)], roi_min=3)
    h = SQLHyper(max_steps=6, **GREEDY)
    q = np.zeros((1, 9, 4))
    paths, m = greedy_rollout(_result(Algorithm.SQL, lay, h, q, None, Rules(ties="first")))
    assert [lay.xy(s) for s in paths[0]] == [(1, 1), (1, 2), (1, 3), (1, 3), (1, 3), (1, 3), (1, 3)]
    assert not m.success[0] and m.steps[0] == 6
    # "random": the same zero table sends it in other directions too (seeded, so fixed)
    paths, _ = greedy_rollout(_result(Algorithm.SQL, lay, h, q, None, Rules(ties="random")))
    moves = {lay.xy(b)[0] - lay.xy(a)[0] for a, b in zip(paths[0], paths[0][1:])}
    assert moves != {0}  # some move changed x: not always "up"


def _one_step_sql(rules, max_steps):
    # one row  . A T : the agent's table says "right"; reaching T is +10 (α = 0.1)
    lay = make_layout(3, [(2, 1)], [(3, 1)], roi_min=3)
    h = SQLHyper(max_steps=max_steps, **GREEDY)
    q = np.zeros((1, 9, 4))
    q[0, lay.cell(2, 1), RIGHT] = 1e-9
    rng, no_paths = np.array([1], np.uint64), np.zeros((0, 0), np.int32)
    _call(Algorithm.SQL, lay, h, q, None, np.zeros(1), True, rng, 0, no_paths, rules)
    return q[0, lay.cell(2, 1), RIGHT]


def test_team_bonus_blend_versus_add():
    # after the move Q ≈ 0.1·10 = 1.0; the team bonus for "all reached" is +10
    # add:   Q ← Q + α·10 = 2.0;   blend: Q ← 0.9·Q + 0.1·10 = 1.9
    assert _one_step_sql(Rules(team_bonus="add"), 5) == pytest.approx(2.0, abs=1e-8)
    assert _one_step_sql(Rules(team_bonus="blend"), 5) == pytest.approx(1.9, abs=1e-8)
    # blend, the agent stops on the last allowed step: the published loop never sees "all
    # stopped", so the bonus is the "reached" one, −1: Q ← 0.9·1.0 − 0.1 = 0.8 (add: 2.0)
    assert _one_step_sql(Rules(team_bonus="blend"), 1) == pytest.approx(0.8, abs=1e-8)
    assert _one_step_sql(Rules(team_bonus="add"), 1) == pytest.approx(2.0, abs=1e-8)


def _two_agent_roi_world():
    """4×4 grid, ROI x, y ≥ 3; targets T0 = (4,4), T1 = (4,3).

    A0 starts at (1,4) and goes right twice (enters the ROI at (3,4) on step 2).
    A1 starts at (2,3) and goes right (enters at (3,3) on step 1); nearest free target T1.
    Target tables: T1 from (3,3): up (3,4), right (4,4), down (4,3) — 3 moves, through
    A0's cell and T0; T0 from (3,4): right (4,4) — 1 move.
    """
    lay = make_layout(4, [(1, 4), (2, 3)], [(4, 4), (4, 3)], roi_min=3)
    q1 = np.zeros((2, 16, 4))
    q1[0, lay.cell(1, 4), RIGHT] = q1[0, lay.cell(2, 4), RIGHT] = 1.0
    q1[1, lay.cell(2, 3), RIGHT] = 1.0
    q2 = np.zeros((2, lay.n_roi, 4))
    r = lambda x, y: lay.roi_id[lay.cell(x, y)]  # noqa: E731
    q2[1, r(3, 3), UP] = q2[1, r(3, 4), RIGHT] = q2[1, r(4, 4), DOWN] = 1.0
    q2[0, r(3, 4), RIGHT] = 1.0
    return lay, q1, q2


@pytest.mark.parametrize(
    "rules,metric,success,reached",
    [
        # published walk, published count. Step 2: A0 enters (3,4) (2 moves); A1 walks T1 in
        # its turn: 3 moves, ROI_step = 3. Step 3: A0 walks 1 move, ROI_step = 1 → A0 2 + 1
        # = 3; A1 (stopped, its turn after A0) 1 + ROI_step 1 = 2. Max = 3; all on targets.
        (replace(Rules.published(), assign="nearest"), 3, True, 2),
        # the same walks, each agent's own count: A1 = 1 + 3 = 4
        (replace(Rules.published(), assign="nearest", step_count="own"), 4, True, 2),
        # intended (online, one move per step, agents block): step 2 A0 enters (3,4), A1's
        # "up" is blocked; step 3 A0 → (4,4) done (3 steps), A1 → (3,4); from step 4 on A1's
        # "right" hits A0 on T0 every step: it never arrives → cap 10, 1 agent on a target.
        (Rules.intended(ties="first"), 10, False, 1),
    ],
)
def test_roi_phase_and_step_count_rules(rules, metric, success, reached):
    lay, q1, q2 = _two_agent_roi_world()
    h = SQLHyper(max_steps=10, **GREEDY)
    paths, m = greedy_rollout(_result(Algorithm.SQL_D, lay, h, q1, q2, rules))
    assert int(m.steps[0]) == metric
    assert bool(m.success[0]) is success and int(m.reached[0]) == reached
    if rules.roi_phase == "pretrained":  # A1's whole walk lands within global step 2
        assert lay.xy(paths[1][2]) == (4, 3) and lay.xy(paths[0][3]) == (4, 4)


def test_claim_target_q_argmax_versus_nearest():
    # K = 9 targets on a 5×5 corner of a 10×10 grid; the agent on (6,6); all targets free.
    M = 10
    xy = [(x, y) for y in (10, 8, 6) for x in (6, 8, 10)]  # id order, as the study's flags
    targets = np.array([(y - 1) * M + (x - 1) for x, y in xy], np.int64)
    s = 5 * M + 5  # (6,6)
    claimed = np.zeros(9, np.bool_)
    rows = np.zeros((9, 4))
    rows[8, RIGHT] = 1.0  # the largest pre-trained value: target 8, action 3
    # published: flattened index 8·4 + 3 = 35 (0-based), free target ceil(36 / 9) = 4th → id 3
    assert claim_target(s, rows, claimed, targets, M, True) == 3
    # nearest free target to (6,6): (6,6) itself, id 6
    assert claim_target(s, rows, claimed, targets, M, False) == 6
    # ids 0..2 taken: target 8 is now the 6th free one, index 5·4 + 3 = 23, ceil(24 / 9) = 3
    # → the 3rd free target, id 5; nearest is still id 6
    claimed[:3] = True
    assert claim_target(s, rows, claimed, targets, M, True) == 5
    assert claim_target(s, rows, claimed, targets, M, False) == 6
    # id 6 taken too: (6,8) id 3 and (8,6) id 7 are both 2 cells away → the lower id, 3
    claimed[6] = True
    assert claim_target(s, rows, claimed, targets, M, False) == 3
    # K = 4: ceil(idx / 4) is exactly the argmax's target
    rows4 = np.zeros((4, 4))
    rows4[2, DOWN] = 0.5
    assert claim_target(s, rows4, np.zeros(4, np.bool_), targets[:4], M, True) == 2


def test_pretrained_roi_tables_walk_greedily_to_each_target():
    # 8×8 grid, ROI x, y ≥ 5 (16 cells), 4 targets: from the corner (5,5) each greedy walk
    # takes the Manhattan distance
    xy = [(6, 8), (8, 8), (6, 6), (8, 6)]
    lay = make_layout(8, [(1, 1), (1, 3), (3, 1), (2, 2)], xy, roi_min=5)
    q2 = pretrained_roi_tables(lay, SQLHyper(), Rules.published(), rng_state(0), _pre())
    from skyherd.policy.sql.kernels import greedy_first, roi_step

    for k, (x, y) in enumerate(xy):
        s, n = lay.cell(5, 5), 0
        while s != lay.targets[k] and n < 50:
            s = roi_step(s, greedy_first(q2[k, lay.roi_id[s]]), lay.next_cell, lay.roi_id)
            n += 1
        assert n == (x - 5) + (y - 5)


def _pre():
    from skyherd.policy.sql.params import RoiPretrain

    return RoiPretrain(episodes=2000)


def test_eps_schedule_stop_decay_versus_clip():
    # ε_0 = 1, ×0.5 per episode, floor 0.2. Published loop "if ε > 0.2: ε ← 0.5 ε":
    # 1, 0.5, 0.25, then 0.125 (0.25 > 0.2 was still true) and no more decay; clip: 0.2
    h = SQLHyper(eps_decay=0.5, eps_min=0.2)
    assert h.epsilons(0, 6, stop_decay=True).tolist() == [1, 0.5, 0.25, 0.125, 0.125, 0.125]
    assert h.epsilons(0, 6).tolist() == [1, 0.5, 0.25, 0.2, 0.2, 0.2]
    # the study's 0.999 / 0.05: the loop stops at 0.999^2995 = 0.04996 (a chunk = the whole)
    s = SQLHyper().epsilons(0, 3000, stop_decay=True)
    assert s[2994] > 0.05 > s[2995] == s[2999] == pytest.approx(0.04996, abs=1e-5)
    np.testing.assert_array_equal(SQLHyper().epsilons(2990, 10, stop_decay=True), s[2990:])


def test_q_form_blend_versus_delta_rounding():
    # Q = 1.303, a terminal move with r = 7.887: 0.9·1.303 + 0.1·7.887 = 1.1727 + 0.7887 =
    # 1.9614. blend computes exactly that sum (rounds to the double 1.9614); delta computes
    # 1.303 + 0.1·6.584 and rounds to the next double below: 1.9613999999999998.
    from skyherd.policy.sql.kernels import q_update

    for blend, want in ((True, 1.9614), (False, 1.9613999999999998)):
        q = np.array([[1.303, 0.0, 0.0, 0.0]])
        q_update(q, 0, 0, 7.887, 0, True, 0.1, 0.9, blend)
        assert q[0, 0] == want  # exact: the two forms differ in the last bit here


def test_assign_cell_reads_agent_1_and_2_x():
    # MATLAB's currentState(1), currentState(2) on the K×2 matrix [x y]: column-major
    # elements 1 and 2 = x of agent 1 and x of agent 2; for K = 1: agent 1's x and y
    from skyherd.policy.sql.kernels import assign_cell

    lay = make_layout(10, [(5, 7), (8, 2), (1, 1)], [(9, 9), (10, 9), (9, 10)], roi_min=9)
    pos = lay.starts.astype(np.int64)
    assert lay.xy(assign_cell(pos, 10)) == (5, 8)
    assert lay.xy(assign_cell(pos[:1], 10)) == (5, 7)


def _claim_world(rules):
    """6×6 grid, ROI x, y ≥ 4, K = 4; flags T0 (5,6), T1 (6,6), T2 (6,4), T3 (6,5).

    A0 (1,1), A1 (2,1), A2 (3,1) press "down" into the bottom wall for ever; A3 (3,4) moves
    right into the ROI at (4,4) on step 1 and claims a flag in its turn of step 2.
    Pre-trained values at (4,4): T2 right 1.0 (the largest), T0 up 0.5; T2's walk right,
    right (2 moves), T0's up, up, right (3 moves).
    """
    lay = make_layout(6, [(1, 1), (2, 1), (3, 1), (3, 4)], [(5, 6), (6, 6), (6, 4), (6, 5)], 4)
    q1 = np.zeros((4, 36, 4))
    for i, (x, y) in enumerate([(1, 1), (2, 1), (3, 1)]):
        q1[i, lay.cell(x, y), DOWN] = 1.0
    q1[3, lay.cell(3, 4), RIGHT] = 1.0
    q2 = np.zeros((4, lay.n_roi, 4))
    r = lambda x, y: lay.roi_id[lay.cell(x, y)]  # noqa: E731
    q2[2, r(4, 4), RIGHT] = q2[2, r(5, 4), RIGHT] = 1.0
    q2[0, r(4, 4), UP] = q2[0, r(4, 5), UP] = q2[0, r(4, 6), RIGHT] = 0.5
    h = SQLHyper(max_steps=3, **GREEDY)
    rng, paths = np.array([7], np.uint64), np.full((4, 4), -1, np.int32)
    _call(Algorithm.SQL_D, lay, h, q1, q2, np.zeros(1), False, rng, 0, paths, rules)
    return lay.xy(paths[3][2]), int(rng[0] - np.uint64(7))


def test_assign_cell_and_walk_draws_in_the_published_claim():
    own = replace(Rules.published(), assign_cell="own", walk_draws="none")
    # own cell (4,4): argmax T2·right, flattened index 2·4 + 3 = 11, free target
    # ceil(12 / 4) = 3rd → T2 (6,4); ε = 0 everywhere: no random draw at all
    assert _claim_world(own) == ((6, 4), 0)
    # agents-1-2: A0 and A1 stand at x = 1 and 2 → cell (1, 2), outside the ROI, all 0 →
    # the first free flag, T0 (5,6), 3 moves
    cell12 = replace(own, assign_cell="agents-1-2")
    assert _claim_world(cell12) == ((5, 6), 0)
    # per-move draws: the 3 walk moves draw 3 numbers (splitmix64 adds its constant per draw)
    golden = 0x9E3779B97F4A7C15
    assert _claim_world(Rules.published()) == ((5, 6), (3 * golden) % 2**64)


def _walk_from_the_flag(flag, q2_setup, rules):
    """4×4 grid, ROI x, y ≥ 3, K = 1: the agent moves right from (2, y) onto its flag's cell
    (3, y) on the ROI's edge, so its walk (next step) starts on its own flag."""
    lay = make_layout(4, [(2, flag[1])], [flag], roi_min=3)
    q1 = np.zeros((1, 16, 4))
    q1[0, lay.cell(2, flag[1]), RIGHT] = 1.0
    q2 = np.zeros((1, lay.n_roi, 4))
    for (x, y), a in q2_setup:
        q2[0, lay.roi_id[lay.cell(x, y)], a] = 1.0
    h = SQLHyper(max_steps=10, **GREEDY)
    paths, m = greedy_rollout(_result(Algorithm.SQL_D, lay, h, q1, q2, rules))
    return int(m.steps[0]), bool(m.success[0]), lay.xy(paths[0][-1])


def test_walk_end_step_onto_versus_on_flag():
    pub = Rules.published()
    on_flag = replace(pub, walk_end="on-flag")
    # flag (3, 4) in the top row: the flag's own row of its table is all 0 → "up", off the
    # grid: the agent stays. step-onto: no move ever lands on the flag, the walk uses its
    # whole budget of 10 moves standing on it: metric 1 + 10 = 11, and it is on its flag
    assert _walk_from_the_flag((3, 4), [], pub) == (11, True, (3, 4))
    # on-flag: done at once, 0 moves: metric 1
    assert _walk_from_the_flag((3, 4), [], on_flag) == (1, True, (3, 4))
    # flag (3, 3): "up" to (3, 4), whose row says "down", back onto the flag: 2 moves → 3
    assert _walk_from_the_flag((3, 3), [((3, 4), DOWN)], pub) == (3, True, (3, 3))
    assert _walk_from_the_flag((3, 3), [((3, 4), DOWN)], on_flag) == (1, True, (3, 3))
