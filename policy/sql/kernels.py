"""Compiled (numba) episode loops of SQL (seed Algorithm 1) and SQL-SIE / SQL-D (Algorithm 2).

Everything here works on integer cell indices (see `layout.py`) and float64 Q arrays that the
caller owns and keeps between calls, so a long run is a sequence of short chunks (one progress
bar tick each) with no state hidden in the kernels. The random source is a splitmix64 state
(a length-1 uint64 array) passed in and advanced in place: a given seed gives the same run
bit for bit.

Update rule (Watkins Q-learning, seed eq. for Q):
    Q(s, a) ← Q(s, a) + α [r + γ max_a' Q(s', a') − Q(s, a)],   the max term dropped at a
    terminal transition (target or ROI reached).
"""

from __future__ import annotations

import numpy as np
from numba import njit

# try_move outcome codes
MOVED, WALL, OBSTACLE, AGENT = 0, 1, 2, 3

_GOLDEN = np.uint64(0x9E3779B97F4A7C15)
_M1 = np.uint64(0xBF58476D1CE4E5B9)
_M2 = np.uint64(0x94D049BB133111EB)


@njit(cache=True)
def next_u64(rng):
    """splitmix64: advance `rng[0]` and return 64 random bits."""
    z = rng[0] + _GOLDEN
    rng[0] = z
    z = (z ^ (z >> np.uint64(30))) * _M1
    z = (z ^ (z >> np.uint64(27))) * _M2
    return z ^ (z >> np.uint64(31))


@njit(cache=True)
def uniform(rng):
    """A float in [0, 1) with 53 random bits."""
    return np.float64(next_u64(rng) >> np.uint64(11)) * (1.0 / 9007199254740992.0)


@njit(cache=True)
def randint(rng, n):
    """An int in [0, n)."""
    return np.int64(next_u64(rng) % np.uint64(n))


@njit(cache=True)
def choose_action(q_row, eps, rng):
    """ε-greedy on one row of Q (shape (A,)); ties among the best actions broken at random."""
    n = q_row.shape[0]
    if eps > 0.0 and uniform(rng) < eps:
        return randint(rng, n)
    best = q_row[0]
    for a in range(1, n):
        if q_row[a] > best:
            best = q_row[a]
    n_best = 0
    for a in range(n):
        if q_row[a] == best:
            n_best += 1
    pick = 0 if n_best == 1 else randint(rng, n_best)
    for a in range(n):
        if q_row[a] == best:
            if pick == 0:
                return a
            pick -= 1
    return 0


@njit(cache=True)
def q_update(q, s, a, r, s2, terminal, alpha, gamma):
    """One Q-learning update on table q (shape (S, A)); returns the TD error."""
    target = r
    if not terminal:
        m = q[s2, 0]
        for b in range(1, q.shape[1]):
            if q[s2, b] > m:
                m = q[s2, b]
        target += gamma * m
    td = target - q[s, a]
    q[s, a] += alpha * td
    return td


@njit(cache=True)
def try_move(s, a, next_cell, obstacle, occupant, roi_id, roi_only):
    """Where an agent on cell s ends up after action a, and why (environment rules).

    Off the grid (or out of the ROI when `roi_only`): stay (WALL). Into an obstacle: stay
    (OBSTACLE, a collision). Into a cell another agent holds (occupant > 0): stay (AGENT, no
    penalty). Otherwise move (MOVED). Does not change `occupant`.
    """
    s2 = next_cell[s, a]
    if s2 < 0 or (roi_only and roi_id[s2] < 0):
        return s, WALL
    if obstacle[s2]:
        return s, OBSTACLE
    if occupant[s2] != 0:
        return s, AGENT
    return s2, MOVED


@njit(cache=True)
def share_max_nonzero(q):
    """Knowledge sharing in place on q (shape (K, S, A)).

    Q*(s, a) = max over agents i with Q_i(s, a) ≠ 0 of Q_i(s, a), and 0 where every agent's
    value is 0; Q* is then copied into every agent's table.
    """
    K, S, A = q.shape
    for s in range(S):
        for a in range(A):
            found = False
            m = 0.0
            for i in range(K):
                v = q[i, s, a]
                if v != 0.0 and (not found or v > m):
                    m = v
                    found = True
            for i in range(K):
                q[i, s, a] = m


@njit(cache=True)
def run_sql(
    next_cell,
    obstacle,
    target_id,
    roi_id,
    starts,
    q,
    eps,
    alpha,
    gamma,
    max_steps,
    r_step,
    r_collision,
    r_goal,
    bonus_all,
    bonus_reached,
    bonus_missed,
    learn,
    rng,
    out_steps,
    out_success,
    out_reached,
    out_collisions,
    out_agent_steps,
    paths,
):
    """SQL (seed Algorithm 1) for len(eps) episodes.

    q: (K, S, 4) per-agent tables. Each step every active agent, in index order, picks an
    ε-greedy action on its own table, moves by `try_move`, and learns. Reaching any free
    target gives r_goal and stops the agent there (its cell stays held). At the episode's end
    the team bonus is added to each agent's last (s, a): Q ← Q + α·bonus, which equals adding
    the bonus to that transition's reward. out_*: (E,) per-episode metrics. paths: (K, T+1)
    int32 cell history of the last episode if its shape is not (0, 0).
    """
    K = starts.shape[0]
    S = next_cell.shape[0]
    occ = np.zeros(S, np.int32)
    pos = np.empty(K, np.int64)
    done = np.zeros(K, np.bool_)
    nsteps = np.zeros(K, np.int64)
    last_s = np.zeros(K, np.int64)
    last_a = np.zeros(K, np.int64)
    record = paths.shape[0] > 0
    for e in range(eps.shape[0]):
        occ[:] = 0
        for i in range(K):
            pos[i] = starts[i]
            occ[starts[i]] = i + 1
            done[i] = False
            nsteps[i] = 0
            last_s[i] = -1
        if record:
            paths[:, :] = -1
            paths[:, 0] = starts
        active = K
        collisions = 0
        for t in range(max_steps):
            if active == 0:
                break
            for i in range(K):
                if done[i]:
                    continue
                s = pos[i]
                a = choose_action(q[i, s], eps[e], rng)
                s2, code = try_move(s, a, next_cell, obstacle, occ, roi_id, False)
                r = r_step
                terminal = False
                if code == OBSTACLE:
                    r = r_collision
                    collisions += 1
                elif code == MOVED:
                    occ[s] = 0
                    occ[s2] = i + 1
                    if target_id[s2] >= 0:
                        r = r_goal
                        terminal = True
                if learn:
                    q_update(q[i], s, a, r, s2, terminal, alpha, gamma)
                pos[i] = s2
                last_s[i] = s
                last_a[i] = a
                nsteps[i] = t + 1
                if record:
                    paths[i, t + 1] = s2
                if terminal:
                    done[i] = True
                    active -= 1
        reached = K - active
        if learn:
            for i in range(K):
                if last_s[i] < 0:
                    continue
                if reached == K:
                    b = bonus_all
                elif done[i]:
                    b = bonus_reached
                else:
                    b = bonus_missed
                q[i, last_s[i], last_a[i]] += alpha * b
        out_steps[e] = nsteps.max()
        out_success[e] = reached == K
        out_reached[e] = reached
        out_collisions[e] = collisions
        out_agent_steps[e] = nsteps.sum()


@njit(cache=True)
def run_sie(
    next_cell,
    obstacle,
    roi_id,
    targets,
    starts,
    q1,
    q2,
    eps,
    alpha,
    gamma,
    max_steps,
    r_step,
    r_collision,
    r_goal,
    share_every,
    episode0,
    learn,
    rng,
    out_steps,
    out_success,
    out_reached,
    out_collisions,
    out_agent_steps,
    paths,
):
    """SQL-SIE (seed Algorithm 2) — or SQL-D when share_every == 0 — for len(eps) episodes.

    Phase 1: agent i picks ε-greedy actions on its own table q1[i] (K, S, 4) over the whole
    grid; entering the ROI gives r_goal and ends phase 1 (terminal). On entry it claims the
    free target nearest (Manhattan, lowest index on ties) to its cell.
    Phase 2: it moves ε-greedily on that target's table q2[k] (T, R, 4) over ROI cells only
    (leaving the ROI = a wall) until it reaches the target (r_goal, terminal), where it stops.
    Knowledge sharing (`share_max_nonzero`) on q1 after every episode whose global index
    episode0 + e + 1 is a multiple of share_every (> 0).
    """
    K = starts.shape[0]
    T = targets.shape[0]
    S = next_cell.shape[0]
    M = np.int64(np.sqrt(S) + 0.5)
    occ = np.zeros(S, np.int32)
    pos = np.empty(K, np.int64)
    phase = np.zeros(K, np.int64)  # 0 to the ROI, 1 to a target, 2 stopped on it
    goal = np.zeros(K, np.int64)
    nsteps = np.zeros(K, np.int64)
    claimed = np.zeros(T, np.bool_)
    record = paths.shape[0] > 0
    for e in range(eps.shape[0]):
        occ[:] = 0
        claimed[:] = False
        for i in range(K):
            pos[i] = starts[i]
            occ[starts[i]] = i + 1
            phase[i] = 0
            nsteps[i] = 0
        if record:
            paths[:, :] = -1
            paths[:, 0] = starts
        active = K
        collisions = 0
        for t in range(max_steps):
            if active == 0:
                break
            for i in range(K):
                if phase[i] == 2:
                    continue
                s = pos[i]
                if phase[i] == 0:
                    a = choose_action(q1[i, s], eps[e], rng)
                    s2, code = try_move(s, a, next_cell, obstacle, occ, roi_id, False)
                else:
                    k = goal[i]
                    a = choose_action(q2[k, roi_id[s]], eps[e], rng)
                    s2, code = try_move(s, a, next_cell, obstacle, occ, roi_id, True)
                r = r_step
                terminal = False
                if code == OBSTACLE:
                    r = r_collision
                    collisions += 1
                elif code == MOVED:
                    occ[s] = 0
                    occ[s2] = i + 1
                if phase[i] == 0:
                    if code == MOVED and roi_id[s2] >= 0:
                        r = r_goal
                        terminal = True
                    if learn:
                        q_update(q1[i], s, a, r, s2, terminal, alpha, gamma)
                    if terminal:
                        # claim the nearest free target (seed: flag assignment)
                        x2, y2 = s2 % M, s2 // M
                        best, best_d = -1, 1 << 30
                        for k in range(T):
                            if not claimed[k]:
                                d = abs(targets[k] % M - x2) + abs(targets[k] // M - y2)
                                if d < best_d:
                                    best, best_d = k, d
                        claimed[best] = True
                        goal[i] = best
                        phase[i] = 1
                        if targets[best] == s2:
                            phase[i] = 2
                            active -= 1
                else:
                    k = goal[i]
                    if s2 == targets[k]:
                        r = r_goal
                        terminal = True
                    if learn:
                        q_update(q2[k], roi_id[s], a, r, roi_id[s2], terminal, alpha, gamma)
                    if terminal:
                        phase[i] = 2
                        active -= 1
                pos[i] = s2
                nsteps[i] = t + 1
                if record:
                    paths[i, t + 1] = s2
        if learn and share_every > 0 and (episode0 + e + 1) % share_every == 0:
            share_max_nonzero(q1)
        out_steps[e] = nsteps.max()
        out_success[e] = active == 0
        out_reached[e] = K - active
        out_collisions[e] = collisions
        out_agent_steps[e] = nsteps.sum()
