"""The wind a vehicle flies in: a mean plus first-order Gauss-Markov gusts (no numba here, so a
command line that only parses wind flags does not compile the physics)."""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class WindModel:
    """Mean wind plus first-order Gauss-Markov gusts, one process per NED axis.

    g_{k+1} = a g_k + σ √(1 − a²) n_k,  a = exp(−dt/τ),  n_k ~ N(0, 1) from a seeded Generator
    (stationary standard deviation σ, correlation time τ). mean_ned (3,) [m/s];
    gust_std σ [m/s]; gust_tau τ [s]; seed for the gusts; gust_std_down σ of the vertical
    axis [m/s] (None: gust_std; near the ground the vertical gusts are weaker, e.g. MIL-HDBK-1797's
    low-altitude σ_w = 0.1 W20, see safety.campaign.vertical_gust_std). The same draws either way.
    """

    mean_ned: tuple[float, float, float] = (0.0, 0.0, 0.0)
    gust_std: float = 0.0
    gust_tau: float = 2.0
    seed: int = 0
    gust_std_down: float | None = None

    def __post_init__(self) -> None:
        down = self.gust_std if self.gust_std_down is None else self.gust_std_down
        vals = [*self.mean_ned, self.gust_std, self.gust_tau, down]
        if len(self.mean_ned) != 3 or not all(math.isfinite(v) for v in vals):
            raise ValueError("wind: mean (3,) and gust figures must be finite")
        if self.gust_std < 0 or self.gust_tau <= 0 or down < 0:
            raise ValueError("wind: gust_std, gust_std_down >= 0 and gust_tau > 0 needed")

    @property
    def gust_stds(self) -> np.ndarray:
        """σ per NED axis (3,) [m/s]."""
        down = self.gust_std if self.gust_std_down is None else self.gust_std_down
        return np.array([self.gust_std, self.gust_std, down])


class WindField:
    """The state of a `WindModel`: `sample(dt)` → wind (3,) [m/s] NED for the next dt.

    The normal draws come from the Generator in blocks of `_BLOCK` rows of 3 (the same
    sequence as one draw of 3 per call).
    """

    _BLOCK = 512

    def __init__(self, model: WindModel):
        self.model = model
        self._rng = np.random.default_rng(model.seed)
        self._mean = np.asarray(model.mean_ned, dtype=float)
        self._gust = np.zeros(3)
        self._dt = -1.0
        self._a = self._b = 0.0
        self._z = np.zeros((0, 3))
        self._k = 0
        self.calm = not np.any(model.gust_stds) and not np.any(self._mean)

    def sample(self, dt: float) -> np.ndarray:
        m = self.model
        if m.gust_std > 0.0 or m.gust_std_down:
            if dt != self._dt:
                self._dt = dt
                self._a = math.exp(-dt / m.gust_tau)
                self._b = m.gust_stds * math.sqrt(1.0 - self._a * self._a)
            if self._k >= len(self._z):
                self._z = self._rng.standard_normal((self._BLOCK, 3))
                self._k = 0
            g = self._gust
            g *= self._a
            g += self._b * self._z[self._k]
            self._k += 1
        return self._mean + self._gust
