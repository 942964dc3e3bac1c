"""Fixtures shared by more than one test file."""

import dataclasses

import numpy as np
import pytest

from skyherd.safety.config import ENVELOPE_DIR, load_envelope
from skyherd.safety.envelope import circle_zone, polygon_zone

NORTH_35 = 35.0  # the judge tests' fence: its north edge [m]


@pytest.fixture(scope="session")
def north35_spec():
    """The ground-air envelope with its fence's north edge at 35 m and a 10 m tower exclusion
    100 m east: the judge's hand-made tracks (test_safety_judge.py, test_drill_judge.py)."""
    base, _ = load_envelope(ENVELOPE_DIR / "quadrotor_groundair.toml")
    n = NORTH_35
    fence = polygon_zone("north 35", [[-200, -200], [n, -200], [n, 200], [-200, 200]])
    tower = circle_zone("tower", np.array([0.0, 100.0]), 10.0, 16, True)
    return dataclasses.replace(base, inclusions=(fence,), exclusions=(tower,))
