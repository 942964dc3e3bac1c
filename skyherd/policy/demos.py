"""Demonstrations: the scripted expert, recording, the file format, replay, feature expectations.

File format (`.npz`, written atomically; one file = one demonstrator on one scenario):

==========  =============  ====================================================================
array       shape, dtype   meaning
==========  =============  ====================================================================
obs         (T, 14) f32    observation before each action (GroundAirEnv docstring)
actions     (T,) i64       action taken (params.ACTION_NAMES)
psi         (T, 9) f32     reward features ψ of the state the action led to
episode     (T,) i64       episode index of each row
t_s         (T,) f64       simulation time of the row [s]
uav_ned     (T, 3) f64     UAV position NED [m] before the action
ugv_ne      (T, n, 2) f64  UGV positions (north, east) [m] before the action
vel_ned     (T, 3) f64     continuous files only: the velocity command flown (north, east, down)
                           [m/s], inside policy.absdl.env.velocity_limits
meta        () str         JSON: format, scenario, demonstrator, episode seeds, episode lengths
                           and metrics, expert params, task params, created (UTC)
==========  =============  ====================================================================

Two formats: "skyherd-demo/1" (discrete: the seven action rows are the commands) and
"skyherd-demo/2" (continuous, `record(..., continuous=True)`: `vel_ned` is the command;
`actions` holds the allowed action whose velocity row is nearest it, for readers of discrete
actions). A file without `vel_ned` is written as /1, so discrete recordings are unchanged and
both stay readable.

A demonstration is replayable: the environment's randomness comes from the recorded episode seed,
so `replay` re-runs each episode with the recorded commands and reports how far the observations
drift from the recorded ones (0 for a faithful file).
"""

from __future__ import annotations

import dataclasses
import datetime as dt
import io
import json
import math
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from skyherd.policy.groundair.env import N_PSI, GroundAirEnv
from skyherd.runio.runfolder import atomic_write_bytes, to_jsonable
from skyherd.task.params import (
    ALL_ACTIONS,
    CLIMB_ACTIONS,
    DESCEND_ACTIONS,
    LATERAL_ACTIONS,
    TaskParams,
    action_velocity_ned,
)
from skyherd.task.scenarios import SCENARIOS

FORMAT = "skyherd-demo/1"
FORMAT_CONTINUOUS = "skyherd-demo/2"
ALLOWED_ACTIONS: dict[str, tuple[int, ...]] = {
    "lateral": LATERAL_ACTIONS,
    "climb": CLIMB_ACTIONS,
    "descend": DESCEND_ACTIONS,
    "composite": ALL_ACTIONS,
}


class DemoFileError(ValueError):
    """A demonstration file that is missing, truncated, or not in the skyherd-demo format."""


# --------------------------------------------------------------------------- scripted expert
@dataclass(frozen=True)
class ExpertParams:
    """The scripted demonstrator: a PD rule on φ, with adjustable imperfection."""

    spread_target: float = 0.35  # preferred φ spread (circle radius / image half-diagonal)
    spread_band: float = 0.06  # dead band around the target
    lateral_band: float = 0.08  # dead band of the centroid offset [fraction of the image width]
    lead_steps: float = 2.0  # look-ahead on the image-motion terms [steps]
    epsilon: float = 0.0  # probability of a random allowed action (people are not perfect)
    lag: float = 0.0  # probability of repeating the previous action (slow reactions)


class ScriptedExpert:
    """callable(obs) → action, restricted to the manoeuvres of a scenario.

    rng: numpy Generator for the imperfections (seeded by the caller).
    """

    def __init__(self, allowed: tuple[int, ...], params: ExpertParams, rng: np.random.Generator):
        self.allowed = tuple(allowed)
        self.p = params
        self.rng = rng
        self.prev = 0

    def ideal(self, o: np.ndarray) -> int:
        p = self.p
        lead = p.lead_steps
        frac, all_in = o[4], o[5] > 0.5
        score = {a: 0.0 for a in range(7)}
        if frac <= 0.0:
            score[5] = 1.0  # nothing seen: climb to search
        else:
            # image offsets (fractions of the image; +u = east, +v = south) with look-ahead
            du = (o[0] - 0.5) + lead * (o[11] - 0.5) / 5.0
            dv = (o[1] - 0.5) + lead * (o[12] - 0.5) / 5.0
            ds = (o[2] - p.spread_target) + lead * (o[13] - 0.5) / 5.0
            score[3] = du / p.lateral_band
            score[4] = -du / p.lateral_band
            score[2] = dv / p.lateral_band
            score[1] = -dv / p.lateral_band
            if not all_in:
                score[5] = 1.5 + (1.0 - frac)  # someone is out of view: widen the view first
            else:
                score[5] = ds / p.spread_band
                score[6] = -ds / p.spread_band
        best = max(self.allowed, key=lambda a: score[a])
        return best if score[best] >= 1.0 else 0

    def __call__(self, obs: np.ndarray) -> int:
        a = self.ideal(np.asarray(obs, dtype=float))
        r = self.rng.random()
        if r < self.p.epsilon:
            a = int(self.rng.choice(self.allowed))
        elif r < self.p.epsilon + self.p.lag:
            a = self.prev
        self.prev = a
        return a


def scripted_expert(
    scenario: str, params: ExpertParams = ExpertParams(), seed: int = 0
) -> ScriptedExpert:
    return ScriptedExpert(ALLOWED_ACTIONS[scenario], params, np.random.default_rng(seed))


# --------------------------------------------------------------------------- recording
@dataclass
class Demonstration:
    """In-memory demonstration (see the module docstring for the arrays)."""

    obs: np.ndarray
    actions: np.ndarray
    psi: np.ndarray
    episode: np.ndarray
    t_s: np.ndarray
    uav_ned: np.ndarray
    ugv_ne: np.ndarray
    meta: dict[str, Any]
    vel_ned: np.ndarray | None = None  # continuous files: the flown command per row [m/s]

    @property
    def n_episodes(self) -> int:
        return len(self.meta["episode_seeds"])

    def save(self, path: Path) -> Path:
        """Write atomically (temp file + rename); with `vel_ned` as skyherd-demo/2."""
        continuous = self.vel_ned is not None
        meta = dict(self.meta, format=FORMAT_CONTINUOUS if continuous else FORMAT)
        extra = {"vel_ned": self.vel_ned.astype(np.float64)} if continuous else {}
        bio = io.BytesIO()
        np.savez_compressed(
            bio,
            **extra,
            obs=self.obs.astype(np.float32),
            actions=self.actions.astype(np.int64),
            psi=self.psi.astype(np.float32),
            episode=self.episode.astype(np.int64),
            t_s=self.t_s.astype(np.float64),
            uav_ned=self.uav_ned.astype(np.float64),
            ugv_ne=self.ugv_ne.astype(np.float64),
            meta=np.array(json.dumps(to_jsonable(meta), sort_keys=True)),
        )
        atomic_write_bytes(Path(path), bio.getvalue())
        return Path(path)


def load_demo(path: str | Path) -> Demonstration:
    """Read a demonstration file; DemoFileError on a missing, corrupt or foreign file."""
    path = Path(path)
    keys = ("obs", "actions", "psi", "episode", "t_s", "uav_ned", "ugv_ne")
    try:
        with np.load(path, allow_pickle=False) as z:
            meta = json.loads(str(z["meta"]))
            if meta.get("format") == FORMAT_CONTINUOUS:
                keys += ("vel_ned",)
            arrays = {k: z[k] for k in keys}
    except FileNotFoundError as e:
        raise DemoFileError(f"{path}: no such demonstration file") from e
    except Exception as e:  # BadZipFile, KeyError, zlib/JSON errors on a truncated file …
        raise DemoFileError(
            f"{path}: not a readable demonstration ({type(e).__name__}: {e})"
        ) from e
    if meta.get("format") not in (FORMAT, FORMAT_CONTINUOUS):
        raise DemoFileError(
            f"{path}: format {meta.get('format')!r}, expected {FORMAT!r} or {FORMAT_CONTINUOUS!r}"
        )
    T = arrays["actions"].shape[0]
    if any(arrays[k].shape[0] != T for k in keys) or arrays["psi"].shape[1:] != (N_PSI,):
        raise DemoFileError(f"{path}: arrays have inconsistent lengths")
    if "vel_ned" in arrays and arrays["vel_ned"].shape[1:] != (3,):
        raise DemoFileError(f"{path}: vel_ned is not (T, 3)")
    finite = ("obs", "psi", "uav_ned") + (("vel_ned",) if "vel_ned" in arrays else ())
    if not all(np.all(np.isfinite(arrays[k])) for k in finite):
        raise DemoFileError(f"{path}: NaN/inf in the recorded data")
    if meta.get("scenario") not in SCENARIOS:
        raise DemoFileError(f"{path}: unknown scenario {meta.get('scenario')!r}")
    return Demonstration(meta=meta, **arrays)


def record(
    scenario: str,
    act: Callable[[np.ndarray], Any],
    n_episodes: int,
    seed: int,
    demonstrator: str,
    extra_meta: dict[str, Any] | None = None,
    task: TaskParams | None = None,
    on_step: Callable[[GroundAirEnv, np.ndarray, int], None] | None = None,
    continuous: bool = False,
) -> Demonstration:
    """Run `n_episodes` of `scenario` with the demonstrator `act(obs)` and record them.

    Discrete: `act(obs) → action`; an action < 0 means "stop". Continuous: `act(obs) → (3,)`
    NED velocity [m/s], None means "stop"; it is flown in policy.absdl.env.ContinuousGroundAirEnv
    (clipped to its limits), the flown command is recorded as `vel_ned` and the nearest allowed
    action as `actions` (skyherd-demo/2). Episode k uses environment seed `seed + k`; on "stop"
    recording ends there and the partial episode is kept (teleop's quit key).
    """
    if continuous:
        from skyherd.policy.absdl.env import ContinuousGroundAirEnv

        env = ContinuousGroundAirEnv(scenario, task=task)
        base = env.base
    else:
        env = base = GroundAirEnv(scenario, task=task)
    allowed = ALLOWED_ACTIONS[scenario]
    rows: dict[str, list] = {
        k: [] for k in ("obs", "actions", "psi", "episode", "t_s", "uav_ned", "ugv_ne", "vel_ned")
    }
    seeds, lengths, metrics = [], [], []
    stopped = False
    for k in range(n_episodes):
        if stopped:
            break
        obs, _ = env.reset(seed=seed + k)
        seeds.append(seed + k)
        done = False
        while not done:
            a = act(obs)
            if (a is None) if continuous else (int(a) < 0):  # the demonstrator stopped
                stopped = True
                info = {"metrics": base.episode_metrics()}
                break
            s = base.uav_state()
            rows["obs"].append(obs)
            rows["uav_ned"].append((s["n"], s["e"], s["d"]))
            rows["ugv_ne"].append(base.formation.positions())
            rows["t_s"].append(base.formation.t)
            rows["episode"].append(k)
            obs, _, term, trunc, info = env.step(a if continuous else int(a))
            if continuous:
                rows["vel_ned"].append(info["command"])
                a = nearest_action(info["command"], allowed, base.task)
            rows["actions"].append(int(a))
            rows["psi"].append(info["psi"])
            if on_step:
                on_step(base, obs, int(a))
            done = term or trunc
        lengths.append(base.steps)
        metrics.append(info["metrics"])
    meta = {
        "scenario": scenario,
        "demonstrator": demonstrator,
        "episode_seeds": seeds,
        "episode_lengths": lengths,
        "episode_metrics": metrics,
        "task": dataclasses.asdict(base.task),
        "created": dt.datetime.now(dt.UTC).isoformat(timespec="seconds"),
        **(extra_meta or {}),
    }
    vel = np.asarray(rows.pop("vel_ned"), float).reshape(-1, 3)
    arr = {k: np.asarray(v) for k, v in rows.items()}
    return Demonstration(meta=meta, vel_ned=vel if continuous else None, **arr)


def nearest_action(v_ned, allowed: tuple[int, ...], task: TaskParams) -> int:
    """The allowed action whose velocity row (action_velocity_ned) is nearest the command."""
    v = np.asarray(v_ned, float)
    return min(allowed, key=lambda a: float(np.sum((action_velocity_ned(a, task.uav) - v) ** 2)))


def replay(demo: Demonstration, task: TaskParams | None = None) -> float:
    """Re-run every episode with its seed and recorded commands (`vel_ned` when the file has
    it, else the actions); max |obs − recorded obs|."""
    env = GroundAirEnv(demo.meta["scenario"], task=task)
    worst = 0.0
    for k, seed in enumerate(demo.meta["episode_seeds"]):
        idx = np.flatnonzero(demo.episode == k)
        obs, _ = env.reset(seed=int(seed))
        for j in idx:
            worst = max(worst, float(np.max(np.abs(obs - demo.obs[j]))))
            if demo.vel_ned is not None:
                obs, *_ = env.step_velocity(demo.vel_ned[j])
            else:
                obs, *_ = env.step(int(demo.actions[j]))
    return worst


# --------------------------------------------------------------------------- feature expectations
def discounted_mean(psi: np.ndarray, episode: np.ndarray, gamma: float) -> np.ndarray:
    """μ = mean over episodes of (1 − γ) Σ_t γ^t ψ_t  (seed Eq. 5), shape (k,)."""
    mus = []
    for k in np.unique(episode):
        p = psi[episode == k]
        disc = gamma ** np.arange(p.shape[0])
        mus.append((1.0 - gamma) * (disc @ p))
    return np.mean(mus, axis=0)


def demo_feature_expectations(demo: Demonstration, gamma: float) -> np.ndarray:
    return discounted_mean(demo.psi.astype(float), demo.episode, gamma)


def rollout_stats(
    act: Callable[[np.ndarray], int],
    scenario: str,
    n_episodes: int,
    seed: int,
    gamma: float,
    task: TaskParams | None = None,
    pixels: bool = False,
) -> tuple[np.ndarray, dict[str, float]]:
    """Monte-Carlo μ(π) (k,) and mean episode metrics of a policy on a scenario.

    pixels: observe through the rendered frame and the detector instead of the fast path.
    """
    env = GroundAirEnv(scenario, task=task, pixels=pixels)
    mus, mets = [], []
    for k in range(n_episodes):
        obs, _ = env.reset(seed=seed + k)
        acc, disc, done = np.zeros(N_PSI), 1.0, False
        while not done:
            obs, _, term, trunc, info = env.step(int(act(obs)))
            acc += disc * np.asarray(info["psi"])
            disc *= gamma
            done = term or trunc
        mus.append((1.0 - gamma) * acc)
        mets.append(info["metrics"])
    keys = mets[0].keys()
    mean = {}
    for key in keys:
        vals = [m[key] for m in mets if not math.isnan(m[key])]
        mean[key] = float(np.mean(vals)) if vals else math.nan
    return np.mean(mus, axis=0), mean


def random_policy(
    seed: int = 0, allowed: tuple[int, ...] = ALL_ACTIONS
) -> Callable[[np.ndarray], int]:
    rng = np.random.default_rng(seed)
    return lambda obs: int(rng.choice(allowed))
