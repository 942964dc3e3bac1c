"""MCAP recording (record/): a flight's file read back with the `mcap` reader finds every
channel with the right message counts and Foxglove schemas, messages decode from the schemas
the file carries (as Foxglove and PlotJuggler do), times are simulation times, and a file cut
by a kill reads up to its last complete chunk."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import textwrap
from pathlib import Path

import numpy as np
import pytest
from google.protobuf import descriptor_pb2, descriptor_pool, message_factory
from mcap.reader import make_reader

from skyherd.record import FlightRecorder, read_messages

ROOT = Path(__file__).resolve().parents[2]


def _decoder(schema):
    """A protobuf message class built only from the schema record in the file."""
    fds = descriptor_pb2.FileDescriptorSet.FromString(schema.data)
    pool = descriptor_pool.DescriptorPool()
    for fd in fds.file:
        pool.Add(fd)
    return message_factory.GetMessageClass(pool.FindMessageTypeByName(schema.name))


def _decision(t: float, verdict: str) -> dict:
    return {
        "t": t, "vehicle": "uav0", "pilot": "policy", "phi": [0.1, 0.2, 0.3, 0.4, 0.5, 0.6, 0.7, float("nan")],
        "proposed": {"pos_ned": None, "vel_ned": [4.0, 0.0, 0.0], "yaw": None},
        "certified": {"pos_ned": [1.0, 2.0, -20.0], "vel_ned": [2.0, 0.0, 0.0], "yaw": 0.5},
        "verdict": verdict, "reason": "accel limit 4 m/s²", "mode": "ai", "autopilot_mode": "OFFBOARD",
    }  # fmt: skip


def _fly(rec: FlightRecorder, n: int = 40) -> None:
    """A synthetic 10 Hz flight: frames, poses, decisions, UGVs; two events; the fence."""
    from skyherd.safety.config import default_envelope_path, load_envelope

    spec, _ = load_envelope(default_envelope_path("quadrotor"))
    rng = np.random.default_rng(0)
    img = (rng.random((60, 80, 3)) * 255).astype(np.uint8)
    rec.geometry(0.0, spec)
    for k in range(n):
        t = 0.1 * k
        rec.clock(t)
        rec.pose(t, [k * 0.5, 0.0, -20.0], [np.cos(0.1), 0.0, 0.0, np.sin(0.1)])
        rec.frame(t, img)
        rec.ugvs(t, [{"id": i, "pos_ned": [i, k * 0.1, 0.0], "heading_rad": 0.2} for i in range(3)])
        rec.decision(t, _decision(t, "projected" if k % 2 else "accepted"))
    rec.event(1.5, {"t": 1.5, "event": "switch", "from": "ai", "to": "fallback", "reason": "fence"})
    rec.event(2.5, {"t": 2.5, "event": "switch", "from": "fallback", "to": "ai", "reason": "clear"})


EXPECTED = {  # topic → (schema, count) for _fly(n=40)
    "/uav0/camera/image": ("foxglove.CompressedImage", 40),
    "/uav0/pose": ("foxglove.PoseInFrame", 40),
    "/tf": ("foxglove.FrameTransforms", 40),
    "/ugvs": ("foxglove.SceneUpdate", 40),
    "/uav0/decision": ("skyherd.Decision", 40),
    "/uav0/phi": ("skyherd.Phi", 40),
    "/uav0/setpoint": ("foxglove.SceneUpdate", 40),
    "/uav0/setpoint/pose": ("foxglove.PoseInFrame", 40),
    "/uav0/safety/event": ("skyherd.SafetyEvent", 2),
    "/uav0/log": ("foxglove.Log", 2),
    "/uav0/safety/state": ("skyherd.NetState", 2),
    "/sim/clock": ("skyherd.SimClock", 40),
}


def test_flight_mcap_has_every_channel_with_its_count_and_schema(tmp_path):
    path = tmp_path / "flight.mcap"
    with FlightRecorder(path) as rec:
        _fly(rec)
    with open(path, "rb") as f:
        reader = make_reader(f)
        summary = reader.get_summary()
        counts = {
            summary.channels[c].topic: n
            for c, n in summary.statistics.channel_message_counts.items()
        }
        schemas = {ch.topic: summary.schemas[ch.schema_id].name for ch in summary.channels.values()}
        n_geometry = counts.pop("/geometry")
        assert schemas.pop("/geometry") == "foxglove.SceneUpdate"
        assert counts == {k: n for k, (_, n) in EXPECTED.items()}
        assert schemas == {k: s for k, (s, _) in EXPECTED.items()}
        assert n_geometry >= 1  # one entity per fence zone
        decoded: dict[str, list] = {}
        classes = {}
        for schema, channel, msg in reader.iter_messages():
            if channel.message_encoding == "json":
                obj = json.loads(msg.data)  # strict JSON: a NaN would not parse in Foxglove
            else:
                assert channel.message_encoding == "protobuf" and schema.encoding == "protobuf"
                cls = classes.setdefault(schema.name, _decoder(schema))
                obj = cls.FromString(msg.data)
            decoded.setdefault(channel.topic, []).append((msg.log_time, obj))
    # simulation time: log time = the 0.1 s steps; message stamps agree
    times = [lt for lt, _ in decoded["/uav0/pose"]]
    assert times == [round(0.1 * k * 1e9) for k in range(40)]
    lt, img = decoded["/uav0/camera/image"][7]
    assert img.format == "jpeg" and img.data[:2] == b"\xff\xd8"
    assert img.timestamp.seconds * 10**9 + img.timestamp.nanos == lt
    _, pose = decoded["/uav0/pose"][4]
    assert pose.frame_id == "ned" and pose.pose.position.x == pytest.approx(2.0)
    assert pose.pose.position.z == pytest.approx(-20.0)
    _, tf = decoded["/tf"][0]
    assert [(x.parent_frame_id, x.child_frame_id) for x in tf.transforms] == [
        ("world", "ned"),
        ("ned", "uav0"),
    ]
    _, dec = decoded["/uav0/decision"][3]
    assert dec["verdict"] == "projected" and dec["proposed"]["vel_ned"] == [4.0, 0.0, 0.0]
    assert dec["phi"][7] is None  # NaN written as null
    _, phi = decoded["/uav0/phi"][0]
    assert set(phi["features"]) and len(phi["values"]) == 8
    _, sp = decoded["/uav0/setpoint"][5]
    assert len(sp.entities[0].arrows) == 2  # proposed and certified velocity
    _, ugv = decoded["/ugvs"][0]
    assert [e.id for e in ugv.entities] == ["ugv0", "ugv1", "ugv2"]
    _, log = decoded["/uav0/log"][0]
    assert "ai → fallback: fence" in log.message
    fence = [o for _, o in decoded["/geometry"]]
    assert all(len(e.lines) >= 3 for u in fence for e in u.entities)
    # our own reader agrees with the mcap summary
    assert read_messages(path).counts() == {
        **{k: n for k, (_, n) in EXPECTED.items()},
        "/geometry": n_geometry,
    }


def test_truncated_file_reads_up_to_the_last_complete_chunk(tmp_path):
    path = tmp_path / "flight.mcap"
    rec = FlightRecorder(path, chunk_s=0.5)
    flushes = [(os.path.getsize(path), 0)]  # (file size, messages readable) at each chunk end
    written = 0
    for k in range(60):
        rec.pose(0.1 * k, [k, 0, -10])
        rec.decision(0.1 * k, _decision(0.1 * k, "accepted"))
        written = sum(rec.counts.values())
        if os.path.getsize(path) != flushes[-1][0]:
            flushes.append((os.path.getsize(path), rec.file.flushed_messages))
    assert len(flushes) > 5
    full = path.read_bytes()  # before close: no summary, no footer (as after a kill)
    rec.close()
    rng = np.random.default_rng(1)
    cuts = sorted(set(rng.integers(flushes[1][0], len(full), 25).tolist()) | {len(full)})
    for cut in cuts:
        part = tmp_path / "cut.mcap"
        part.write_bytes(full[:cut])
        got = read_messages(part)
        before = max(n for size, n in flushes if size <= cut)
        after = min((n for size, n in flushes if size > cut), default=before)
        assert before <= len(got.messages) <= after, (cut, before, len(got.messages), after)
        assert not got.complete
    # a closed file is complete and indexed
    done = read_messages(path)
    assert done.complete and not done.truncated and len(done.messages) == written


CHILD = textwrap.dedent(
    """
    import sys
    from skyherd.record import FlightRecorder
    rec = FlightRecorder(sys.argv[1], chunk_s=1.0)
    for k in range(35):                      # 3.5 s of sim time: 3 closed chunks + an open one
        rec.pose(0.1 * k, [k, 0, -10])
        rec.event(0.1 * k, {"t": 0.1 * k, "event": "tick", "reason": str(k)})
    print(rec.file.chunks, flush=True)
    sys.stdin.readline()                     # killed here, the open chunk still in memory
    """
)


def test_a_killed_recorder_leaves_every_closed_chunk_readable(tmp_path):
    path = tmp_path / "flight.mcap"
    p = subprocess.Popen([sys.executable, "-c", CHILD, str(path)], cwd=ROOT,
                         stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True)  # fmt: skip
    try:
        chunks = int(p.stdout.readline())
    finally:
        p.send_signal(signal.SIGKILL)
        p.wait(timeout=60)
    got = read_messages(path)
    assert chunks == 3 and not got.complete
    times = [m.t for m in got.topic("/uav0/pose")]
    # every chunk spans 1 s of sim time: the poses of t < 3.0 s survive, the open chunk not
    assert times == pytest.approx([0.1 * k for k in range(len(times))]) and 28 <= len(times) <= 31
    assert [m.json()["reason"] for m in got.topic("/uav0/safety/event")] == [
        str(k) for k in range(len(got.topic("/uav0/safety/event")))
    ]
