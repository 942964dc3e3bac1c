"""The companion as a separate program: frames over Zenoh are what it detects on, and the
simulator holds at each camera frame until the companion has closed the tick (lockstep)."""

import threading
import time

import numpy as np
import pytest

from skyherd.flight.lockstep import LockstepParams, is_mark
from skyherd.groundsim.ugv import UGVModel, initial_states
from skyherd.mission.companion import FrameInbox
from skyherd.mission.perception import Perception
from skyherd.mission.vehicle import VehicleLink
from skyherd.perception.render_fast import FastRenderer
from skyherd.perception.transport import (
    FramePublisher,
    FrameSubscriber,
    encode_frame,
    frame_key,
    open_session,
    publisher_params,
    subscriber_params,
)
from skyherd.runio.constants import COMPANION_COMPONENT
from skyherd.task.params import TaskParams
from skyherd.world.sim import World, WorldParams


class _Level:
    quat = np.array([1.0, 0.0, 0.0, 0.0])

    def __init__(self, alt):
        self.pos_ned = np.array([0.0, 0.0, -alt])


@pytest.fixture
def zenoh_pair():
    pub = open_session(publisher_params(7452))
    sub = open_session(subscriber_params("tcp/127.0.0.1:7452"))
    yield pub, sub
    sub.close()
    pub.close()


def test_the_companion_detects_on_the_bytes_it_received(zenoh_pair):
    """φ(s) in the companion comes from the frame as it came off the wire: a frame whose pixels
    were altered on the way changes φ; a frame damaged on the wire (bad CRC) is dropped and
    leaves φ and the camera's last-good time as they were (plain frames: the CRC covers the
    header, the link's own checksum the pixels; docs/perception.md)."""
    pub_s, sub_s = zenoh_pair
    task = TaskParams()
    pub = FramePublisher(pub_s, "uav9", task.camera, rng=np.random.default_rng(1))
    inbox = FrameInbox(FrameSubscriber(sub_s, "uav9"))
    assert pub.wait_for_subscriber(20.0)
    team = initial_states(np.array([[4.0, 0.0], [-3.0, 3.0], [-3.0, -3.0]]))
    pose = _Level(20.0)
    image = FastRenderer(task.camera, UGVModel()).render(pose, team)
    seen = Perception(task)

    def deliver(t, img):
        pub.publish(t, pose.pos_ned, pose.quat, img)
        frame, status = inbox.frame_at(t, 20.0)
        seen.on_frame(t, frame, status)
        return status

    assert deliver(0.1, image) == "ok"
    clean = seen.phi.copy()
    assert clean[4] == pytest.approx(1.0) and clean[5] == 1.0  # three of three UGVs seen
    altered = image.copy()
    altered[:, image.shape[1] // 2 :] = image[0, 0]  # the right half painted over on the way
    assert deliver(0.2, altered) == "ok"
    assert seen.phi[5] == 0.0 and not np.allclose(seen.phi, clean)
    after_altered = seen.phi.copy()
    bad = bytearray(encode_frame(99, 0.3, pose.pos_ned, pose.quat, image, stream=7))
    bad[40] ^= 0xFF  # a byte of the header's pose flipped: the header CRC no longer matches
    pub_s.declare_publisher(frame_key("uav9")).put(bytes(bad))
    deadline = time.monotonic() + 20.0  # it arrives before the companion asks for tick 0.3 (a
    while inbox.sub.stats.corrupt == 0:  # frame goes out before its mark): still its answer
        assert time.monotonic() < deadline, "the damaged frame did not arrive"
        time.sleep(0.01)
    asked = time.monotonic()
    frame, status = inbox.frame_at(0.3, 20.0)
    assert time.monotonic() - asked < 10.0  # answered, not the patience waited out
    seen.on_frame(0.3, frame, status)
    assert status == "corrupt" and frame is None
    np.testing.assert_array_equal(seen.phi, after_altered)
    assert seen.camera_t == 0.2 and seen.counts == {"ok": 2, "corrupt": 1, "lost": 0}


def test_the_simulation_holds_until_the_companion_closes_each_tick():
    """The world does not step past t_k + L before tick k is closed, however long the companion
    takes; the companion's view is cut exactly at the mark (no telemetry newer than t_k)."""
    from skyherd.hil.link import MavlinkLink

    latency = 0.02
    world = World(
        WorldParams(instance=11, speedup=0, lockstep_params=LockstepParams(latency_s=latency))
    )
    thread = threading.Thread(target=world.run, args=(3.0,), daemon=True)
    link = MavlinkLink.open(
        "udpin:127.0.0.1:14551", source_system=12, source_component=COMPANION_COMPONENT
    )
    v = VehicleLink(link)
    thread.start()
    try:
        held = []
        assert world.clock.t == 0.0
        v.hello(30.0)  # the companion's hello starts the world's clock
        for k in range(12):
            t = v.next_mark(30.0)
            assert t == pytest.approx(0.1 * k)
            assert v.tel.time_boot_ms / 1000.0 <= t + 1e-9  # the cut: nothing after the mark
            if k in (3, 7):
                time.sleep(0.5)  # a slow decision (wall time): the world must wait for it
                held.append(world.clock.t)
            v.close_tick()
        for t_k, t_seen in zip((0.3, 0.7), held):
            assert t_seen == pytest.approx(t_k + latency)
    finally:
        world.stop()
        thread.join(10)
        world.close()
        link.close()
    assert not is_mark(link.mav.timesync_encode(5, 5))


def _udp_pair():
    """A vehicle-side link and a companion-side link joined on loopback (ephemeral ports)."""
    from skyherd.flight.mavlink.link import UdpLink

    vehicle = UdpLink("api", ("127.0.0.1", 0), ("127.0.0.1", 9), 1, 1)
    companion = UdpLink("c", ("127.0.0.1", 0), vehicle.sock.getsockname(), 255, COMPANION_COMPONENT)
    vehicle.remote = companion.sock.getsockname()
    return vehicle, companion


def test_collect_closes_waits_for_every_gate_and_keeps_each_ticks_messages_apart():
    """One wait for a fleet's closes: each gate gets what its companion sent before its own
    close, in order, whatever order the gates' closes arrive in; a stale close is dropped."""
    from skyherd.flight.lockstep import LockstepGate, collect_closes

    pairs = [_udp_pair(), _udp_pair()]
    gates = [LockstepGate(v, v.codec.mav, LockstepParams(resend_s=0.05, timeout_s=30.0))
             for v, _ in pairs]  # fmt: skip
    t_us, t_ns = 100_000, 100_000_000
    try:
        c0, c1 = pairs[0][1], pairs[1][1]
        m = c0.codec.mav
        c1.send(m.heartbeat_encode(6, 8, 0, 0, 4))  # gate 1 closes first
        c1.send(m.timesync_encode(t_ns, t_ns))
        c0.send(m.timesync_encode(1, 0))  # a close of an older tick (a mark answered twice)
        c0.send(m.command_long_encode(1, 1, 400, 0, 1, 0, 0, 0, 0, 0, 0))
        c0.send(m.set_mode_encode(1, 1, 4))
        c0.send(m.timesync_encode(t_ns, t_ns))
        c0.send(m.heartbeat_encode(6, 8, 0, 0, 4))  # after the close: the next tick's
        got = collect_closes([(g, t_us, None) for g in gates], lambda: False)
        assert [[msg.get_type() for msg, _ in b] for b in got] == [
            ["COMMAND_LONG", "SET_MODE"],
            ["HEARTBEAT"],
        ]
        assert gates[0].stats.stale_closes == 1 and gates[1].stats.stale_closes == 0
        assert [g.stats.ticks for g in gates] == [1, 1]
        # the message after gate 0's close is kept for its next tick
        c0.send(m.timesync_encode(2 * t_ns, 2 * t_ns))
        (b,) = collect_closes([(gates[0], 2 * t_us, None)], lambda: False)
        assert [msg.get_type() for msg, _ in b] == ["HEARTBEAT"]
    finally:
        for v, c in pairs:
            v.close()
            c.close()


def test_collect_closes_resends_marks_stops_and_times_out_in_wall_time():
    """Waiting (wall time, with margin): the open gates re-send their marks every resend_s;
    stopped() ends the wait with None; a companion that never closes raises LockstepTimeout."""
    from skyherd.flight.lockstep import LockstepGate, LockstepTimeout, collect_closes, is_mark

    vehicle, companion = _udp_pair()
    gate = LockstepGate(vehicle, vehicle.codec.mav, LockstepParams(resend_s=0.05, timeout_s=0.6))
    waits = []
    try:
        assert collect_closes([(gate, 5000, lambda: waits.append(1))], lambda: True) is None
        with pytest.raises(LockstepTimeout, match="t = 0.005 s"):
            collect_closes([(gate, 5000, lambda: waits.append(1))], lambda: False)
        marks = [msg for msg, _ in companion.receive(1 << 12) if is_mark(msg, 5_000_000)]
        assert len(marks) >= 2 and gate.stats.resends == len(marks) and len(waits) == len(marks)
    finally:
        vehicle.close()
        companion.close()
