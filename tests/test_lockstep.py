"""The companion as a separate program: frames over Zenoh are what it detects on, and the
simulator holds at each camera frame until the companion has closed the tick (lockstep)."""

import threading
import time

import numpy as np
import pytest

from flight.lockstep import LockstepParams, is_mark
from groundsim.ugv import UGVModel, initial_states
from mission.companion import FrameInbox
from mission.perception import Perception
from mission.vehicle import COMPANION_COMPONENT, VehicleLink
from perception.render_fast import FastRenderer
from perception.transport import (
    FramePublisher,
    FrameSubscriber,
    encode_frame,
    frame_key,
    open_session,
    publisher_params,
    subscriber_params,
)
from policy.groundair.params import TaskParams
from world.sim import World, WorldParams


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
    leaves φ and the camera's last-good time as they were."""
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
    bad[-10] ^= 0xFF  # one pixel byte flipped: the CRC no longer matches
    pub_s.declare_publisher(frame_key("uav9")).put(bytes(bad))
    frame, status = inbox.frame_at(0.3, 20.0)
    seen.on_frame(0.3, frame, status)
    assert status == "corrupt" and frame is None
    np.testing.assert_array_equal(seen.phi, after_altered)
    assert seen.camera_t == 0.2 and seen.counts == {"ok": 2, "corrupt": 1, "lost": 0}


def test_the_simulation_holds_until_the_companion_closes_each_tick():
    """The world does not step past t_k + L before tick k is closed, however long the companion
    takes; the companion's view is cut exactly at the mark (no telemetry newer than t_k)."""
    from hil.link import MavlinkLink

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
