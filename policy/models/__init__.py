"""Trained policy files the repository keeps (so `make run` starts at once).

groundair_ab.npz  Apprenticeship Bootstrapping (mean rule, sub-task demos only), best of 5 seeds
                  of `skyherd train ab` (docs/learning.md); load with policy.load_policy.
"""

from pathlib import Path

DEFAULT_POLICY = Path(__file__).with_name("groundair_ab.npz")
