"""Issue 27 item 3 for the JSON records on Zenoh (runio.mac): the camera's info, the companion's
decisions and its safety net's events carry a MAC under the flight's key, as the UGV states and
the clock do, and every reader given the key (the companion's camera link, `fly`'s recorder)
refuses and counts what fails. The forgeries come from a real Zenoh session of their own (a
third session here; a real attacker process, tests/attacker.py `records`, against a default
`skyherd fly` and a `--no-signing` one, so the test can fail)."""

from __future__ import annotations

import json
import os
import time

import pytest
from test_attack_mavlink import assert_signed_and_untouched, assert_unsigned, attacked_flight

from skyherd.mission.flight import Record
from skyherd.perception.camera import CameraParams
from skyherd.perception.transport import (
    FramePublisher,
    FrameSubscriber,
    ZenohParams,
    open_session,
    publisher_params,
)
from skyherd.record import ZenohRecorder, read_messages
from skyherd.runio.mac import record_mac
from skyherd.safety.events import ZenohEventSink
from tests.attacker import FORGED_T_SIM, forged_records

KEY, OTHER = bytes(range(32)), os.urandom(32)
PORT = 7548  # instance 101's Zenoh port (this helper's instances 100-105)


def zenoh_counts(path) -> dict:
    """The recorder's counts in flight.mcap (the "skyherd zenoh" metadata record)."""
    from mcap.reader import make_reader

    with open(path, "rb") as f:
        (meta,) = [m for m in make_reader(f).iter_metadata() if m.name == "skyherd zenoh"]
    return {k: json.loads(v) for k, v in meta.metadata.items()}


def _until(cond, what: str, patience_s: float = 30.0) -> None:
    deadline = time.monotonic() + patience_s
    while not cond():
        assert time.monotonic() < deadline, what
        time.sleep(0.01)


def _client() -> object:
    return open_session(ZenohParams(mode="client", connect=(f"tcp/127.0.0.1:{PORT}",)))


INFO, DECISION, EVENT = ("skyherd/uav0/camera/info", "skyherd/uav0/decision",
                         "skyherd/uav0/safety/event")  # fmt: skip


def test_forged_camera_info_decisions_and_events_from_another_session_are_refused(tmp_path):
    """The simulator's peer signs its camera info; the companion's decisions and events are
    signed; a third session forges each twice (no "mac"; a MAC under another key)."""
    owner = open_session(publisher_params(PORT))  # the simulator's peer
    reader, forger = _client(), _client()
    path = tmp_path / "flight.mcap"
    try:
        guarded = FrameSubscriber(reader, "uav0", key=KEY)
        naive = FrameSubscriber(reader, "uav0")
        rec = ZenohRecorder(reader, "uav0", path, key=KEY)
        frames = FramePublisher(owner, "uav0", CameraParams(width_px=80, height_px=60), key=KEY)
        live = Record(live=owner.declare_publisher(DECISION), live_key=KEY)
        events = ZenohEventSink(owner, "uav0", KEY)
        fakes = {k: forger.declare_publisher(k) for k in (INFO, DECISION, EVENT)}
        probes = [owner.declare_publisher(k) for k in fakes]
        _until(lambda: all(p.matching_status.matching for p in [*probes, *fakes.values()]),
               "every reader matched")  # fmt: skip
        frames.publish_info(0.5)
        live.decision({"t": 0.5, "vehicle": "uav0", "mode": "ai", "verdict": "accepted"})
        events.write({"t": 0.5, "event": "switch", "from": "ai", "to": "fallback", "reason": "x"})
        _until(lambda: guarded.stats.info_received == naive.stats.info_received == 1
               and rec.received.get("decision") == rec.received.get("event") == 1, "the real ones")  # fmt: skip
        forged = forged_records(1)
        for k, pub in fakes.items():
            pub.put(json.dumps(forged[k]).encode())  # no "mac"
            pub.put(json.dumps({**forged[k], "mac": record_mac(OTHER, forged[k])}).encode())
        _until(lambda: guarded.stats.info_refused == 2 and naive.stats.info_received == 3
               and rec.corrupt.get("decision") == rec.corrupt.get("event") == 2, "the forgeries")  # fmt: skip
        assert guarded.info["width_px"] == 80 and guarded.stats.info_received == 1
        assert naive.info["width_px"] == 9999  # without the key the forgery is the camera
        assert rec.received == {"decision": 1, "event": 1}
        rec.close()
        for s in (guarded, naive, frames, events):
            s.close()
    finally:
        for s in (forger, reader, owner):
            s.close()
    got = read_messages(path)
    assert got.counts()["/uav0/decision"] == 1 and got.counts()["/uav0/safety/event"] == 1
    assert max(m.t for m in got.messages) == 0.5
    assert zenoh_counts(path) == {"authenticated": True, "received": {"decision": 1, "event": 1},
                                  "corrupt": {"decision": 2, "event": 2}}  # fmt: skip


@pytest.mark.timeout(2400)
@pytest.mark.slow
def test_forged_records_from_an_attacker_reach_only_an_unsigned_flight(tmp_path):
    """tests/attacker.py `records`: at each of the first 6 decisions it sees, one forged record
    on camera/info, decision, safety/event, UGV 0's state and the clock (every record stamped
    9999 s and later). Signed: the companion refuses the camera info (counted), flight.mcap holds
    none of them. Unsigned: flight.mcap holds the attacker's decisions, events, UGV and clock."""
    forge = ("--count", "6")
    rc, run, report = attacked_flight(tmp_path / "signed", "records", instance=101,
                                      zenoh_port=PORT, attacker_args=forge, record=True)  # fmt: skip
    assert_signed_and_untouched(rc, run)
    assert report["sent"] >= 1, report
    link = json.loads((run / "companion.json").read_text())["camera_link"]
    assert link["authenticated"] is True and 1 <= link["info_refused"] <= report["sent"], link
    got = read_messages(run / "flight.mcap")
    assert got.complete and got.counts()["/uav0/decision"] > 0
    assert max(m.t for m in got.messages) < FORGED_T_SIM, "a forged record was recorded"
    refused = zenoh_counts(run / "flight.mcap")["corrupt"]  # counted by the recorder
    assert {"decision", "event", "ugv", "clock"} <= set(refused), refused
    rc, run, report = attacked_flight(tmp_path / "unsigned", "records", "--no-signing",
                                      instance=101, zenoh_port=PORT, attacker_args=forge,
                                      record=True)  # fmt: skip
    assert_unsigned(run)
    assert report["sent"] >= 1, report
    link = json.loads((run / "companion.json").read_text())["camera_link"]
    assert link["authenticated"] is False and link["info_refused"] == 0
    got = read_messages(run / "flight.mcap")
    taken = {m.topic for m in got.messages if m.t >= FORGED_T_SIM}
    assert {"/uav0/decision", "/uav0/safety/event", "/ugvs", "/sim/clock"} <= taken, taken
    assert zenoh_counts(run / "flight.mcap")["authenticated"] is False


def _furthest(run) -> float:
    """The largest furthest-UGV feature the shepherd decided on (its distance over the flock's
    radius f, mission.shepherd): a UGV reported 500 m away makes it jump."""
    rows = [json.loads(x) for x in (run / "decisions.jsonl").read_text().splitlines()]
    return max(
        (r.get("explanation") or {}).get("concepts", {}).get("furthest_over_f", 0.0) for r in rows
    )


@pytest.mark.timeout(2400)
@pytest.mark.slow
def test_a_forged_ugv_state_reaches_only_an_unsigned_shepherd(tmp_path):
    """The shepherd reads the flock's states from Zenoh: signed, the attacker's UGV 0 (500 m
    north) is refused and counted (companion.json `ugv_link`); unsigned, the shepherd decides
    on it (its furthest-UGV feature jumps)."""
    shepherd = ("--mission", "shepherd", "--shepherd-selector", "strombom", "--duration", "15")
    forge = ("--count", "6")
    rc, run, report = attacked_flight(tmp_path / "signed", "records", *shepherd, instance=102,
                                      zenoh_port=PORT + 1, attacker_args=forge)  # fmt: skip
    assert rc == 0, (run / "summary.md").read_text()
    link = json.loads((run / "companion.json").read_text())["ugv_link"]
    assert link["authenticated"] is True and link["received"] > 100, link
    assert 1 <= link["refused"] <= report["sent"], (link, report)
    signed = _furthest(run)
    rc, run, report = attacked_flight(tmp_path / "unsigned", "records", "--no-signing", *shepherd,
                                      instance=102, zenoh_port=PORT + 1, attacker_args=forge)  # fmt: skip
    link = json.loads((run / "companion.json").read_text())["ugv_link"]
    assert link["authenticated"] is False and link["refused"] == 0, link
    assert _furthest(run) > 10 * signed, (signed, _furthest(run))
