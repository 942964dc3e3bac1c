"""Recording from Zenoh (record.zenoh.ZenohRecorder) between two real Zenoh sessions on
loopback (Zenoh port 7462), and the live Foxglove WebSocket server (record.live.LiveServer, on
a free port) with a real WebSocket client (the `websockets` package) speaking the Foxglove
WebSocket protocol: subscribe, receive frames and poses stamped in simulation time."""

from __future__ import annotations

import json
import struct
import time

import numpy as np
import pytest
from google.protobuf import descriptor_pb2, descriptor_pool, message_factory

from skyherd.groundsim.transport import UGVStatePublisher
from skyherd.groundsim.ugv import UGVStates
from skyherd.perception.camera import CameraParams
from skyherd.perception.transport import FramePublisher, ZenohParams, open_session
from skyherd.record import LiveServer, ZenohRecorder, read_messages
from skyherd.safety.events import ZenohEventSink

ZPORT = 7462
WSPORT = 0  # any free port (the server says which: live.port); no clash with a parallel run


def _until(cond, what: str, timeout_s: float = 30.0) -> None:
    """Wait for a condition of the real link; the timeout only stops a hung test."""
    deadline = time.monotonic() + timeout_s
    while not cond():
        if time.monotonic() > deadline:
            raise AssertionError(f"timed out waiting for {what}")
        time.sleep(0.005)


def test_zenoh_recorder_records_every_key_of_a_flight_in_another_session(tmp_path):
    pub_s = open_session(ZenohParams(listen=(f"tcp/127.0.0.1:{ZPORT}",)))
    rec_s = open_session(ZenohParams(connect=(f"tcp/127.0.0.1:{ZPORT}",)))
    path = tmp_path / "flight.mcap"
    rec = ZenohRecorder(rec_s, "uav0", path)
    try:
        cam = CameraParams(width_px=80, height_px=60)
        frames = {"raw": FramePublisher(pub_s, "uav0", cam, "raw"),
                  "jpeg": FramePublisher(pub_s, "uav0", cam, "jpeg")}  # fmt: skip
        ugv = UGVStatePublisher(pub_s, 3)
        events = ZenohEventSink(pub_s, "uav0")
        dec = pub_s.declare_publisher("skyherd/uav0/decision")
        clock = pub_s.declare_publisher("skyherd/sim/clock")
        junk = pub_s.declare_publisher("skyherd/uav0/decision")
        # every key's subscriber known to the publishing session before the first put (the
        # recorder declares them one after another; a put before its match is not delivered)
        probes = [pub_s.declare_publisher(k) for k in (
            "skyherd/ugv/0/state", "skyherd/ugv/2/state", "skyherd/uav0/decision",
            "skyherd/uav0/safety/event", "skyherd/sim/clock")]  # fmt: skip
        _until(
            lambda: (
                frames["raw"].has_subscriber()
                and frames["jpeg"].has_subscriber()
                and all(p.matching_status.matching for p in probes)
            ),
            "every subscriber matched",
        )
        img = (np.random.default_rng(0).random((60, 80, 3)) * 255).astype(np.uint8)
        n = 10
        for k in range(n):  # lockstep on what arrived: a count, not a wall-time race
            t = 0.1 * k
            before = sum(rec.received.values())
            frames["raw" if k % 2 else "jpeg"].publish(
                t, np.array([k, 0.0, -20.0]), np.array([1.0, 0, 0, 0]), img
            )
            ugv.publish(
                t,
                UGVStates(
                    np.array([[0, 0], [5, 0], [0, 5.0]]), np.zeros(3), np.ones(3), np.zeros(3, bool)
                ),
            )
            dec.put(
                json.dumps(
                    {
                        "t": t,
                        "vehicle": "uav0",
                        "phi": [0.0] * 8,
                        "proposed": {"vel_ned": [1, 0, 0]},
                        "certified": {"vel_ned": [1, 0, 0]},
                        "verdict": "accepted",
                        "reason": "",
                        "mode": "ai",
                    }
                )
            )
            clock.put(json.dumps({"t_sim": t}) if k % 2 else struct.pack("<d", t))
            if k == 4:
                events.write(
                    {"t": t, "event": "switch", "from": "ai", "to": "fallback", "reason": "fence"}
                )
            _until(
                lambda b=before, k=k: sum(rec.received.values()) >= b + 6 + (k == 4), f"step {k}"
            )
        junk.put(b"{not json")
        _until(lambda: rec.corrupt.get("decision", 0) == 1, "the corrupt decision")
    finally:
        rec.close()
        rec_s.close()
        pub_s.close()
    got = read_messages(path)
    assert got.complete
    c = got.counts()
    assert c["/uav0/camera/image"] == n and c["/uav0/pose"] == n and c["/tf"] == n
    assert c["/uav0/decision"] == n and c["/uav0/phi"] == n
    # the three states of each time in one scene (the first time: UGV 0 alone, then 1 and 2,
    # while the recorder learns how many there are); every state drawn once
    scenes = [(m.t, [e.id for e in _scene(m.data).entities]) for m in got.topic("/ugvs")]
    assert scenes[:2] == [(0.0, ["ugv0"]), (0.0, ["ugv1", "ugv2"])]
    assert scenes[2:] == [(pytest.approx(0.1 * k), ["ugv0", "ugv1", "ugv2"]) for k in range(1, n)]
    assert c["/uav0/safety/event"] == 1 and c["/uav0/log"] == 1 and c["/sim/clock"] == n
    assert [m.t for m in got.topic("/sim/clock")] == pytest.approx([0.1 * k for k in range(n)])
    assert [m.t for m in got.topic("/uav0/camera/image")] == pytest.approx(
        [0.1 * k for k in range(n)]
    )
    assert got.topic("/uav0/safety/event")[0].json()["reason"] == "fence"
    # frames: JPEG kept as received, raw frames JPEG-encoded; all decode to the published size
    import cv2

    assert all(b"\xff\xd8" in m.data for m in got.topic("/uav0/camera/image"))
    jpg = got.topic("/uav0/camera/image")[0].data
    start = jpg.index(b"\xff\xd8")
    im = cv2.imdecode(np.frombuffer(jpg[start:], np.uint8), cv2.IMREAD_COLOR)
    assert im is not None and im.shape == (60, 80, 3)


def _scene(data: bytes):
    """A foxglove.SceneUpdate decoded from its bytes with the schema foxglove publishes."""
    from foxglove import messages as fm

    schema = fm.SceneUpdate.get_schema()
    fds = descriptor_pb2.FileDescriptorSet.FromString(schema.data)
    pool = descriptor_pool.DescriptorPool()
    for fd in fds.file:
        pool.Add(fd)
    return message_factory.GetMessageClass(pool.FindMessageTypeByName(schema.name)).FromString(data)


def _proto_class(schema: dict):
    """A protobuf class from an advertised channel's schema (base64 FileDescriptorSet)."""
    import base64

    fds = descriptor_pb2.FileDescriptorSet.FromString(base64.b64decode(schema["schema"]))
    pool = descriptor_pool.DescriptorPool()
    for fd in fds.file:
        pool.Add(fd)
    return message_factory.GetMessageClass(pool.FindMessageTypeByName(schema["schemaName"]))


class _Session:
    """Enough of a Zenoh session for the recorder: its callbacks by key, fed by hand."""

    def __init__(self):
        self.callbacks = {}

    def declare_subscriber(self, key, cb):
        self.callbacks[key] = cb
        return self

    def undeclare(self):
        pass


class _Sample:
    def __init__(self, payload: bytes):
        self.payload = self
        self._b = payload

    def to_bytes(self) -> bytes:
        return self._b


def test_ugv_states_of_one_time_make_one_scene_and_every_authentic_state_is_drawn_once(tmp_path):
    from skyherd.runio.mac import record_mac, sign_record

    key = bytes(range(32))
    session = _Session()
    rec = ZenohRecorder(session, "uav0", tmp_path / "flight.mcap", key=key)
    feed = session.callbacks["skyherd/ugv/*/state"]

    def state(i: int, t: float, heading: float = 0.1) -> dict:
        return {"id": i, "seq": round(10 * t), "t_sim": t, "pos_ned": [float(i), t, 0.0],
                "heading_rad": heading, "speed_mps": 1.0, "camouflaged": i == 2}  # fmt: skip

    sent = [(0, 0.0), (1, 0.0), (2, 0.0), (0, 0.1), (1, 0.1), (2, 0.1),
            (0, 0.2), (2, 0.2),  # UGV 1 silent: its time is drawn when the next one starts
            (0, 0.3), (0, 0.3), (1, 0.3), (2, 0.3),  # UGV 0 twice: both drawn
            (0, 0.4)]  # fmt: skip
    for i, t in sent:
        feed(_Sample(sign_record(state(i, t), key)))
    old = state(1, 0.4)  # an older writer's record (spaced, its own key order): still authentic
    feed(_Sample(json.dumps({**old, "mac": record_mac(key, old)}).encode()))
    feed(_Sample(sign_record(state(2, 0.4), bytes(32))))  # another key: refused
    feed(_Sample(sign_record(state(2, 0.4, heading=float("inf")), key)))  # cannot be drawn
    feed(_Sample(sign_record(state(2, 0.4), key)[:-3] + b'0"}'))  # altered mac: refused
    rec.close()  # draws 0.4's two states: UGV 2 never came right
    assert rec.received == {"ugv": len(sent) + 1} and rec.corrupt == {"ugv": 3}
    scenes = [
        (round(m.t, 3), [e.id for e in _scene(m.data).entities])
        for m in read_messages(tmp_path / "flight.mcap").topic("/ugvs")
    ]
    assert scenes == [(0.0, ["ugv0"]), (0.0, ["ugv1", "ugv2"]), (0.1, ["ugv0", "ugv1", "ugv2"]),
                      (0.2, ["ugv0", "ugv2"]), (0.3, ["ugv0"]), (0.3, ["ugv0", "ugv1", "ugv2"]),
                      (0.4, ["ugv0", "ugv1"])]  # fmt: skip
    ent = _scene(read_messages(tmp_path / "flight.mcap").topic("/ugvs")[2].data).entities[2]
    assert ent.cubes[0].pose.position.x == 2.0 and ent.cubes[0].color.r == 1.0  # orange
    assert ent.texts[0].text == "ugv 2" and ent.timestamp.nanos == 100_000_000


def _frame(t: float, north: float) -> bytes:
    from skyherd.perception.transport import encode_frame

    image = np.zeros((6, 8, 3), np.uint8)
    return encode_frame(round(10 * t), t, np.array([north, 0.0, -20.0]), np.array([1.0, 0, 0, 0]),
                        image)  # fmt: skip


def _decision(t: float) -> bytes:
    return json.dumps({"t": t, "certified": {"vel_ned": [2.0, 0.0, 0.0]}}).encode()


def test_the_recorders_thread_records_the_queue_and_draws_each_decision_from_its_own_pose(tmp_path):
    """Each key's callback only queues the sample's bytes; the recorder's thread records the
    queue in arrival order (close() what is still queued). A decision's setpoint arrow starts
    at the pose of its own time, also when the next frame came first (the keys race)."""
    session = _Session()
    rec = ZenohRecorder(session, "uav0", tmp_path / "flight.mcap")
    frame, decision = (session.callbacks[f"skyherd/uav0/{k}"] for k in ("camera/frame", "decision"))
    frame(_Sample(_frame(0.0, 1.0)))
    frame(_Sample(_frame(0.1, 5.0)))  # before the decision of 0.0
    decision(_Sample(_decision(0.0)))
    decision(_Sample(_decision(0.1)))
    decision(_Sample(_decision(0.25)))  # its frame not (yet) come: the newest before it
    session.callbacks["skyherd/sim/clock"](_Sample(b'{"t_sim": 0.1}'))
    rec.close()
    assert rec.received == {"frame": 2, "decision": 3, "clock": 1} and not rec.corrupt
    got = read_messages(tmp_path / "flight.mcap")
    arrows = [_scene(m.data).entities[0].arrows[0] for m in got.topic("/uav0/setpoint")]
    assert [a.pose.position.x for a in arrows] == [1.0, 5.0, 5.0]
    assert [m.t for m in got.topic("/sim/clock")] == [0.1]


def test_a_full_queue_drops_and_counts_what_comes_never_holding_zenoh(tmp_path, monkeypatch):
    """Samples that come while QUEUE wait (the recorder's thread behind) are dropped and
    counted in the file's metadata: the callback returns at once."""
    from mcap.reader import make_reader

    monkeypatch.setattr(ZenohRecorder, "QUEUE", 3)
    monkeypatch.setattr(ZenohRecorder, "BATCH_S", 60.0)  # the thread takes none before close()
    session = _Session()
    rec = ZenohRecorder(session, "uav0", tmp_path / "flight.mcap")
    for k in range(5):
        session.callbacks["skyherd/sim/clock"](_Sample(json.dumps({"t_sim": k / 10}).encode()))
    rec.close()
    assert rec.received == {"clock": 3} and rec.dropped == 2
    clock = read_messages(tmp_path / "flight.mcap").topic("/sim/clock")
    assert [m.t for m in clock] == [0.0, 0.1, 0.2]
    with open(tmp_path / "flight.mcap", "rb") as f:
        meta = {m.name: m.metadata for m in make_reader(f).iter_metadata()}
    assert meta["skyherd zenoh"]["dropped"] == "2"


def test_the_queue_is_bounded_in_bytes_too_so_big_frames_cannot_grow_it(tmp_path, monkeypatch):
    """QUEUE_BYTES bounds what waits as well as QUEUE: with room for two of these payloads the
    third and fourth are dropped (counted), a small one after them still fits; once the
    thread took the queue there is room again."""
    monkeypatch.setattr(ZenohRecorder, "QUEUE_BYTES", 250)
    monkeypatch.setattr(ZenohRecorder, "BATCH_S", 60.0)  # the thread takes none before close()
    session = _Session()
    rec = ZenohRecorder(session, "uav0", tmp_path / "flight.mcap")
    clock = session.callbacks["skyherd/sim/clock"]
    pad = " " * 90  # JSON allows the whitespace: each payload ~110 bytes
    for k in range(4):
        clock(_Sample(json.dumps({"t_sim": k / 10}).encode() + pad.encode()))
    clock(_Sample(b'{"t_sim": 0.5}'))
    assert rec.dropped == 2
    rec._drain()
    clock(_Sample(json.dumps({"t_sim": 0.6}).encode() + pad.encode()))
    rec.close()
    assert rec.received == {"clock": 4} and rec.dropped == 2
    assert [m.t for m in read_messages(tmp_path / "flight.mcap").topic("/sim/clock")] == [
        0.0, 0.1, 0.5, 0.6
    ]  # fmt: skip


def test_live_server_serves_frames_and_poses_to_a_websocket_client():
    from websockets.sync.client import connect

    live = LiveServer(WSPORT)
    img = (np.random.default_rng(0).random((60, 80, 3)) * 255).astype(np.uint8)
    try:
        live.pose(0.0, [0, 0, -20])  # channels are advertised once they exist
        live.frame(0.0, img)
        with connect(live.url, subprotocols=["foxglove.sdk.v1"], open_timeout=30) as ws:
            channels: dict[str, dict] = {}
            while not {"/uav0/pose", "/uav0/camera/image"} <= set(channels):
                msg = ws.recv(timeout=30)
                if isinstance(msg, str):
                    m = json.loads(msg)
                    if m["op"] == "advertise":
                        channels.update({c["topic"]: c for c in m["channels"]})
            assert channels["/uav0/camera/image"]["schemaName"] == "foxglove.CompressedImage"
            assert channels["/uav0/pose"]["encoding"] == "protobuf"
            subs = {1: "/uav0/pose", 2: "/uav0/camera/image"}
            ws.send(json.dumps({"op": "subscribe", "subscriptions": [
                {"id": i, "channelId": channels[t]["id"]} for i, t in subs.items()]}))  # fmt: skip
            got: dict[str, list] = {"/uav0/pose": [], "/uav0/camera/image": []}
            k = 0
            # the subscription takes effect asynchronously: publish until the first pose shows
            while not got["/uav0/pose"]:
                k += 1
                live.pose(0.1 * k, [k, 0, -20])
                live.frame(0.1 * k, img)
                try:
                    msg = ws.recv(timeout=0.2)
                except TimeoutError:
                    continue
                if isinstance(msg, bytes) and msg[0] == 1:  # opcode 1: message data
                    sub, log_time = struct.unpack_from("<IQ", msg, 1)
                    got[subs[sub]].append((log_time, msg[13:]))
                assert k < 500, "no message after 500 publishes"
            first = k + 1
            for j in range(first, first + 5):
                live.pose(0.1 * j, [j, 0, -20])
                live.frame(0.1 * j, img)
            while len([1 for lt, _ in got["/uav0/camera/image"] if lt >= round(0.1 * first * 1e9)]) < 5 or \
                    len([1 for lt, _ in got["/uav0/pose"] if lt >= round(0.1 * first * 1e9)]) < 5:  # fmt: skip
                msg = ws.recv(timeout=30)
                if isinstance(msg, bytes) and msg[0] == 1:
                    sub, log_time = struct.unpack_from("<IQ", msg, 1)
                    got[subs[sub]].append((log_time, msg[13:]))
        pose_cls = _proto_class(channels["/uav0/pose"])
        img_cls = _proto_class(channels["/uav0/camera/image"])
        tail = [
            (lt, pose_cls.FromString(d))
            for lt, d in got["/uav0/pose"]
            if lt >= round(0.1 * first * 1e9)
        ]
        assert [lt for lt, _ in tail] == [round(0.1 * j * 1e9) for j in range(first, first + 5)]
        assert [p.pose.position.x for _, p in tail] == [float(j) for j in range(first, first + 5)]
        frame = img_cls.FromString(got["/uav0/camera/image"][-1][1])
        assert frame.format == "jpeg" and frame.data[:2] == b"\xff\xd8"
    finally:
        live.close()
