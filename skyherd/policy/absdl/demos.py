"""Continuous demonstrations: roll-outs of a demonstrator (or a learner) through the shield.

`rollout` flies one episode: at each decision the actor proposes a command, the shield (when
given) certifies it, the environment flies the certified command. `collect` gathers a data set
(obs → target command) of a sub-task's demonstrator on its own scenario: the target is the
certified command with the shield (shielded training learns what the net lets through), the
proposal without it. `dagger` (Ross et al., 2011) rolls the learner out and labels every state
it visits with the demonstrator's noise-free command (certified by a second net that sees the
same states when shielded), so the learner is corrected where it goes itself.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np

from skyherd.policy.absdl.demonstrator import Demonstrator
from skyherd.policy.absdl.env import ContinuousGroundAirEnv
from skyherd.policy.absdl.shield import Shield, ShieldStats


@dataclass
class Episode:
    obs: np.ndarray  # (T, 14) observation before each decision
    proposed: np.ndarray  # (T, 3) proposed command [m/s]
    certified: np.ndarray  # (T, 3) flown command [m/s]
    verdicts: list[str]
    metrics: dict[str, float]


@dataclass
class DataSet:
    obs: list[np.ndarray] = field(default_factory=list)
    target: list[np.ndarray] = field(default_factory=list)
    stats: ShieldStats = field(default_factory=ShieldStats)

    def arrays(self) -> tuple[np.ndarray, np.ndarray]:
        return np.concatenate(self.obs).astype(np.float32), np.concatenate(self.target)

    def __len__(self) -> int:
        return sum(len(o) for o in self.obs)


def rollout(
    env: ContinuousGroundAirEnv,
    actor: Callable[[np.ndarray], np.ndarray],
    seed: int,
    shield: Shield | None = None,
    label: Callable[[np.ndarray], np.ndarray] | None = None,
    label_shield: Shield | None = None,
) -> tuple[Episode, np.ndarray | None]:
    """One episode; with `label`, also the labels (T, 3) of the visited states."""
    o, _ = env.reset(seed=seed)
    if shield is not None:
        shield.reset()
    if label_shield is not None:
        label_shield.reset()
    obs, prop, cert, verdicts, labels = [], [], [], [], []
    dt = env.task.dt_s
    k = 0
    while True:
        t = k * dt
        v = np.asarray(actor(o), float)
        uav = env.uav_state()
        c, verdict = shield.certify(t, uav, v) if shield is not None else (v, "accepted")
        if label is not None:
            y = label(o)
            if label_shield is not None:
                y, _ = label_shield.certify(t, uav, y)
            labels.append(y)
        obs.append(o)
        prop.append(v)
        cert.append(c)
        verdicts.append(verdict)
        o, _, term, trunc, info = env.step(c)
        k += 1
        if term or trunc:
            break
    ep = Episode(np.array(obs), np.array(prop), np.array(cert), verdicts, info["metrics"])
    return ep, (np.array(labels) if label is not None else None)


def collect(
    subtask: str, demonstrator: Demonstrator, seeds, shield: bool, on_episode=None
) -> DataSet:
    """Demonstrations of `subtask` on its own scenario (the composite for "composite")."""
    env = ContinuousGroundAirEnv(subtask)
    sh = Shield() if shield else None
    data = DataSet()
    for s in seeds:
        demonstrator.reset(np.random.default_rng([int(s), 7]))
        ep, _ = rollout(env, demonstrator, int(s), sh)
        data.obs.append(ep.obs)
        data.target.append(ep.certified if shield else ep.proposed)
        if on_episode is not None:
            on_episode()
    if sh is not None:
        data.stats = sh.stats
    return data


def dagger(
    subtask: str, learner, demonstrator: Demonstrator, seeds, shield: bool, on_episode=None
) -> DataSet:
    """One DAgger round: the learner flies, the demonstrator's ideal command labels."""
    env = ContinuousGroundAirEnv(subtask)
    sh, lsh = (Shield(), Shield()) if shield else (None, None)
    data = DataSet()
    for s in seeds:
        ep, y = rollout(env, learner, int(s), sh, demonstrator.ideal, lsh)
        data.obs.append(ep.obs)
        data.target.append(y)
        if on_episode is not None:
            on_episode()
    return data


def from_recording(demo, shield: bool, on_episode=None) -> DataSet:
    """A recorded demonstration (policy.demos: `skyherd teleop` from the keyboard or MAVLink
    MANUAL_CONTROL, or any recorder) as continuous training data: each episode is replayed
    with its seed and recorded commands (the file's states). The command is the recorded
    velocity of a continuous file (skyherd-demo/2, `vel_ned`), else the action's velocity row
    (action_velocity_ned); with the shield its target is what the net certifies at the
    recorded state."""
    from skyherd.task.params import action_velocity_ned

    env = ContinuousGroundAirEnv(demo.meta["scenario"])
    uav = env.task.uav
    sh = Shield() if shield else None
    data = DataSet()
    dt = env.task.dt_s
    for k, seed in enumerate(demo.meta["episode_seeds"]):
        idx = np.flatnonzero(demo.episode == k)
        if not len(idx):
            continue
        o, _ = env.reset(seed=int(seed))
        if sh is not None:
            sh.reset()
        obs, target = [], []
        for i, j in enumerate(idx):
            if demo.vel_ned is not None:
                v = np.array(demo.vel_ned[j], float)
            else:
                v = np.array(action_velocity_ned(int(demo.actions[j]), uav))
            c = sh.certify(i * dt, env.uav_state(), v)[0] if sh is not None else v
            obs.append(o)
            target.append(c)
            o, *_ = env.step(v)
        data.obs.append(np.array(obs))
        data.target.append(np.array(target))
        if on_episode is not None:
            on_episode()
    if sh is not None:
        data.stats = sh.stats
    return data
