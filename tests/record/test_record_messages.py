"""record.messages' fast paths write what the plain ways write, to the byte: `json_bytes` of a
record (json as it is, strict_json only when json refuses it) and the setpoint arrows
(`_arrow_to`: plain floats instead of np.cross), over many generated inputs."""

from __future__ import annotations

import enum
import json
import math

import numpy as np

from skyherd.record import messages as m
from skyherd.runio import strict_json


class _Mode(enum.Enum):
    AI = "ai"


def _strict(record) -> bytes:
    """json_bytes as it was: every record through strict_json."""
    return json.dumps(strict_json(record), sort_keys=True, allow_nan=False).encode()


def _value(rng: np.random.Generator, depth: int):
    kind = rng.integers(0, 12 if depth < 3 else 8)
    if kind == 0:
        return float(rng.choice([math.nan, math.inf, -math.inf, -0.0, 0.0, 1e300, 5e-324]))
    if kind == 1:
        return float(rng.normal() * 10.0 ** rng.integers(-8, 8))
    if kind == 2:
        return int(rng.integers(-(2**40), 2**40))
    if kind == 3:
        return bool(rng.integers(0, 2))
    if kind == 4:
        return None
    if kind == 5:
        return str(rng.choice(["", "ai", "accel limit 4 m/s²", 'q"uote\\', "φ"]))
    if kind == 6:  # what strict_json converts: numpy values, enums
        odd = [np.float64(rng.normal()), np.int64(3), np.float32(0.5), _Mode.AI]
        return odd[rng.integers(0, len(odd))]
    if kind == 7:
        return np.float64(rng.choice([math.nan, 2.5]))
    if kind in (8, 9):
        return [_value(rng, depth + 1) for _ in range(rng.integers(0, 5))]
    if kind == 10:
        return tuple(_value(rng, depth + 1) for _ in range(rng.integers(0, 4)))
    return _record(rng, depth + 1)


def _record(rng: np.random.Generator, depth: int = 0) -> dict:
    keys = ["t", "phi", "mac", "vehicle", "proposed", "certified", "b", "a", "é", "10", "2"]
    return {str(rng.choice(keys)): _value(rng, depth) for _ in range(rng.integers(0, 7))}


def test_json_bytes_writes_what_strict_json_writes_for_any_string_keyed_record():
    rng = np.random.default_rng(31)
    records = [_record(rng) for _ in range(5000)]
    records += [{"t_sim": t} for t in (0.0, 0.1, 99.9, -0.0, math.nan, math.inf, 1e-7)]
    plain = 0
    for rec in records:
        assert m.json_bytes(rec) == _strict(rec), rec
        try:
            json.dumps(rec, allow_nan=False)
            plain += 1
        except (TypeError, ValueError):
            pass
    assert 500 < plain < len(records) - 500  # both ways taken, many times each


def _arrow_numpy(origin, vec, rgba, scale_s: float = 1.0):
    """messages._arrow_to as it was, with numpy's norm, dot and cross."""
    v = np.asarray(vec, dtype=float) * scale_s
    n = float(np.linalg.norm(v))
    if not (math.isfinite(n) and n > 1e-6):
        return None
    x = np.array([1.0, 0.0, 0.0])
    h = x + v / n
    if np.linalg.norm(h) < 1e-9:
        q = [0.0, 0.0, 0.0, 1.0]
    else:
        h /= np.linalg.norm(h)
        q = [float(np.dot(x, h)), *np.cross(x, h)]
    head = min(0.3 * n, 1.0)
    return m.fm.ArrowPrimitive(
        pose=m._pose(origin, q), shaft_length=n - head, shaft_diameter=0.1,
        head_length=head, head_diameter=0.3, color=m._color(rgba),
    )  # fmt: skip


def test_setpoint_arrows_are_numpys_to_the_bit():
    rng = np.random.default_rng(32)
    scale = rng.choice([1e-7, 1e-3, 0.1, 1.0, 4.0, 100.0], size=(8000, 1))
    vecs = list(rng.normal(size=(8000, 3)) * scale)
    vecs += list(np.round(rng.normal(size=(3000, 3)) * 4, 1))  # a policy's round velocities
    vecs += [[4.0, 0.0, 0.0], [-4.0, -0.0, 0.0], [0.0, -4.0, -0.0], [-1.0, 5e-9, 0.0],
             [-2.0, 1e-8, -0.0], [0.0, 0.0, 0.0], [1.0, math.nan, 0.0], [math.inf, 0.0, 0.0]]  # fmt: skip
    for v in vecs:
        for s in (1.0, 0.5):
            want = _arrow_numpy((1.0, 2.0, -3.0), v, m.GREEN, s)
            got = m._arrow_to((1.0, 2.0, -3.0), v, m.GREEN, s)
            assert (got is None) == (want is None), v
            assert got is None or got.encode() == want.encode(), v


def _pose_numpy(t, pos_ned, quat_wxyz, vehicle) -> list[bytes] | None:
    """FlightLog.pose's two messages as it made them: numpy's checks, each message whole."""
    p = np.asarray(pos_ned, dtype=float)
    if p.shape != (3,) or not np.all(np.isfinite(p)):
        return None
    ts = m.stamp(t)
    tf = m.fm.FrameTransforms(transforms=[
        m.fm.FrameTransform(timestamp=ts, parent_frame_id=m.WORLD, child_frame_id=m.NED,
                            translation=m._v3((0, 0, 0)), rotation=m._quat((0, 1, 0, 0))),
        m.fm.FrameTransform(timestamp=ts, parent_frame_id=m.NED, child_frame_id=vehicle,
                            translation=m._v3(p), rotation=m._quat(quat_wxyz)),
    ])  # fmt: skip
    return [m.pose_in_frame(t, p, quat_wxyz).encode(), tf.encode()]


class _Sink:
    def __init__(self):
        self.data: list[bytes] = []

    def channel(self, spec):
        return spec.topic

    def write(self, handle, t_ns, data):
        self.data.append(data)

    def close(self):
        pass


def test_a_pose_is_recorded_as_before():
    """FlightLog.pose (finite3, pose_and_transforms: one stamp, position and quaternion for
    both messages) writes the bytes it wrote with numpy's checks and two builders."""
    from skyherd.record.flightlog import FlightLog

    rng = np.random.default_rng(33)
    poses = [(rng.normal(size=3) * 50, rng.normal(size=4)) for _ in range(2000)]
    poses += [(list(rng.normal(size=3)), tuple(rng.normal(size=4))) for _ in range(500)]
    poses += [([1, 2, 3], (1, 0, 0, 0)), ((0.0, -0.0, -20.0), [0.0, 0.0, 0.0, 0.0]),
              ([1.0, math.nan, 0.0], (1, 0, 0, 0)), ([1.0, 2.0], (1, 0, 0, 0)),
              (np.zeros((1, 3)), (1, 0, 0, 0)), ([True, 2, 3.5], [math.nan, 0, 0, 1]),
              ([math.inf, 0, 0], (1, 0, 0, 0)), ((5.0, 6.0, -7.0), (0.5, math.inf, 0, 0))]  # fmt: skip
    for i, (p, q) in enumerate(poses):
        t = i * 0.1
        sink = _Sink()
        FlightLog(sink).pose(t, p, q, vehicle="uav1")
        want = _pose_numpy(t, p, q, "uav1")
        assert sink.data == (want or []), (p, q)
