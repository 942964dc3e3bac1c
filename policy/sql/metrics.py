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

from policy.sql.train import Metrics


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
