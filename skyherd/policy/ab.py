"""Apprenticeship Bootstrapping (AB): μ_E for the composite task from sub-task demonstrations only.

The demonstrations of (1) lateral, (2) climb and (3) descend give feature expectations μ_1, μ_2,
μ_3 (k,) each; AB feeds μ_E^Primitive = combine(μ_1, μ_2, μ_3) to projection IRL in place of
composite demonstrations. The seed paper does not give the combination rule; three are here:

mean          μ_E,j = (μ_1,j + μ_2,j + μ_3,j) / 3
per_feature   μ_E,j = mean of μ_k,j over the sub-tasks whose manoeuvres control feature j
              (FEATURE_SUBTASKS: lateral moves control centring and edge margin, climb and descend
              control the spread bins, all three keep the UGVs in view)
var_weighted  μ_E,j = Σ_k v_k,j μ_k,j / Σ_k v_k,j with v_k,j the variance of ψ_j over the
              demonstration of sub-task k (+1e-6): a feature counts where the demonstrator had to
              work on it, found from the data instead of from the manoeuvre map
"""

from __future__ import annotations

import numpy as np

from skyherd.policy.demos import Demonstration, demo_feature_expectations
from skyherd.policy.groundair.env import PSI_NAMES

SUBTASKS: tuple[str, ...] = ("lateral", "climb", "descend")
RULES: tuple[str, ...] = ("mean", "per_feature", "var_weighted")

# feature name → the sub-tasks that exercise it (per_feature rule)
FEATURE_SUBTASKS: dict[str, tuple[str, ...]] = {
    "all_in_view": ("lateral", "climb", "descend"),
    "centred_u": ("lateral",),
    "centred_v": ("lateral",),
    "edge_margin": ("lateral",),
    "spread_0_15": ("climb", "descend"),
    "spread_15_30": ("climb", "descend"),
    "spread_30_45": ("climb", "descend"),
    "spread_45_60": ("climb", "descend"),
    "spread_60_100": ("climb", "descend"),
}


def combine(demos: dict[str, Demonstration], rule: str, gamma: float) -> np.ndarray:
    """μ_E^Primitive (k,) from the sub-task demonstrations {'lateral', 'climb', 'descend'}."""
    if rule not in RULES:
        raise ValueError(f"unknown AB rule {rule!r}; choose from {', '.join(RULES)}")
    missing = [s for s in SUBTASKS if s not in demos]
    if missing:
        raise ValueError(f"AB needs demonstrations of {', '.join(missing)}")
    for s in SUBTASKS:
        if demos[s].meta["scenario"] != s:
            raise ValueError(
                f"demonstration given for {s} was recorded on {demos[s].meta['scenario']}"
            )
    mus = np.array([demo_feature_expectations(demos[s], gamma) for s in SUBTASKS])  # (3, k)
    if rule == "mean":
        return mus.mean(axis=0)
    if rule == "per_feature":
        out = np.empty(mus.shape[1])
        for j, name in enumerate(PSI_NAMES):
            rows = [SUBTASKS.index(s) for s in FEATURE_SUBTASKS[name]]
            out[j] = mus[rows, j].mean()
        return out
    var = np.array([demos[s].psi.astype(float).var(axis=0) for s in SUBTASKS]) + 1e-6  # (3, k)
    return (var * mus).sum(axis=0) / var.sum(axis=0)
