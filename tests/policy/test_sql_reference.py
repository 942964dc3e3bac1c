"""The compiled SQL-D / SQL-SIE kernel under `Rules.published()` against a slow reference.

The reference below is written in the terms of the study's public MATLAB implementation
(`SQL_D.m` / `SQL_SIE.m` and the functions they call, read, not copied): 1-based (x, y)
positions in a K×2 list, Q indexed [x, y, action, agent], obstacles checked in a loop, the
flag looked up at `Q_ROI(currentState(1), currentState(2))` of the whole position matrix, a
`rand` before every action (also in the ε = 0 ROI walk), ε decayed while above its floor, and
every update as (1 − α)·Q + α·target with the max term kept. It takes its random numbers from
the kernels' own generator in the same order as the MATLAB code calls `rand` / `randi`, so for
a given stream the two must agree bit for bit: per-episode step metric, agents on flags,
collisions and the final tables.
"""

from dataclasses import replace

import numpy as np
import pytest

from skyherd.policy.sql import Algorithm, SQLHyper, make_layout
from skyherd.policy.sql import kernels as kn
from skyherd.policy.sql.params import RoiPretrain, Rules
from skyherd.policy.sql.train import pretrained_roi_tables, rng_state, train

M, ROI = 12, 9
STARTS = [(1, 5), (1, 2), (2, 1), (5, 1)]
FLAGS = [(10, 12), (12, 12), (10, 10), (12, 10)]  # id order: row by row from the top
OBST = [(1, 8), (3, 3), (3, 3), (6, 4), (4, 7), (8, 11), (9, 6), (7, 7)]  # one duplicate
MOVES = {0: (0, 1), 1: (0, -1), 2: (-1, 0), 3: (1, 0)}  # up, down, left, right
H = SQLHyper(episodes=150, max_steps=150, eps_decay=0.9, eps_min=0.05)  # floor 0.047


def _first_max(v):
    return int(np.argmax(v))  # numpy's argmax = MATLAB's max: the first of equal values


def _select(qv, eps, rng):
    """action_selection_*: rand, then greedy if rand >= ε, else randi(4)."""
    if kn.uniform(rng) >= eps:
        return _first_max(qv)
    return int(kn.randint(rng, 4))


def reference(q_roi, episodes, share_every, rng):
    """Published SQL-D (share_every 0) / SQL-SIE. q_roi: [x, y, a, flag] pre-trained tables.

    Returns per-episode (metric, agents on their flags, collisions) and Q [x, y, a, agent]."""
    K = len(STARTS)
    Q = np.zeros((M + 1, M + 1, 4, K))
    eps, out = 1.0, []
    for _ in range(episodes):
        cur = [list(p) for p in STARTS]
        stop, n_step, roi_step = [0] * K, [0] * K, 0
        total, free, flag_of, hits = [0] * K, list(range(K)), [-1] * K, 0
        for _step in range(H.max_steps):
            for i in range(K):
                if stop[i] == 0:
                    x, y = cur[i]
                    a = _select(Q[x, y, :, i], eps, rng)
                    tx, ty = x + MOVES[a][0], y + MOVES[a][1]
                    nxt = [x, y] if not (1 <= tx <= M and 1 <= ty <= M) else [tx, ty]
                    collide = any((tx, ty) == o for o in OBST)
                    if collide or any([tx, ty] == cur[j] for j in range(K) if j != i):
                        nxt = [x, y]
                    in_roi = nxt[0] >= ROI and nxt[1] >= ROI
                    r = 10.0 if in_roi else (-1.0 if collide else 0.0)
                    hits += collide
                    target = r + H.gamma * Q[nxt[0], nxt[1], :, i].max()
                    Q[x, y, a, i] = (1 - H.alpha) * Q[x, y, a, i] + H.alpha * target
                    cur[i], n_step[i] = nxt, n_step[i] + 1
                    stop[i] = 1 if in_roi else 0
                elif stop[i] == 1:
                    # flag_assignment(currentState, ...): currentState(1), currentState(2)
                    # of the K×2 matrix are agent 1's and agent 2's x
                    vals = q_roi[cur[0][0], cur[1][0]][:, free].T.reshape(-1)  # action fastest
                    k = free.pop(_first_max(vals) // K)  # ceil(idx / flag_num), 0-based
                    flag_of[i], collect, roi_step = k, False, 0
                    while not collect and roi_step < H.max_steps:
                        kn.uniform(rng)  # the walk's rand, compared with ε = 0
                        a = _first_max(q_roi[cur[i][0], cur[i][1], :, k])
                        tx, ty = cur[i][0] + MOVES[a][0], cur[i][1] + MOVES[a][1]
                        if ROI <= tx <= M and ROI <= ty <= M:
                            cur[i] = [tx, ty]
                        collect = (tx, ty) == FLAGS[k]
                        roi_step += 1
                    stop[i] = 2
                total[i] = n_step[i] + roi_step
            if all(s == 2 for s in stop):
                break
        if eps > H.eps_min:
            eps *= H.eps_decay
        if share_every and (len(out) + 1) % share_every == 0:
            nz = np.where(Q != 0, Q, -np.inf).max(axis=3)
            Q[:] = np.where(np.isfinite(nz), nz, 0.0)[..., None]
        on = sum(flag_of[i] >= 0 and tuple(cur[i]) == FLAGS[flag_of[i]] for i in range(K))
        out.append((max(total), on, hits))
    return np.array(out), Q


@pytest.mark.parametrize("algorithm,share_every", [(Algorithm.SQL_D, 0), (Algorithm.SQL_SIE, 5)])
def test_kernel_matches_the_published_reference_bit_for_bit(algorithm, share_every):
    lay = make_layout(M, STARTS, FLAGS, ROI, OBST)
    rules, pre = Rules.published(), RoiPretrain(episodes=300, max_steps=150)
    hyper = replace(H, share_every=max(share_every, 1))
    run = train(algorithm, lay, hyper, 3, rules=rules, pretrain=pre)  # the trainer's path
    # the fixed table (roi_table="fixed"): pre-trained from its own seed's stream, as the
    # published code loads one made by a separate program; the run's stream starts at episode 1
    q2 = pretrained_roi_tables(lay, H, rules, rng_state(pre.seed), pre)
    np.testing.assert_array_equal(q2, run.q_target)
    rng = rng_state(3)
    q_roi = np.zeros((M + 1, M + 1, 4, len(FLAGS)))  # the kernel's (T, R, 4) as [x, y, a, k]
    for s in np.flatnonzero(lay.roi_id >= 0):
        x, y = lay.xy(int(s))
        q_roi[x, y] = q2[:, lay.roi_id[s]].T
    ref, Q = reference(q_roi, H.episodes, share_every, rng)
    m = run.metrics
    assert m.reached.max() == len(STARTS) and m.steps.min() < 40  # it learned
    assert (ref[:, 2] > 0).any()  # obstacles were hit, so their rule is exercised
    np.testing.assert_array_equal(m.steps, ref[:, 0])
    np.testing.assert_array_equal(m.reached, ref[:, 1])
    np.testing.assert_array_equal(m.collisions, ref[:, 2])
    for i in range(len(STARTS)):
        for s in range(lay.n_cells):
            x, y = lay.xy(s)
            np.testing.assert_array_equal(run.q[i, s], Q[x, y, :, i])  # bit for bit
