"""Learning-curve summaries: episodes to converge, final metric and success rate.

Definitions (ours; the seed reads convergence off its plots):
- final metric: mean of the per-episode metric (largest step count of any agent) over the
  last `tail` episodes; final success rate likewise.
- first success: the first episode in which every agent reached a target (None if never).
- episodes to converge: the first episode e such that the `window`-episode moving average of
  the metric ending at e and every later one stays within 10 % (+1 step) of the final metric;
  None ("did not converge") when the final success rate is below `min_success`.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from skyherd.policy.sql.train import Metrics


@dataclass(frozen=True)
class RunSummary:
    episodes_to_converge: int | None
    final_steps: float
    final_success: float
    first_success: int | None


def moving_average(x: np.ndarray, window: int) -> np.ndarray:
    """Trailing moving average, shape (E − window + 1,): element j covers x[j : j+window]."""
    x = np.asarray(x, dtype=np.float64)
    if window < 1 or x.shape[0] < window:
        raise ValueError(f"need at least window={window} >= 1 episodes, got {x.shape[0]}")
    c = np.concatenate([[0.0], np.cumsum(x)])
    return (c[window:] - c[:-window]) / window


def convergence_episode(
    steps: np.ndarray,
    success: np.ndarray,
    window: int = 100,
    tail: int = 500,
    min_success: float = 0.9,
) -> int | None:
    """Episode count after which the learning curve has settled (see module doc)."""
    steps = np.asarray(steps, dtype=np.float64)
    tail = min(tail, steps.shape[0])
    window = min(window, steps.shape[0])
    if np.mean(np.asarray(success)[-tail:]) < min_success:
        return None
    final = steps[-tail:].mean()
    ma = moving_average(steps, window)
    outside = np.flatnonzero(ma > 1.1 * final + 1.0)
    first_ok = 0 if outside.size == 0 else int(outside[-1]) + 1
    return first_ok + window  # episodes seen when that window ends


def summarize(m: Metrics, window: int = 100, tail: int = 500) -> RunSummary:
    tail = min(tail, m.steps.shape[0])
    return RunSummary(
        convergence_episode(m.steps, m.success, window, tail),
        float(m.steps[-tail:].mean()),
        float(np.mean(m.success[-tail:])),
        int(np.argmax(m.success)) + 1 if m.success.any() else None,
    )


# --- The seed study's own definitions (the published implementation's analysis scripts) ---


def study_metric(steps: np.ndarray, cap: int = 1000) -> np.ndarray:
    """Per-episode metric: min(max over agents of steps, cap) — `steps` is already the max."""
    return np.minimum(np.asarray(steps, dtype=np.float64), cap)


def study_convergence(metric: np.ndarray, window: int = 100) -> int:
    """The first episode (1-based) after which the `window`-episode moving average of the
    metric stays below 2× its final value (the average over the last `window` episodes).

    The average "at episode e" covers episodes e − window + 1 .. e, so the answer is at least
    `window`; E + 1 would mean "never", which cannot happen (the last average is below 2× itself
    unless it is 0, and a metric of 0 steps does not occur).
    """
    ma = moving_average(metric, window)
    final = ma[-1]
    above = np.flatnonzero(ma >= 2.0 * final)
    j = 0 if above.size == 0 else int(above[-1]) + 1
    return j + window


@dataclass(frozen=True)
class StudySummary:
    """One run in the study's terms ("tail" = the last 10 % of episodes)."""

    tail_metric: float
    """Mean of the metric over the tail."""
    tail_success: float
    """Share of tail episodes with metric < cap (what the published step logs show)."""
    tail_on_target: float
    """Share of tail episodes with every agent on its own target (kernel truth)."""
    convergence: int | None
    """`study_convergence` of the metric; None (did not converge) when tail_success is below
    `min_success` — a run flat at the cap would otherwise "converge" at episode `window`."""
    first_all_reached: int | None
    """First episode (1-based) with every agent on a target; None if never."""


def study_summary(
    steps: np.ndarray,
    on_target: np.ndarray,
    cap: int = 1000,
    window: int = 100,
    min_success: float = 0.9,
) -> StudySummary:
    m = study_metric(steps, cap)
    E = m.shape[0]
    tail = max(1, E // 10)
    window = min(window, E)
    on_target = np.asarray(on_target, dtype=bool)
    success = float((m[-tail:] < cap).mean())
    return StudySummary(
        float(m[-tail:].mean()),
        success,
        float(on_target[-tail:].mean()),
        study_convergence(m, window) if success >= min_success else None,
        int(np.argmax(on_target)) + 1 if on_target.any() else None,
    )


def mean_sd(values, digits: int = 1) -> str:
    """ "mean ± sd" over seeds (population sd, as MATLAB std(x, 1) in the study's plots)."""
    a = np.asarray([v for v in values if v is not None], dtype=np.float64)
    if a.size == 0:
        return "–"
    return f"{a.mean():.{digits}f} ± {a.std():.{digits}f}"
