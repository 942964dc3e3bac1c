"""safety.nearest: the point of {x : A x <= h} nearest to x0, exactly. Checked against cvxpy +
Clarabel (projection.qp_cvxpy, solved to 1e-11) on 2,400 seeded problems with degenerate rows,
against closed-form answers by hand, and the net's path (projection and recovery target) run
in a fresh process without importing OSQP or SciPy (issue 31: ~0.15-0.2 CPU s of make run's
companion)."""

from __future__ import annotations

import math
import subprocess
import sys

import numpy as np
import pytest

from skyherd.safety.nearest import INF, nearest_point
from skyherd.safety.projection import qp_cvxpy

SQ2 = math.sqrt(2.0)


def random_problem(rng: np.random.Generator, kind: str) -> tuple[np.ndarray, ...]:
    """(A, h, x0) of one of several families; rows of mixed scale (|a| from 0.01 to 100)."""
    m = int(rng.integers(1, 41))
    A = rng.normal(size=(m, 3)) * 10.0 ** rng.uniform(-2, 2, (m, 1))
    x0, y = rng.normal(0, 3, 3), rng.normal(0, 1, 3)
    h = A @ y + rng.uniform(0, 2, m) * np.linalg.norm(A, axis=1)  # y inside: non-empty
    if kind == "duplicate":  # rows repeated, some scaled copies
        k = m // 2
        s = rng.choice([1.0, 3.0], m - k)
        A[k:], h[k:] = A[: m - k] * s[:, None], h[: m - k] * s
    elif kind == "parallel":  # slabs around y: normals reversed, width >= 0.05 / |a|
        k = m // 2
        A[k : 2 * k] = -A[:k] * rng.uniform(0.5, 2, (k, 1))
        h[k : 2 * k] = A[k : 2 * k] @ y + rng.uniform(0.05, 1, k) * np.linalg.norm(
            A[k : 2 * k], axis=1
        )
    elif kind == "feasible":  # x0 inside already
        h = A @ x0 + rng.uniform(0, 1, m)
    elif kind == "empty":  # a random set, mostly empty, and a slab of negative width
        h = rng.normal(0, 1, m) * np.linalg.norm(A, axis=1)
        if m >= 2 and rng.uniform() < 0.5:
            A[1] = -A[0] * rng.uniform(0.5, 2)
            h[1] = -h[0] * np.linalg.norm(A[1]) / np.linalg.norm(A[0]) - 0.1
    return A, h, x0


KINDS = ("general", "duplicate", "parallel", "feasible", "empty")


@pytest.mark.parametrize("kind", KINDS)
def test_agrees_with_cvxpy_in_answer_and_verdict(kind):
    rng = np.random.default_rng(KINDS.index(kind))
    n_empty = n_moved = 0
    for _ in range(480):
        A, h, x0 = random_problem(rng, kind)
        x, ref = nearest_point(A, h, x0), qp_cvxpy(A, h, x0)
        assert (x is None) == (ref is None), (A, h, x0, ref)
        if x is None:
            n_empty += 1
            continue
        n_moved += not np.array_equal(x, x0)
        assert np.max(np.abs(x - ref)) <= 1e-7 * max(1.0, np.max(np.abs(ref)))
        assert np.all(A @ x - h <= 1e-9 * np.linalg.norm(A, axis=1))  # feasible to tol
    if kind == "empty":
        assert n_empty >= 200
    elif kind == "feasible":
        assert n_moved == 0
    else:
        assert n_empty == 0 and n_moved >= 300


def test_closed_form_answers():
    box = np.vstack([np.eye(3), -np.eye(3)])  # |x_i| <= 1
    assert np.array_equal(nearest_point(box, np.ones(6), [5.0, 5.0, 5.0]), [1.0, 1.0, 1.0])
    assert np.allclose(nearest_point(box, np.ones(6), [5.0, -0.5, -3.0]), [1.0, -0.5, -1.0])
    # a wedge x <= -|y| (normals (1, ±1, 0)): from in front of its edge, the edge
    wedge = np.array([[1.0, 1.0, 0.0], [1.0, -1.0, 0.0]])
    assert np.allclose(nearest_point(wedge, np.zeros(2), [5.0, 0.5, 1.0]), [0.0, 0.0, 1.0])
    # ... from beside one face, that face: x0 - (n·x0 - c) n / |n|^2
    x0 = np.array([1.0, 4.0, 2.0])
    want = x0 - (x0 @ wedge[0]) * wedge[0] / 2
    assert np.allclose(nearest_point(wedge, np.zeros(2), x0), want)
    # a single plane, and its scaled copy: the same point
    a, c = np.array([2.0, -1.0, 2.0]), 3.0
    x0 = np.array([4.0, 0.0, 5.0])
    want = x0 - (a @ x0 - c) / (a @ a) * a
    assert np.allclose(nearest_point(a[None], [c], x0), want, atol=1e-14)
    assert np.allclose(nearest_point(np.array([a, 1e-3 * a]), [c, 1e-3 * c], x0), want)
    # a cone z >= |x| + |y|: four planes meet at the apex, one more than the dimension
    cone = np.array([[1, 1, -1], [1, -1, -1], [-1, 1, -1], [-1, -1, -1]], float)
    assert np.allclose(nearest_point(cone, np.zeros(4), [0.0, 0.0, -5.0]), 0.0, atol=1e-15)
    assert np.allclose(nearest_point(cone, np.zeros(4), [0.1, 0.0, -5.0]), 0.0, atol=1e-14)
    # the edge of two faces, the cone's x = 0 ridge: from (0, 3, 0) to (0, 1.5, 1.5)
    assert np.allclose(nearest_point(cone, np.zeros(4), [0.0, 3.0, 0.0]), [0, 1.5, 1.5])


def test_degenerate_and_bad_input():
    x0 = np.array([3.0, -2.0, 1.0])
    assert np.array_equal(nearest_point(np.zeros((0, 3)), np.zeros(0), x0), x0)
    assert nearest_point(np.eye(3), np.zeros(3), [math.nan, 0, 0]) is None
    assert nearest_point(np.eye(3), [0, math.nan, 0], x0) is None
    assert nearest_point(np.eye(3), [0, -math.inf, 0], x0) is None
    bad_row = np.array([[1.0, math.inf, 0.0]])
    assert nearest_point(bad_row, [0.0], x0) is None
    # unselected rows (h >= INF) are ignored, whatever A holds there
    A = np.array([[1.0, 0, 0], [math.nan, 0, 0], [0, 1.0, 0]])
    assert np.allclose(nearest_point(A, [0.0, INF, INF], x0), [0.0, -2.0, 1.0])
    # a zero row: 0 <= h always true (ignored) or never (empty)
    A = np.array([[0.0, 0, 0], [1.0, 0, 0]])
    assert np.allclose(nearest_point(A, [0.0, 1.0], x0), [1.0, -2.0, 1.0])
    assert nearest_point(A, [-1.0, 1.0], x0) is None
    # parallel planes: a slab of width 0 is a plane; of negative width, empty
    slab = np.array([[1.0, 1, 0], [-1.0, -1, 0]])
    assert np.allclose(nearest_point(slab, [1.0, -1.0], [0.0, 0.0, 0.0]), [0.5, 0.5, 0.0])
    assert nearest_point(slab, [1.0, -1.0 - 1e-6], [0.0, 0.0, 0.0]) is None
    # three planes through a line and a fourth that cuts it: a point, found exactly
    A = np.array([[1.0, 0, 0], [0, 1.0, 0], [1.0, 1.0, 0], [0, 0, 1.0]])
    assert np.allclose(nearest_point(A, [0.0, 0.0, 0.0, -2.0], [1.0, 1.0, 1.0]), [0, 0, -2])


NET_PATH = """
import sys
import numpy as np
from skyherd.safety.config import default_envelope_path, load_envelope
from skyherd.safety.envelope import NZ
from skyherd.safety.fallback import PidGains, RecoveryPID, recovery_target
from skyherd.safety.net import warm_up
from skyherd.safety.projection import Projector
from skyherd.safety.supervisor import SupervisorParams

spec, _ = load_envelope(default_envelope_path("quadrotor"))
warm_up(spec.envelope(), SupervisorParams(intervention="project"))  # AI, FALLBACK, PID
pr = Projector(spec.envelope())
z = np.zeros(NZ)
z[0:3], z[3:6], z[8:11] = (60.0, 0.0, -20.0), (3.0, 0.0, 0.0), (6.0, 5.0, 0.0)
u = pr.project(z, closed_form=False)
geo = spec.geometry()
p = recovery_target(geo, np.array([83.0, 10.0, -20.0]), 6.0)
RecoveryPID(PidGains(), geo, speed_mps=3.0, margin_m=6.0)
print(u is not None, np.allclose(p, [74.0, 10.0, -20.0]), "osqp" in sys.modules,
      "scipy" in sys.modules)
"""


def test_the_nets_projection_and_recovery_import_neither_osqp_nor_scipy():
    out = subprocess.run([sys.executable, "-c", NET_PATH], capture_output=True, text=True,
                         timeout=300)  # fmt: skip
    assert out.returncode == 0, out.stderr[-2000:]
    assert out.stdout.split() == ["True", "True", "False", "False"]
