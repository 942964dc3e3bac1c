"""ABS-DL hyper-parameters: one frozen dataclass, printed and saved with every run."""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass


@dataclass(frozen=True)
class DemonstratorParams:
    """The scripted PD demonstrator and its human-like imperfections."""

    kp_xy: float = 0.6  # lateral gain on the ground offset of the team's centre [1/s]
    kp_z: float = 0.5  # vertical gain on the altitude error the spread implies [1/s]
    spread_target: float = 0.35  # preferred φ spread (TaskParams.spread_target)
    search_climb_mps: float = 1.5  # climb while a UGV is out of view [m/s]
    noise_mps: float = 0.0  # std of white noise added to each commanded axis [m/s]
    delay_steps: int = 0  # reaction delay: the command of `delay_steps` decisions ago
    gain_error: float = 0.0  # per-episode gain factor drawn from [1 − e, 1 + e]


@dataclass(frozen=True)
class AbsdlParams:
    """ABS-DL hyper-parameters (saved with every run)."""

    seed: int = 0  # seeds torch, numpy and the episode seeds
    demo_episodes: int = 30  # demonstration episodes per sub-task (and for the composite)
    dagger_rounds: int = 1  # DAgger rounds after behaviour cloning (0: cloning only)
    dagger_episodes: int = 10  # learner roll-outs per DAgger round and sub-task
    noise_mps: float = 0.2  # demonstrator noise std [m/s]
    delay_steps: int = 1  # demonstrator reaction delay [decisions]
    gain_error: float = 0.2  # demonstrator per-episode gain error ±
    shield: bool = True  # the SafetyNet certifies every training action
    hidden: tuple[int, ...] = (64, 64)  # MLP hidden widths (ReLU)
    epochs: int = 60  # passes over the data per fit
    batch_size: int = 256  # samples per gradient step
    lr: float = 2e-3  # Adam learning rate
    weight_decay: float = 1e-5  # Adam L2
    gate_temperature: float = 0.04  # width of the climb/descend gate in φ spread units
    eval_episodes: int = 200  # unseen composite episodes for the evaluation
    eval_seed: int = 100_000  # first evaluation episode seed (training seeds stay below)
    num_threads: int = 1  # torch intra-op threads (the machine is shared)

    def demonstrator(self, noisy: bool = True) -> DemonstratorParams:
        if not noisy:
            return DemonstratorParams()
        return DemonstratorParams(
            noise_mps=self.noise_mps, delay_steps=self.delay_steps, gain_error=self.gain_error
        )

    @classmethod
    def of(cls, o) -> AbsdlParams:
        """The parameters of `skyherd train abs-dl`'s options: any object with the fields as
        attributes (an argparse namespace; `hidden` comma-separated widths); ValueError (one
        line) if they are refused."""
        kw = {f.name: getattr(o, f.name) for f in dataclasses.fields(cls)}
        try:
            kw["hidden"] = tuple(int(x) for x in str(kw["hidden"]).split(",") if x)
        except ValueError:
            raise ValueError(
                f"--hidden must be comma-separated widths, got {kw['hidden']!r}"
            ) from None
        return cls(**kw)

    def __post_init__(self) -> None:
        if self.demo_episodes < 1 or self.epochs < 1 or self.eval_episodes < 1:
            raise ValueError("need demo_episodes, epochs and eval_episodes >= 1")
        if self.dagger_rounds < 0 or self.delay_steps < 0 or self.noise_mps < 0:
            raise ValueError("dagger_rounds, delay_steps and noise_mps must be >= 0")
        if not 0 <= self.gain_error < 1 or self.gate_temperature <= 0:
            raise ValueError("need 0 <= gain_error < 1 and gate_temperature > 0")


QUICK = dict(demo_episodes=8, dagger_rounds=1, dagger_episodes=4, epochs=25, eval_episodes=20)
"""--quick: a small budget (under a minute of CPU)."""
