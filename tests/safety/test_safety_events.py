"""Switch events published live on Zenoh (real sessions on 127.0.0.1) and to events.jsonl."""

import json
import threading
import time

import numpy as np

from skyherd.flight.autopilot_api import Setpoint
from skyherd.flight.state import VehicleState
from skyherd.perception.transport import ZenohParams, open_session
from skyherd.runio.runfolder import JsonlWriter
from skyherd.safety.config import default_envelope_path, load_envelope
from skyherd.safety.events import Tee, ZenohEventSink, event_key
from skyherd.safety.supervisor import Mode, Supervisor

PORT = 7463  # away from the camera's 7447


def test_switch_events_reach_a_zenoh_subscriber_and_the_file(tmp_path):
    spec, _ = load_envelope(default_envelope_path("quadrotor"))
    pub_s = open_session(ZenohParams(listen=(f"tcp/127.0.0.1:{PORT}",)))
    sub_s = open_session(ZenohParams(connect=(f"tcp/127.0.0.1:{PORT}",)))
    got, ev = [], threading.Event()

    def on_sample(sample):
        got.append(json.loads(bytes(sample.payload.to_bytes()).decode()))
        ev.set()

    sub = sub_s.declare_subscriber(event_key("uav0"), on_sample)
    try:
        zsink = ZenohEventSink(pub_s, "uav0")
        fw = JsonlWriter(tmp_path / "events.jsonl")
        sup = Supervisor(spec.envelope(), events=Tee(fw, zsink))
        s = VehicleState(
            0.0,
            np.array([74.0, 0, -20]),
            np.array([3.0, 0, 0]),
            np.array([1.0, 0, 0, 0]),
            np.zeros(3),
            np.zeros(3),
            False,
        )
        deadline = time.monotonic() + 5.0
        while not ev.is_set() and time.monotonic() < deadline:  # the peers need a moment to meet
            sup.mode = Mode.AI
            sup.update(0.0, s, Setpoint(vel_ned=np.array([3.0, 0, 0])))
            ev.wait(0.2)
        fw.close()
        assert got and got[0]["reason"] == "field edge 2" and got[0]["to"] == "fallback"
        assert got[0]["envelope_version"] == spec.version and zsink.sent >= 1
        line = json.loads((tmp_path / "events.jsonl").read_text().splitlines()[0])
        assert line == got[0]  # the same record in both places
    finally:
        sub.undeclare()
        sub_s.close()
        pub_s.close()


def test_a_failing_sink_does_not_stop_the_supervisor():
    class Broken:
        def write(self, r):
            raise OSError("disk full")

    spec, _ = load_envelope(default_envelope_path("quadrotor"))
    tee = Tee(Broken())
    sup = Supervisor(spec.envelope(), events=tee)
    s = VehicleState(
        0.0,
        np.array([0.0, 0, -20]),
        np.zeros(3),
        np.array([1.0, 0, 0, 0]),
        np.zeros(3),
        np.zeros(3),
        False,
    )
    d = sup.update(0.0, s, Setpoint(vel_ned=np.array([np.nan, 0, 0])))
    assert d.mode is Mode.FALLBACK and tee.errors == 1
