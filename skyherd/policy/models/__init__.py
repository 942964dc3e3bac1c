"""Trained policy files the repository keeps (so `make run` starts at once).

groundair_ab.npz  Apprenticeship Bootstrapping (mean rule, sub-task demos only), best of 5 seeds
                  of `skyherd train ab` (docs/learning.md); load with policy.load_policy.
groundair_absdl.npz  ABS-DL (policy.absdl): lateral, climb and descend networks fused, continuous
                  velocity commands; `skyherd train abs-dl --save-policy` with the defaults
                  (seed 0; docs/learning.md); fly with `skyherd fly --policy` (numpy only).
"""

from pathlib import Path

DEFAULT_POLICY = Path(__file__).with_name("groundair_ab.npz")
ABSDL_POLICY = Path(__file__).with_name("groundair_absdl.npz")
