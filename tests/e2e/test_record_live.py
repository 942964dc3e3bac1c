"""The live view (record.live) with a real WebSocket client (the `websockets` package speaking
the Foxglove SDK's subprotocol) that joins late: every channel advertised before the flight's
first message, the fence and the net's newest event re-sent on subscription, every decision
after it, and a close frame at the end. In-process, then through `skyherd fly
--foxglove` (a flight with a lost camera: the net's fallback is the event)."""

import json
import os
import re
import subprocess
import sys
import time
from pathlib import Path

import pytest
from websockets.sync.client import connect

from skyherd.record import LiveServer
from skyherd.safety.config import ENVELOPE_DIR, load_envelope

ROOT = Path(__file__).resolve().parents[2]
SUBPROTOCOL = ["foxglove.sdk.v1"]


class Client:
    """A Foxglove WebSocket client: advertised channels, subscriptions, messages by topic."""

    def __init__(self, ws):
        self.ws = ws
        self.channels: dict[str, dict] = {}
        self.subs: dict[int, str] = {}
        self.got: dict[str, list[bytes]] = {}
        self.status: list[str] = []
        self.closed_with: int | None = None

    def pump(self, until, timeout_s: float = 60.0) -> None:
        """Read until `until()` is true (or the server closes the connection)."""
        end = time.monotonic() + timeout_s
        while not until():
            assert time.monotonic() < end, "timed out waiting for the live view"
            try:
                msg = self.ws.recv(timeout=0.5)
            except TimeoutError:
                continue
            except Exception:  # noqa: BLE001 - the server closed: record how
                self.closed_with = (
                    self.ws.protocol.close_rcvd.code if self.ws.protocol.close_rcvd else -1
                )
                return
            if isinstance(msg, str):
                m = json.loads(msg)
                if m["op"] == "advertise":
                    self.channels.update({c["topic"]: c for c in m["channels"]})
                elif m["op"] == "status":
                    self.status.append(m["message"])
            elif msg[0] == 1:  # opcode 1: message data (subscription id, log time, payload)
                sub = int.from_bytes(msg[1:5], "little")
                self.got.setdefault(self.subs[sub], []).append(msg[13:])

    def subscribe(self, topics) -> None:
        ids = {i + 1: t for i, t in enumerate(topics)}
        self.subs.update(ids)
        self.ws.send(json.dumps({"op": "subscribe", "subscriptions": [
            {"id": i, "channelId": self.channels[t]["id"]} for i, t in ids.items()]}))  # fmt: skip

    def json(self, topic: str) -> list[dict]:
        return [json.loads(d) for d in self.got.get(topic, [])]


def test_a_late_client_gets_every_channel_the_fence_the_last_event_then_every_decision():
    spec, _ = load_envelope(ENVELOPE_DIR / "quadrotor_groundair.toml")
    live = LiveServer(0)  # any free port on 127.0.0.1
    try:
        live.advertise("uav0")
        live.geometry(0.0, spec)  # before anyone is there
        live.event(1.0, {"t": 1.0, "event": "switch", "to": "fallback", "reason": "camera lost"})
        live.event(2.0, {"t": 2.0, "event": "switch", "to": "ai", "reason": "camera back"})
        fence_msgs = live.counts["/geometry"]
        assert fence_msgs >= 1
        ws = connect(live.url, subprotocols=SUBPROTOCOL, open_timeout=60).__enter__()
        c = Client(ws)  # joins late: the fence and two events are gone by
        wanted = {"/uav0/decision", "/uav0/safety/state", "/geometry", "/uav0/safety/event",
                  "/uav0/camera/image", "/uav0/pose", "/tf", "/ugvs", "/sim/clock", "/uav0/log"}  # fmt: skip
        c.pump(lambda: wanted <= set(c.channels))  # advertised although no decision was logged
        # the decisions' subscription first: it is in force when the latched state comes back
        c.subscribe(["/uav0/decision", "/geometry", "/uav0/safety/state"])
        c.pump(
            lambda: (
                len(c.got.get("/geometry", [])) >= fence_msgs and c.got.get("/uav0/safety/state")
            )
        )
        state = c.json("/uav0/safety/state")[-1]
        assert state["events"] == 2 and state["last_event"]["reason"] == "camera back"
        for k in range(50):
            live.decision(3.0 + 0.1 * k, {"t": 3.0 + 0.1 * k, "vehicle": "uav0", "k": k})
        c.pump(lambda: len(c.got.get("/uav0/decision", [])) >= 50)
        assert [d["k"] for d in c.json("/uav0/decision")] == list(range(50))  # every one, in order
    finally:
        live.close()
    c.pump(lambda: c.closed_with is not None)
    ws.__exit__(None, None, None)
    assert c.closed_with == 1005  # a close frame (the SDK's has no status code), not a drop (1006)


@pytest.mark.slow
def test_fly_foxglove_serves_a_late_client_the_fence_the_events_and_every_decision(tmp_path):
    """Through `skyherd fly --foxglove`: the client connects once the live view is announced
    (during the simulator's start and the take-off), and gets the fence, the net's events and
    every decision decisions.jsonl holds. Lockstep on the simulation clock: load-independent."""
    env = dict(os.environ, PYTHONPATH=str(ROOT))
    argv = [sys.executable, "-m", "skyherd.scripts.cli", "fly", "--duration", "20", "--cut-camera", "22:2",
            "--speedup", "0", "--instance", "33", "--zenoh-port", "7433", "--foxglove", "0",
            "--runs-dir", str(tmp_path)]  # fmt: skip
    fly = subprocess.Popen(argv, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                           cwd=ROOT, env=env)  # fmt: skip
    try:
        url = None
        for line in fly.stdout:
            m = re.search(r"live view on (ws://127\.0\.0\.1:\d+)", line)
            if m:
                url = m.group(1)
                break
        assert url, "fly announced no live view"
        ws = connect(url, subprotocols=SUBPROTOCOL, open_timeout=60).__enter__()
        c = Client(ws)
        topics = ["/uav0/decision", "/uav0/safety/event", "/uav0/safety/state", "/geometry"]
        c.pump(lambda: set(topics) <= set(c.channels))
        c.subscribe(topics)
        c.pump(lambda: c.closed_with is not None, timeout_s=600)
        ws.__exit__(None, None, None)
        out, err = fly.communicate(timeout=600)
    finally:
        if fly.poll() is None:
            fly.kill()
    assert fly.returncode == 0, err[-2000:]
    (run,) = tmp_path.iterdir()
    decisions = [json.loads(x) for x in (run / "decisions.jsonl").read_text().splitlines()]
    events = [json.loads(x) for x in (run / "events.jsonl").read_text().splitlines()]
    switches = [e for e in events if e.get("event") == "switch"]
    assert any("camera lost" in e.get("reason", "") for e in switches), switches
    got = c.json("/uav0/decision")
    assert len(got) == len(decisions) > 0
    assert [round(d["t"], 6) for d in got] == [round(d["t"], 6) for d in decisions]
    got_events = c.json("/uav0/safety/event")
    assert [e.get("reason") for e in got_events if e.get("event") == "switch"] == [
        e.get("reason") for e in switches]  # fmt: skip
    assert c.got.get("/geometry"), "no fence geometry reached the late client"
    assert c.json("/uav0/safety/state")[-1]["events"] == len(got_events)
    assert c.closed_with == 1005
