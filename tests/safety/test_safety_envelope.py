"""Envelope rows, geometry, constraint-set files, MAVLink fence items, monitor, projection."""

import math
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from skyherd.flight.geo import DEFAULT_HOME, ned_to_geodetic
from skyherd.safety.config import (
    GUARD_KEYS,
    EnvelopeFileError,
    default_envelope_path,
    load_envelope,
    parse_envelope,
)
from skyherd.safety.envelope import NZ, P, U, V, build
from skyherd.safety.fence import FenceItemsError, envelope_from_fence_items
from skyherd.safety.geometry import (
    circle_polygon,
    convex_pieces,
    half_planes,
    is_convex,
    point_in_polygon,
)
from skyherd.safety.monitor import Monitor
from skyherd.safety.projection import Projector, qp_cvxpy

SPEC, _ = load_envelope(default_envelope_path("quadrotor"))
ENV = SPEC.envelope()
GEO = SPEC.geometry()

L_SHAPE = np.array([[0, 0], [60, 0], [60, 20], [20, 20], [20, 60], [0, 60]], float)


def z_of(p, v=(0, 0, 0), u=(0, 0, 0), att=(0, 0)):
    z = np.zeros(NZ)
    z[P], z[V], z[6:8], z[U] = p, v, att, u
    return z


def test_half_planes_of_a_square_are_unit_outward():
    n, d = half_planes(np.array([[-1, -1], [1, -1], [1, 1], [-1, 1]], float))
    assert np.allclose(np.linalg.norm(n, axis=1), 1)
    assert np.allclose(d, 1)
    assert np.all(n @ np.zeros(2) <= d) and np.any(n @ np.array([1.5, 0]) > d)


def test_convex_decomposition_covers_the_l_shape_exactly():
    pieces = convex_pieces(L_SHAPE)
    assert 2 <= len(pieces) <= 3 and all(is_convex(p) for p in pieces)
    rng = np.random.default_rng(0)
    for q in rng.uniform(-5, 65, size=(2000, 2)):
        inside_any = any(np.all(half_planes(p)[0] @ q <= half_planes(p)[1] + 1e-9) for p in pieces)
        assert inside_any == point_in_polygon(q, L_SHAPE)


def test_circle_polygons_bracket_the_circle():
    inner = circle_polygon(np.zeros(2), 10.0, 16, outer=False)
    outer = circle_polygon(np.zeros(2), 10.0, 16, outer=True)
    assert np.allclose(np.linalg.norm(inner, axis=1), 10.0)  # vertices on the circle
    n, d = half_planes(outer)
    assert np.allclose(d, 10.0)  # edges tangent to it


def test_row_names_a_person_reads():
    names = set(ENV.names)
    assert "ceiling 60 m" in names and "floor 5 m" in names
    assert "field edge 2" in names and "barn face 1" in names
    assert any(n.startswith("tilt 20 deg") for n in names)
    assert any(n.startswith("home radius 150 m") for n in names)


def test_stopping_time_is_the_braking_chord():
    th, tu, td = SPEC.stop_times()
    d, lim = SPEC.dynamics, SPEC.limits
    assert th == pytest.approx(lim.speed_h_mps / (2 * d.decel_h_mps2) + d.react_s)
    s = np.linspace(0, lim.speed_h_mps, 50)  # braking distance never exceeds T s on [0, v_max]
    assert np.all(s**2 / (2 * d.decel_h_mps2) + s * d.react_s <= th * s + 1e-12)


def test_fence_row_switches_exactly_at_the_predicted_stop():
    """North edge at 80 m: with v = u = s north, z is allowed iff 80 - margin >= p + (dt+T) s."""
    th = SPEC.stop_times()[0]
    k = SPEC.dynamics.dt_s + th
    s = 4.0
    p_lim = 80.0 - SPEC.limits.margin_m - k * s
    alt = (0, 0, -20)
    ok = ENV.worst(z_of((p_lim - 0.01, 0, -20), (s, 0, 0), (s, 0, 0)))
    bad = ENV.worst(z_of((p_lim + 0.01, 0, -20), (s, 0, 0), (s, 0, 0)))
    assert ok <= 0 < bad and bad == pytest.approx(0.01, abs=1e-9)
    assert ENV.violated(z_of((p_lim + 0.01, 0, -20), (s, 0, 0), (s, 0, 0)))[0][0] == "field edge 2"
    assert GEO.distance_outside(np.array([80.5, 0, -20])) == pytest.approx(0.5)
    assert GEO.distance_outside(np.array(alt, float)) == pytest.approx(
        -15.0
    )  # floor 5 m is nearest


def test_limits_rows_fire_with_their_names():
    hover = (0, 0, -20)
    assert ENV.violated(z_of(hover, v=(0, 0, -3.0), u=(0, 0, -3.5)))[0][0].startswith(
        "climb rate 3"
    )
    assert ENV.violated(z_of(hover, u=(0, 0, -3.5)))[0][0] == "vertical accel 3 m/s2 (up)"
    assert ENV.violated(z_of(hover, v=(7, 0, 0), u=(9, 0, 0)))[0][0].startswith(
        "horizontal speed 8"
    )
    assert ENV.violated(z_of(hover, u=(0, 5, 0)))[0][0].startswith("tilt 20 deg")
    assert ENV.violated(z_of(hover, att=(0.9, 0)))[0][0] == "roll 45 deg"
    assert ENV.violated(z_of((40, 40, -20)))[0][0].startswith("barn")  # inside the barn
    assert math.isnan(ENV.worst(z_of(hover, u=(math.nan, 0, 0))))
    assert math.isnan(ENV.worst(z_of(hover, u=(1e308, 1e308, 0))))


def test_compiled_check_equals_numpy_reference_on_a_union():
    doc = {
        "envelope": {"name": "l", "version": "t1", "airframe": "quadrotor"},
        "guards": dict.fromkeys(GUARD_KEYS, "off"),
        "fence": {
            "inclusion": [{"name": "L", "points_ne": L_SHAPE.tolist()}],
            "exclusion": [{"name": "c", "center_ne": [10, 10], "radius_m": 3}],
        },
    }
    env = build(parse_envelope(doc), predictive=True)
    assert len(env.piece_starts) >= 2 and len(env.zone_starts) == 1
    rng = np.random.default_rng(1)
    for _ in range(3000):
        z = z_of(
            (*rng.uniform(-10, 70, 2), -rng.uniform(0, 70)),
            rng.normal(0, 4, 3),
            rng.normal(0, 4, 3),
            rng.normal(0, 0.4, 2),
        )
        assert env.worst(z) == pytest.approx(env.worst_of(env.residual(z)), abs=1e-12)
        r = env.residual(z)
        assert np.array_equal(env.selected(r), env.select(r))  # the rows and their order
        tied = np.round(r, 0)  # equal residuals: both take the first of the tied rows
        assert np.array_equal(env.selected(tied), env.select(tied))


def test_monitor_prediction_and_stopping_distance():
    mon = Monitor(ENV)
    p1, v1 = mon.predict(z_of((0, 0, -20), (2, 0, 0), (4, 0, 0)))
    a = SPEC.dynamics.dt_s / SPEC.dynamics.tau_s
    assert v1[0] == pytest.approx(2 + a * 2)
    assert p1[0] == pytest.approx(SPEC.dynamics.dt_s * v1[0])
    h, _ = mon.stopping_distance(np.array([5.0, 0, 0]))
    assert h == pytest.approx(25 / (2 * SPEC.dynamics.decel_h_mps2) + 5 * SPEC.dynamics.react_s)
    c = mon.check(z_of((74, 0, -20), (3, 0, 0), (3, 0, 0)))  # 74 + 1.92·3 = 79.76 > 80 - 2
    assert not c.ok and c.reason == "field edge 2 (by 1.76)"
    near = mon.check(z_of((70, 0, -20), (3, 0, 0), (3, 0, 0)))
    assert near.ok and near.near[0][0] == "field edge 2"


@pytest.mark.parametrize(
    "text, msg",
    [
        ("[envelope\nname=", "not valid TOML"),
        ('[envelope]\nname="a"\nversion="1"\nairframe="boat"\n', "airframe must be one of"),
        (
            '[envelope]\nname="a"\nversion="1"\nairframe="quadrotor"\n[limits]\nceilling_m=3\n',
            "unknown key",
        ),
        (
            '[envelope]\nname="a"\nversion="1"\nairframe="quadrotor"\n[limits]\nceiling_m=3.0\nfloor_m=5.0\n[[fence.inclusion]]\nname="f"\npoints_ne=[[0,0],[1,0],[0,1]]\n',
            "must be above floor_m",
        ),
        (
            '[envelope]\nname="a"\nversion="1"\nairframe="quadrotor"\n[[fence.inclusion]]\nname="f"\npoints_ne=[[0,0],[10,10],[10,0],[0,20]]\n',
            "cross",
        ),
        (
            '[envelope]\nname="a"\nversion="1"\nairframe="quadrotor"\n[limits]\nspeed_h_mps="fast"\n',
            "finite number",
        ),
    ],
)
def test_corrupt_constraint_sets_raise_clear_errors(tmp_path, text, msg):
    f = tmp_path / "bad.toml"
    f.write_text(text)
    with pytest.raises(EnvelopeFileError) as e:
        load_envelope(f)
    assert msg in str(e.value) and "bad.toml" in str(e.value)
    with pytest.raises(EnvelopeFileError, match="cannot read"):
        load_envelope(tmp_path / "missing.toml")


def test_drill_cli_reports_a_corrupt_file_in_one_line(tmp_path):
    f = tmp_path / "bad.toml"
    f.write_bytes(b"\x00\xff garbage")
    r = subprocess.run(
        [
            str(Path(sys.executable).parent / "skyherd"),
            "drill",
            "--envelope",
            str(f),
            "--runs-dir",
            str(tmp_path),
        ],
        capture_output=True,
        text=True,
        timeout=60,
    )
    assert r.returncode == 2
    assert r.stderr.count("\n") == 1 and "bad.toml" in r.stderr and "Traceback" not in r.stderr


def _items_for(points_ne, cmd):
    out = []
    for n, e in points_ne:
        lat, lon, _ = ned_to_geodetic(DEFAULT_HOME, np.array([n, e, 0.0]))
        out.append((cmd, lat, lon, float(len(points_ne)), 0.0))
    return out


def test_envelope_from_mavlink_fence_items():
    square = [(-50, -50), (50, -50), (50, 50), (-50, 50)]
    lat, lon, _ = ned_to_geodetic(DEFAULT_HOME, np.array([20.0, -20.0, 0.0]))
    items = _items_for(square, 5001) + [
        (5004, lat, lon, 5.0, 0.0),
        (5000, DEFAULT_HOME.lat_deg, DEFAULT_HOME.lon_deg, 0.0),
    ]
    spec = envelope_from_fence_items(items, DEFAULT_HOME, SPEC)
    assert spec.version.startswith(SPEC.version + "+fence-") and spec.limits == SPEC.limits
    geo = spec.geometry()
    assert geo.distance_outside(np.array([50.3, 0, -20])) == pytest.approx(0.3, abs=0.02)
    assert geo.distance_outside(np.array([20.0, -20.0, -20])) == pytest.approx(
        5.0, abs=0.05
    )  # circle centre
    assert geo.distance_outside(np.array([0.0, 0.0, -20])) < 0
    again = envelope_from_fence_items(items, DEFAULT_HOME, ENV)
    assert again.version == spec.version  # same items → same version
    with pytest.raises(FenceItemsError, match="polygon of 4 vertices, 3 items left"):
        envelope_from_fence_items(_items_for(square, 5001)[:3], DEFAULT_HOME, SPEC)
    with pytest.raises(FenceItemsError, match="not a MAV_CMD_NAV_FENCE"):
        envelope_from_fence_items([(16, lat, lon, 0.0)], DEFAULT_HOME, SPEC)
    with pytest.raises(FenceItemsError, match="radius"):
        envelope_from_fence_items([(5003, lat, lon, math.nan)], DEFAULT_HOME, SPEC)


def test_projection_matches_cvxpy_and_is_verified_safe():
    pr = Projector(ENV)
    rng = np.random.default_rng(2)
    n_proj = 0
    for _ in range(40):
        p = (rng.uniform(40, 76), rng.uniform(-60, 20), -rng.uniform(10, 50))
        v = rng.uniform(-2, 4, 3) * np.array([1, 1, 0.3])
        z = z_of(p, v, v + rng.normal(0, 3, 3))
        if ENV.worst(z) <= 0:
            continue
        u = pr.project(z)
        A, h, state_ok = pr.bounds(z)
        ref = qp_cvxpy(A[h < 1e29], h[h < 1e29], z[U])
        if u is None:
            assert ref is None or not state_ok or ENV.worst(np.concatenate([z[:8], ref])) > -1e-6
            continue
        n_proj += 1
        zz = z.copy()
        zz[U] = u
        assert ENV.worst(zz) <= 0
        assert ref is not None and np.allclose(u, ref, atol=2e-3)
        u_exact = pr.project(z, closed_form=False)  # the general path agrees with the shortcut
        assert u_exact is not None and np.allclose(u_exact, ref, atol=2e-3)
    assert n_proj >= 10
    assert pr.project(z_of((0, 0, -20), att=(1.0, 0))) is None  # state-only row: nothing helps


def test_signed_distance_of_a_notched_fence():
    """North-west corner cut out at (30, -30): splits between convex pieces are not fences."""
    from skyherd.safety.envelope import SignedDistance

    spec, _ = load_envelope(default_envelope_path("quadrotor").with_name("quadrotor_notched.toml"))
    sd, geo = SignedDistance(spec), spec.geometry()
    assert len(geo.piece_starts) >= 2
    assert sd(np.array([0.0, 0.0, -20.0])) == pytest.approx(-15.0)  # floor nearest, not a split
    assert sd(np.array([29.0, -29.0, -30.0])) == pytest.approx(-math.sqrt(2))  # reflex corner
    assert sd(np.array([40.0, -40.0, -30.0])) == pytest.approx(10.0)  # in the notch: outside
    env = spec.envelope()
    hover = z_of((0.0, 0.0, -20.0))  # on a split: allowed in either piece, no margin there
    assert env.worst(hover) <= 0
    split_rows = [n for n in env.names if " split " in n]
    assert split_rows and all(n.startswith("field piece") for n in split_rows)
    # flying into the notch from the south is refused by a real edge of the notch
    z = z_of((26.0, -40.0, -30.0), (3, 0, 0), (3, 0, 0))
    assert env.worst(z) > 0 and " edge " in env.violated(z)[0][0]
