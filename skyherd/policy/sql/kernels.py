"""Compiled (numba) episode loops of SQL (seed Algorithm 1) and SQL-SIE / SQL-D (Algorithm 2).

Everything here works on integer cell indices (see `layout.py`) and float64 Q arrays that the
caller owns and keeps between calls, so a long run is a sequence of short chunks (one progress
bar tick each) with no state hidden in the kernels. The random source is a splitmix64 state
(a length-1 uint64 array) passed in and advanced in place: a given seed gives the same run
bit for bit.

Update rule (Watkins Q-learning, seed eq. for Q):
    Q(s, a) ← Q(s, a) + α [r + γ max_a' Q(s', a') − Q(s, a)],   the max term dropped at a
    terminal transition (target or ROI reached); with `blend` computed in the published
    form (1 − α) Q(s, a) + α [r + γ max_a' Q(s', a')] (same value up to rounding).
"""

from __future__ import annotations

import numpy as np
from numba import njit

# try_move outcome codes
MOVED, WALL, OBSTACLE, AGENT = 0, 1, 2, 3

_GOLDEN = np.uint64(0x9E3779B97F4A7C15)
_M1 = np.uint64(0xBF58476D1CE4E5B9)
_M2 = np.uint64(0x94D049BB133111EB)


def rng_state(seed: int) -> np.ndarray:
    """The kernels' splitmix64 state from an integer seed via numpy's SeedSequence."""
    return np.random.SeedSequence(int(seed)).generate_state(1, dtype=np.uint64)


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
def greedy_first(q_row):
    """The lowest index among the largest values of q_row (MATLAB `[~, a] = max(q)`)."""
    best_a = 0
    for a in range(1, q_row.shape[0]):
        if q_row[a] > q_row[best_a]:
            best_a = a
    return best_a


@njit(cache=True)
def choose_action(q_row, eps, rng, ties_first):
    """ε-greedy on one row of Q (shape (A,)): with probability ε a uniform action, else the
    best one; ties among the best broken by the lowest index (`ties_first`) or at random."""
    n = q_row.shape[0]
    if eps > 0.0 and uniform(rng) < eps:
        return randint(rng, n)
    if ties_first:
        return greedy_first(q_row)
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
def q_update(q, s, a, r, s2, terminal, alpha, gamma, blend=False):
    """One Q-learning update on table q (shape (S, A)); returns the TD error.

    blend: store (1 − α)·Q + α·target (published `Qvalues_update.m`) instead of
    Q + α·(target − Q): equal in exact arithmetic, rounded differently."""
    target = r
    if not terminal:
        m = q[s2, 0]
        for b in range(1, q.shape[1]):
            if q[s2, b] > m:
                m = q[s2, b]
        target += gamma * m
    td = target - q[s, a]
    if blend:
        q[s, a] = (1.0 - alpha) * q[s, a] + alpha * target
    else:
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
    ties_first,
    bonus_blend,
    q_blend,
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
    the team bonus b goes onto each agent's last (s, a):
      bonus_blend False:  Q ← Q + α·b  (= b added to that transition's reward);
      bonus_blend True:   Q ← (1 − α)·Q + α·b  (published `Qvalues_update_swarm_final`), and
                          +bonus_all only if all agents stopped before the last allowed step
                          (the published loop notices "all stopped" one step later).
    q_blend: every Q update in the published form (`q_update`).
    out_*: (E,) per-episode metrics. paths: (K, T+1) int32 cell history of the last episode
    if its shape is not (0, 0).
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
            occ[starts[i]] += 1
            done[i] = False
            nsteps[i] = 0
            last_s[i] = -1
        if record:
            paths[:, :] = -1
            paths[:, 0] = starts
        active = K
        collisions = 0
        t_all = -1  # the step in which the last agent stopped
        for t in range(max_steps):
            if active == 0:
                break
            for i in range(K):
                if done[i]:
                    continue
                s = pos[i]
                a = choose_action(q[i, s], eps[e], rng, ties_first)
                s2, code = try_move(s, a, next_cell, obstacle, occ, roi_id, False)
                r = r_step
                terminal = False
                if code == OBSTACLE:
                    r = r_collision
                    collisions += 1
                elif code == MOVED:
                    occ[s] -= 1
                    occ[s2] += 1
                    if target_id[s2] >= 0:
                        r = r_goal
                        terminal = True
                if learn:
                    q_update(q[i], s, a, r, s2, terminal, alpha, gamma, q_blend)
                pos[i] = s2
                last_s[i] = s
                last_a[i] = a
                nsteps[i] = t + 1
                if record:
                    paths[i, t + 1] = s2
                if terminal:
                    done[i] = True
                    active -= 1
            if active == 0:
                t_all = t
        reached = K - active
        all_bonus = reached == K and (not bonus_blend or t_all < max_steps - 1)
        if learn:
            for i in range(K):
                if last_s[i] < 0:
                    continue
                if all_bonus:
                    b = bonus_all
                elif done[i]:
                    b = bonus_reached
                else:
                    b = bonus_missed
                if bonus_blend:
                    q[i, last_s[i], last_a[i]] = (1.0 - alpha) * q[
                        i, last_s[i], last_a[i]
                    ] + alpha * b
                else:
                    q[i, last_s[i], last_a[i]] += alpha * b
        out_steps[e] = nsteps.max()
        out_success[e] = reached == K
        out_reached[e] = reached
        out_collisions[e] = collisions
        out_agent_steps[e] = nsteps.sum()


@njit(cache=True)
def roi_step(s, a, next_cell, roi_id):
    """A move inside the ROI with no obstacles or agents: leaving the ROI (or grid) = stay."""
    s2 = next_cell[s, a]
    if s2 < 0 or roi_id[s2] < 0:
        return s
    return s2


@njit(cache=True)
def pretrain_roi(
    next_cell, roi_id, targets, corner, q2, episodes, max_steps, eps_decay, eps_min, reward,
    alpha, gamma, ties_first, rng, q_blend=False,
):  # fmt: skip
    """Published `Q_Learning_ROI.m`: per-target tables q2 (T, R, 4) trained in place.

    For each target k, `episodes` episodes from the ROI corner cell `corner`, ε-greedy with
    ε = 1 decayed ×eps_decay after each episode while above eps_min, moves inside the ROI
    only, `reward` on reaching target k (the episode ends), 0 otherwise; Watkins update
    (`q_blend`: in the published form).
    """
    T = targets.shape[0]
    for k in range(T):
        eps = 1.0
        for _ in range(episodes):
            s = corner
            for _t in range(max_steps):
                a = choose_action(q2[k, roi_id[s]], eps, rng, ties_first)
                s2 = roi_step(s, a, next_cell, roi_id)
                hit = s2 == targets[k]
                q_update(
                    q2[k], roi_id[s], a, reward if hit else 0.0, roi_id[s2], hit, alpha, gamma,
                    q_blend,
                )  # fmt: skip
                s = s2
                if hit:
                    break
            if eps > eps_min:
                eps *= eps_decay


@njit(cache=True)
def assign_cell(pos, M):
    """The cell the published `flag_assignment` reads: `Q(currentState(1), currentState(2))`
    of the K×2 (x, y) position matrix, MATLAB's column-major elements 1 and 2 — (x of agent
    1, x of agent 2), or agent 1's own (x, y) when K = 1. pos: (K,) cell indices."""
    x1 = pos[0] % M
    other = pos[1] % M if pos.shape[0] > 1 else pos[0] // M
    return other * M + x1


@njit(cache=True)
def claim_target(s, q2_row_of, claimed, targets, M, qargmax):
    """Index of the free target an agent on ROI cell s claims (see `Rules.assign`).

    qargmax: argmax over (action, free target in id order) of q2[k, roi(s), a], flattened
    action-fastest like MATLAB's reshape, first index on ties, then free target number
    ceil(idx / T) (1-based) as in the published `flag_assignment`. Otherwise the nearest free
    target (Manhattan, lowest id on ties). q2_row_of: (T, 4) rows of q2 at cell s.
    """
    T = targets.shape[0]
    if qargmax:
        best, best_idx, idx = -np.inf, -1, 0
        for k in range(T):
            if claimed[k]:
                continue
            for a in range(4):
                if q2_row_of[k, a] > best:
                    best, best_idx = q2_row_of[k, a], idx
                idx += 1
        j = best_idx // T  # ceil((best_idx + 1) / T) − 1
        last = -1
        for k in range(T):
            if not claimed[k]:
                if j == 0:
                    return k
                j -= 1
                last = k
        return last  # j past the free targets (only K < 4; MATLAB stops with an index error)
    x2, y2 = s % M, s // M
    best, best_d = -1, 1 << 30
    for k in range(T):
        if not claimed[k]:
            d = abs(targets[k] % M - x2) + abs(targets[k] // M - y2)
            if d < best_d:
                best, best_d = k, d
    return best


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
    ties_first,
    roi_pretrained,
    assign_qargmax,
    step_published,
    assign_x1x2,
    walk_draws,
    walk_step_onto,
    q_blend,
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
    grid; entering the ROI gives r_goal and ends phase 1 (terminal).
    Phase 2, roi_pretrained False: on entry the agent claims a target (`claim_target`) and moves
    ε-greedily, one move per step, on that target's table q2[k] (T, R, 4), learned online, over
    ROI cells only (leaving the ROI = a wall, other agents block) until it reaches the target
    (r_goal, terminal), where it stops.
    Phase 2, roi_pretrained True (published): at its next turn the agent claims a target and
    walks the fixed pre-trained q2[k] greedily to it within that one turn (≤ max_steps moves,
    passing through other agents), then stops (on the target, or where the walk gave up).
    Step count: phase-1 moves + own phase-2 moves, or (step_published) + the length of the
    last ROI walk of any agent when this agent's turn came in the last step.
    assign_x1x2 (published): the pre-trained claim reads the values at `assign_cell(pos, M)`
    (x of agent 1, x of agent 2), all 0 when that cell is outside the ROI. walk_draws: one
    unused uniform draw per walk move (the published walk's `rand` at ε = 0).
    walk_step_onto (published): the walk ends only with a move onto the target, so an agent
    that starts its walk on its target first moves (`Rules.walk_end`).
    q_blend: every Q update in the published form (`q_update`).
    Knowledge sharing (`share_max_nonzero`) on q1 after every episode whose global index
    episode0 + e + 1 is a multiple of share_every (> 0).
    """
    K = starts.shape[0]
    T = targets.shape[0]
    S = next_cell.shape[0]
    M = np.int64(np.sqrt(S) + 0.5)
    occ = np.zeros(S, np.int32)
    pos = np.empty(K, np.int64)
    phase = np.zeros(K, np.int64)  # 0 to the ROI, 1 to a target, 2 stopped
    goal = np.zeros(K, np.int64)
    nsteps = np.zeros(K, np.int64)
    walk = np.zeros(K, np.int64)
    total = np.zeros(K, np.int64)
    on_target = np.zeros(K, np.bool_)
    claimed = np.zeros(T, np.bool_)
    zero_rows = np.zeros((T, 4))
    record = paths.shape[0] > 0
    for e in range(eps.shape[0]):
        occ[:] = 0
        claimed[:] = False
        for i in range(K):
            pos[i] = starts[i]
            occ[starts[i]] += 1
            phase[i] = 0
            nsteps[i] = 0
            walk[i] = 0
            total[i] = 0
            on_target[i] = False
        if record:
            paths[:, :] = -1
            paths[:, 0] = starts
        active = K
        collisions = 0
        shared_walk = 0  # published ROI_step: the last walk's length, any agent
        for t in range(max_steps):
            if active == 0:
                break
            for i in range(K):
                if phase[i] == 2:
                    total[i] = nsteps[i] + (shared_walk if step_published else walk[i])
                    continue
                s = pos[i]
                if phase[i] == 1 and roi_pretrained:
                    c = assign_cell(pos, M) if assign_x1x2 else s
                    rows = q2[:, roi_id[c]] if roi_id[c] >= 0 else zero_rows
                    k = claim_target(s, rows, claimed, targets, M, assign_qargmax)
                    claimed[k] = True
                    goal[i] = k
                    s2, n = s, 0
                    while n < max_steps and (walk_step_onto or s2 != targets[k]):
                        if walk_draws:
                            uniform(rng)  # drawn and compared with ε = 0: always greedy
                        a = choose_action(q2[k, roi_id[s2]], 0.0, rng, ties_first)
                        s_prev = s2
                        s2 = roi_step(s2, a, next_cell, roi_id)
                        n += 1
                        if walk_step_onto and s2 == targets[k] and s_prev != s2:
                            break  # the published `collect`: this move stepped onto the flag
                    occ[s] -= 1
                    occ[s2] += 1
                    pos[i] = s2
                    walk[i] = n
                    shared_walk = n
                    on_target[i] = s2 == targets[k]
                    phase[i] = 2
                    active -= 1
                    if record:
                        paths[i, t + 1] = s2
                    total[i] = nsteps[i] + (shared_walk if step_published else walk[i])
                    continue
                if phase[i] == 0:
                    a = choose_action(q1[i, s], eps[e], rng, ties_first)
                    s2, code = try_move(s, a, next_cell, obstacle, occ, roi_id, False)
                else:
                    k = goal[i]
                    a = choose_action(q2[k, roi_id[s]], eps[e], rng, ties_first)
                    s2, code = try_move(s, a, next_cell, obstacle, occ, roi_id, True)
                r = r_step
                terminal = False
                if code == OBSTACLE:
                    r = r_collision
                    collisions += 1
                elif code == MOVED:
                    occ[s] -= 1
                    occ[s2] += 1
                if phase[i] == 0:
                    if code == MOVED and roi_id[s2] >= 0:
                        r = r_goal
                        terminal = True
                    if learn:
                        q_update(q1[i], s, a, r, s2, terminal, alpha, gamma, q_blend)
                    nsteps[i] += 1
                    if terminal:
                        phase[i] = 1
                        if not roi_pretrained:  # claim on entry
                            k = claim_target(
                                s2, q2[:, roi_id[s2]], claimed, targets, M, assign_qargmax
                            )
                            claimed[k] = True
                            goal[i] = k
                            if targets[k] == s2:
                                phase[i] = 2
                                on_target[i] = True
                                active -= 1
                else:
                    k = goal[i]
                    if s2 == targets[k]:
                        r = r_goal
                        terminal = True
                    if learn:
                        q_update(
                            q2[k], roi_id[s], a, r, roi_id[s2], terminal, alpha, gamma, q_blend
                        )
                    walk[i] += 1
                    if terminal:
                        phase[i] = 2
                        on_target[i] = True
                        active -= 1
                pos[i] = s2
                total[i] = nsteps[i] + (shared_walk if step_published else walk[i])
                if record:
                    paths[i, t + 1] = s2
        if learn and share_every > 0 and (episode0 + e + 1) % share_every == 0:
            share_max_nonzero(q1)
        out_steps[e] = total.max()
        n_on = 0
        for i in range(K):
            if on_target[i]:
                n_on += 1
        out_success[e] = n_on == K
        out_reached[e] = n_on
        out_collisions[e] = collisions
        out_agent_steps[e] = nsteps.sum() + walk.sum()
