"""The flown deep policy: sub-task networks fused by relevance gating (ref [15]), or one network.

ABS-DL bootstraps the composite skill from sub-task skills: the lateral network commands north
and east, the climb and descend networks the vertical, each weighted by how relevant its
sub-task is in the present state. Relevance comes from the quantity each sub-task's
demonstrations regulate, the image spread φ[2] against the target:

    w_climb = σ((spread − target) / T),   w_descend = 1 − w_climb      (T = gate_temperature)
    w_climb = 1 when a UGV is out of view (widen the view first)
    v = (lat_n, lat_e, w_climb · climb_d + w_descend · descend_d)

so the fused policy never needs a composite demonstration. A "single" policy (the baseline
trained on composite demonstrations) is one network for all axes. Each network's output is in
units of the velocity limits' scale; the command is clipped to the limits.

File (`.npz`, numpy only): per network `<name>/W0`, `<name>/b0`, …; `meta` JSON with format
"skyherd-absdl-policy/1", kind ("fused" | "single"), networks, obs_dim, act_dim, scale,
limits, gate_temperature, spread_target, and what the trainer adds (params, metrics).
`explain(obs)` says which network decided (the largest share of the command) and its weight.
"""

from __future__ import annotations

import io
import json
import math
from pathlib import Path
from typing import Any

import numpy as np

from skyherd.policy.absdl.mlp import forward
from skyherd.runio.runfolder import atomic_write_bytes, to_jsonable

FORMAT = "skyherd-absdl-policy/1"
FUSED, SINGLE = "fused", "single"


class AbsdlPolicy:
    """callable(obs (14,)) → NED velocity command (3,) [m/s]; explain(obs) → dict."""

    continuous = True
    n_actions = None  # no discrete actions: a velocity command

    def __init__(self, nets: dict[str, tuple[list, list]], meta: dict[str, Any]):
        self.nets = {k: ([np.asarray(w, float) for w in W], [np.asarray(b, float) for b in B])
                     for k, (W, B) in nets.items()}  # fmt: skip
        self.meta = dict(meta)
        self.kind = self.meta.get("kind", FUSED)
        need = ("lateral", "climb", "descend") if self.kind == FUSED else ("composite",)
        missing = [k for k in need if k not in self.nets]
        if missing:
            raise ValueError(
                f"a {self.kind} ABS-DL policy needs networks {need}; missing {missing}"
            )
        dims = {W[0].shape[1] for W, _ in self.nets.values()}
        outs = {W[-1].shape[0] for W, _ in self.nets.values()}
        if len(dims) != 1 or outs != {3}:
            raise ValueError(f"networks disagree on shapes: inputs {dims}, outputs {outs} (need 3)")
        self.obs_dim = dims.pop()
        self.act_dim = 3
        self.scale = np.asarray(self.meta["scale"], float)
        lim = self.meta["limits"]
        self.h_max, self.up_max, self.down_max = lim["h_mps"], lim["up_mps"], lim["down_mps"]
        self.temperature = float(self.meta.get("gate_temperature", 0.04))
        self.target = float(self.meta.get("spread_target", 0.35))

    def _net(self, name: str, obs: np.ndarray) -> np.ndarray:
        W, B = self.nets[name]
        return forward(W, B, obs) * self.scale

    def gates(self, obs: np.ndarray) -> dict[str, float]:
        """Relevance of each sub-task network at obs (fused policies)."""
        if obs[5] <= 0.5:
            wc = 1.0
        else:
            z = (float(obs[2]) - self.target) / self.temperature
            wc = 1.0 / (1.0 + math.exp(-max(min(z, 50.0), -50.0)))
        return {"lateral": 1.0, "climb": wc, "descend": 1.0 - wc}

    def _clip(self, v: np.ndarray) -> np.ndarray:
        h = float(np.hypot(v[0], v[1]))
        if h > self.h_max:
            v[:2] *= self.h_max / h
        v[2] = min(max(v[2], -self.up_max), self.down_max)
        return v

    def _decide(self, obs) -> tuple[np.ndarray, dict[str, Any]]:
        obs = np.asarray(obs, np.float64)
        if obs.shape != (self.obs_dim,) or not np.all(np.isfinite(obs)):
            raise ValueError(f"policy expects a finite obs of shape ({self.obs_dim},), got {obs.shape}")  # fmt: skip
        if self.kind == SINGLE:
            v = self._clip(self._net("composite", obs))
            return v, {"module": "composite", "weight": 1.0, "share": 1.0, "weights": {"composite": 1.0}}  # fmt: skip
        g = self.gates(obs)
        lat, cl, de = (self._net(k, obs) for k in ("lateral", "climb", "descend"))
        v = self._clip(np.array([lat[0], lat[1], g["climb"] * cl[2] + g["descend"] * de[2]]))
        part = {
            "lateral": float(np.hypot(lat[0], lat[1])),
            "climb": abs(g["climb"] * cl[2]),
            "descend": abs(g["descend"] * de[2]),
        }
        total = sum(part.values())
        best = max(part, key=part.get)
        share = part[best] / total if total > 0 else 1.0
        return v, {"module": best, "weight": round(g[best], 4), "share": round(share, 4),
                   "weights": {k: round(w, 4) for k, w in g.items()}}  # fmt: skip

    def __call__(self, obs) -> np.ndarray:
        return self._decide(obs)[0]

    def velocity(self, obs) -> np.ndarray:
        return self._decide(obs)[0]

    def explain(self, obs) -> dict[str, Any]:
        v, why = self._decide(obs)
        why["command_ned_mps"] = [round(float(x), 4) for x in v]
        why["reason"] = (
            f"{why['module']} network decided (gate weight {why['weight']:.2f}, "
            f"{100 * why['share']:.0f} % of the command): v = ({v[0]:+.2f}, {v[1]:+.2f}, "
            f"{v[2]:+.2f}) m/s NED"
        )
        return why

    # ---- file
    def save(self, path: Path) -> None:
        arrays: dict[str, np.ndarray] = {}
        for name, (W, B) in self.nets.items():
            for k, (w, b) in enumerate(zip(W, B)):
                arrays[f"{name}/W{k}"] = w.astype(np.float32)
                arrays[f"{name}/b{k}"] = b.astype(np.float32)
        meta = {**self.meta, "format": FORMAT, "kind": self.kind, "networks": sorted(self.nets),
                "obs_dim": self.obs_dim, "act_dim": 3}  # fmt: skip
        arrays["meta"] = np.array(json.dumps(to_jsonable(meta)))
        bio = io.BytesIO()
        np.savez_compressed(bio, **arrays)
        atomic_write_bytes(Path(path), bio.getvalue())


def from_arrays(z, meta: dict[str, Any]) -> AbsdlPolicy:
    """An AbsdlPolicy from an open `.npz` (policy.dqn.load_policy dispatches here)."""
    nets = {}
    for name in meta.get("networks", []):
        n = sum(1 for k in z.files if k.startswith(f"{name}/W"))
        W = [z[f"{name}/W{k}"] for k in range(n)]
        B = [z[f"{name}/b{k}"] for k in range(n)]
        for a in W + B:
            if not np.all(np.isfinite(a)):
                raise ValueError(f"network {name!r} has NaN/inf weights")
        nets[name] = (W, B)
    return AbsdlPolicy(nets, meta)
