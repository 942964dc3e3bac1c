"""A stand-alone frame source: UGVs on a route, a UAV hovering over them, frames on Zenoh.

`stream(CamstreamParams(frames=200, rate_hz=30))` (`skyherd camstream --frames 200 --rate 30`)
publishes what the UAV's camera sees (fast renderer, kinematic ground world) on `skyherd/<vehicle>/camera/frame`, and the UGVs'
states on `skyherd/ugv/<id>/state`, so that
`skyherd watch`, the Zenoh tests and the benchmark have a real second process to talk to.
The UAV trails the group's centre with a 3 s first-order lag at 25–35 m (so the group drifts
in the image and sometimes leaves it); simulation time advances `sim_dt_s` per frame.
"""

from __future__ import annotations

import time
from dataclasses import dataclass

import numpy as np

from skyherd.flight.frames import euler_to_quat
from skyherd.groundsim.behaviours import DriveParams, make_behaviour, triangle_offsets
from skyherd.groundsim.kinematic import KinematicWorld
from skyherd.groundsim.transport import UGVStatePublisher
from skyherd.groundsim.ugv import UGVModel, initial_states
from skyherd.perception.camera import CameraParams, UAVPose
from skyherd.perception.render_fast import FastRenderer
from skyherd.perception.transport import FramePublisher, ZenohParams, open_session, publisher_params
from skyherd.runio.constants import ZENOH_BASE


@dataclass(frozen=True)
class CamstreamParams:
    """What the frame source sends, and where."""

    vehicle: str = "uav0"  # the vehicle's name in the key expressions
    port: int = ZENOH_BASE  # listen on tcp/127.0.0.1:PORT
    config: str | None = None  # a Zenoh JSON5 configuration file instead of `port`
    frames: int = 300  # frames to send (0: until interrupted)
    rate_hz: float = 30.0  # frames per wall second (0: as fast as possible)
    sim_dt_s: float = 0.1  # simulation time per frame [s]
    size: str = "320x240"  # image WxH [px]
    encoding: str = "raw"  # raw | jpeg
    behaviour: str = "route"  # the UGVs' groundsim behaviour
    wait_s: float = 5.0  # wait up to this long for a subscriber [wall s]
    static: bool = False  # send one pre-rendered frame again and again (the benchmark)
    seed: int = 0


def stream(a: CamstreamParams) -> int:
    """Publish `a.frames` frames (and the UGVs' states); returns how many were sent."""
    w, h = (int(x) for x in a.size.lower().split("x"))
    cam = CameraParams(width_px=w, height_px=h)
    zp = ZenohParams(config_file=a.config) if a.config else publisher_params(a.port)
    session = open_session(zp)
    pub = FramePublisher(session, a.vehicle, cam, a.encoding, rng=np.random.default_rng(a.seed))
    ugv_pub = UGVStatePublisher(session, 3)
    rng = np.random.default_rng(a.seed)
    drive = DriveParams()
    world = KinematicWorld(
        initial_states(triangle_offsets(3)), make_behaviour(a.behaviour, 3, rng, drive), drive
    )
    renderer = FastRenderer(cam, UGVModel())
    uav = UAVPose(np.array([0.0, 0.0, -30.0]), euler_to_quat(0.0, 0.0, 0.0))
    if pub.wait_for_subscriber(a.wait_s):
        time.sleep(0.05)  # the route is known on both ends; let the link settle
    dt = a.sim_dt_s
    t, k, next_wall = 0.0, 0, time.monotonic()
    image = renderer.render(uav, world.states)
    try:
        while a.frames == 0 or k < a.frames:
            if not a.static:
                states = world.step(t, dt)
                centre = states.pos_ne.mean(axis=0)
                ne = uav.pos_ned[:2] + (centre - uav.pos_ned[:2]) * min(dt / 3.0, 1.0)
                alt = 30.0 + 5.0 * np.sin(0.2 * t)
                uav = UAVPose(np.array([ne[0], ne[1], -alt]), uav.quat)
                image = renderer.render(uav, states)
            pub.publish(t, uav.pos_ned, uav.quat, image)
            ugv_pub.publish(t, world.states)
            t += dt
            k += 1
            if a.rate_hz > 0:
                next_wall += 1.0 / a.rate_hz
                time.sleep(max(0.0, next_wall - time.monotonic()))
    except KeyboardInterrupt:
        pass
    finally:
        time.sleep(0.2)  # let the last frames leave before the session closes
        pub.close()
        ugv_pub.close()
        session.close()
    return k
