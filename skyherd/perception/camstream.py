"""A stand-alone frame source: UGVs on a route, a UAV hovering over them, frames on Zenoh.

`python -m skyherd.perception.camstream --frames 200 --rate 30` publishes what the UAV's camera sees
(fast renderer, kinematic ground world) on `skyherd/<vehicle>/camera/frame`, and the UGVs'
states on `skyherd/ugv/<id>/state`, so that
`skyherd watch`, the Zenoh tests and the benchmark have a real second process to talk to.
The UAV trails the group's centre with a 3 s first-order lag at 25–35 m (so the group drifts
in the image and sometimes leaves it); simulation time advances --sim-dt per frame.
"""

from __future__ import annotations

import argparse
import sys
import time

import numpy as np

from skyherd.flight.frames import euler_to_quat
from skyherd.groundsim.behaviours import DriveParams, make_behaviour, triangle_offsets
from skyherd.groundsim.kinematic import KinematicWorld
from skyherd.groundsim.transport import UGVStatePublisher
from skyherd.groundsim.ugv import UGVModel, initial_states
from skyherd.perception.camera import CameraParams, UAVPose
from skyherd.perception.render_fast import FastRenderer
from skyherd.perception.transport import FramePublisher, ZenohParams, open_session, publisher_params


def parse(argv: list[str] | None) -> argparse.Namespace:
    ap = argparse.ArgumentParser(prog="python -m skyherd.perception.camstream", description=__doc__)
    ap.add_argument("--vehicle", default="uav0")
    ap.add_argument("--port", type=int, default=7447, help="listen on tcp/127.0.0.1:PORT")
    ap.add_argument("--config", default=None, help="Zenoh JSON5 config file (replaces --port)")
    ap.add_argument("--frames", type=int, default=300, help="frames to send (0 = forever)")
    ap.add_argument("--rate", type=float, default=30.0, help="frames per second (0 = max)")
    ap.add_argument("--sim-dt", type=float, default=0.1, help="simulation time per frame [s]")
    ap.add_argument("--size", default="320x240", help="image WxH")
    ap.add_argument("--encoding", choices=("raw", "jpeg"), default="raw")
    ap.add_argument("--behaviour", default="route")
    ap.add_argument(
        "--wait-s", type=float, default=5.0, help="wait up to this long for a subscriber [s]"
    )
    ap.add_argument("--static", action="store_true", help="send one pre-rendered frame (bench)")
    ap.add_argument("--seed", type=int, default=0)
    return ap.parse_args(argv)


def main(argv: list[str] | None = None) -> int:
    a = parse(argv)
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
    dt = a.sim_dt
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
            if a.rate > 0:
                next_wall += 1.0 / a.rate
                time.sleep(max(0.0, next_wall - time.monotonic()))
    except KeyboardInterrupt:
        pass
    finally:
        time.sleep(0.2)  # let the last frames leave before the session closes
        pub.close()
        ugv_pub.close()
        session.close()
    print(f"camstream: sent {k} frames", file=sys.stderr)
    return 0


if __name__ == "__main__":
    sys.exit(main())
