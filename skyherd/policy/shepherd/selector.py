"""The high-level selector: which sub-skill (collect or drive) flies now.

- `StrombomSelector`: the hand-written rule (policy.shepherd.rules.strombom_rule).
- `LearnedSelector`: logistic regression on the flock's features, trained from the rule's
  demonstrations (`train_selector`), kept as a small JSON file (selector.json beside this
  module: weights, the feature names, the seeds and the fit). P(drive | x) = σ(w·x + b).

Features (`features`), each divided by the cohesion radius f(N) so that they mean the same for
any flock size: the furthest agent's distance from the centre, the mean spread, the distance
of the centre from the goal.
"""

from __future__ import annotations

import json
import math
from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np

from skyherd.groundsim.flock import FlockParams
from skyherd.policy.shepherd.rules import COLLECT, DRIVE, cohesion_radius, furthest, strombom_rule

SELECTOR_FILE = Path(__file__).with_name("selector.json")
FEATURES = ("furthest_over_f", "spread_over_f", "goal_distance_over_f")


def features(pos: np.ndarray, goal_ne, flock: FlockParams) -> np.ndarray:
    """(3,) the selector's input (FEATURES)."""
    f = cohesion_radius(flock)
    g = pos.mean(axis=0)
    spread = float(np.linalg.norm(pos - g, axis=1).mean())
    goal = float(np.linalg.norm(g - np.asarray(goal_ne, dtype=float)))
    return np.array([furthest(pos)[1] / f, spread / f, goal / f])


class StrombomSelector:
    name = "strombom"

    def choose(self, pos: np.ndarray, goal_ne, flock: FlockParams) -> tuple[str, float]:
        """(skill, P(drive)): the rule's choice, P = 1 or 0."""
        s = strombom_rule(pos, flock)
        return s, float(s == DRIVE)


@dataclass(frozen=True)
class SelectorFitParams:
    """How the learned selector is fitted (saved in selector.json)."""

    seeds: tuple[int, ...] = tuple(range(1000, 1020))  # demonstration episodes (not the study's)
    epochs: int = 3000  # full-batch gradient steps [-]
    lr: float = 0.5  # step size [-]
    l2: float = 1e-4  # weight decay [-]


class LearnedSelector:
    """σ(w·x + b) > ½ → drive. `w` (3,), `b`, the features' mean and scale (standardised)."""

    name = "learned"

    def __init__(self, w, b: float, mean, scale):
        self.w, self.b = np.asarray(w, dtype=float), float(b)
        self.mean, self.scale = np.asarray(mean, dtype=float), np.asarray(scale, dtype=float)

    def p_drive(self, x: np.ndarray) -> np.ndarray:
        z = ((np.asarray(x) - self.mean) / self.scale) @ self.w + self.b
        return 1.0 / (1.0 + np.exp(-z))

    def choose(self, pos: np.ndarray, goal_ne, flock: FlockParams) -> tuple[str, float]:
        p = float(self.p_drive(features(pos, goal_ne, flock)))
        return (DRIVE if p > 0.5 else COLLECT), p

    def to_json(self, **extra) -> dict:
        return {"features": list(FEATURES), "w": self.w.tolist(), "b": self.b,
                "mean": self.mean.tolist(), "scale": self.scale.tolist(), **extra}  # fmt: skip

    @classmethod
    def load(cls, path: Path | str = SELECTOR_FILE) -> LearnedSelector:
        """From a selector.json (ValueError saying how to make one when it is unreadable)."""
        try:
            d = json.loads(Path(path).read_text())
            if list(d["features"]) != list(FEATURES):
                raise ValueError(f"features {d['features']} are not {list(FEATURES)}")
            return cls(d["w"], d["b"], d["mean"], d["scale"])
        except (OSError, KeyError, TypeError, json.JSONDecodeError, ValueError) as e:
            raise ValueError(f"{path}: not a selector file ({e}); make one with "
                             "`python -m skyherd.policy.shepherd.train`") from None  # fmt: skip


def fit_logistic(x: np.ndarray, y: np.ndarray, p: SelectorFitParams) -> LearnedSelector:
    """Full-batch gradient descent on the mean log-loss (+ l2): deterministic for given data."""
    mean, scale = x.mean(axis=0), x.std(axis=0) + 1e-9
    z = (x - mean) / scale
    w, b = np.zeros(x.shape[1]), 0.0
    for _ in range(p.epochs):
        q = 1.0 / (1.0 + np.exp(-(z @ w + b)))
        g = q - y
        w -= p.lr * (z.T @ g / len(y) + p.l2 * w)
        b -= p.lr * float(g.mean())
    return LearnedSelector(w, b, mean, scale)


def make_selector(name: str, path: Path | str | None = None):
    """'strombom' or 'learned' (from `path`, default the kept selector.json)."""
    if name == "strombom":
        return StrombomSelector()
    if name == "learned":
        return LearnedSelector.load(path or SELECTOR_FILE)
    raise ValueError(f"unknown selector {name!r}: use learned or strombom")


def train_selector(fit: SelectorFitParams = SelectorFitParams(), flock: FlockParams | None = None,
                   task=None) -> tuple[LearnedSelector, dict]:  # fmt: skip
    """Demonstrations: the Strömbom shepherd's (features, choice) at every decision of the
    `fit.seeds` episodes; then `fit_logistic`. Returns (selector, record for selector.json)."""
    from skyherd.policy.shepherd.episode import run_episode
    from skyherd.policy.shepherd.rules import ShepherdParams

    task = task if task is not None else ShepherdParams()
    flock = flock if flock is not None else FlockParams()
    xs, ys = [], []
    for seed in fit.seeds:
        ep = run_episode(seed, StrombomSelector(), flock, task, demos=True)
        xs += [features(pos, task.goal_ne, flock) for pos in ep.demo_positions]
        ys += [float(s == DRIVE) for s in ep.demo_skills]
    x, y = np.array(xs), np.array(ys)
    sel = fit_logistic(x, y, fit)
    acc = float(((sel.p_drive(x) > 0.5) == (y > 0.5)).mean())
    rec = {"fit": asdict(fit), "demonstrations": len(y), "drive_fraction": float(y.mean()),
           "train_accuracy": round(acc, 4),
           "log_loss": round(float(-np.mean(y * np.log(sel.p_drive(x) + 1e-12)
                                            + (1 - y) * np.log(1 - sel.p_drive(x) + 1e-12))), 4)}  # fmt: skip
    if not math.isfinite(rec["log_loss"]):
        raise ValueError("the fit diverged: lower SelectorFitParams.lr")
    return sel, rec
