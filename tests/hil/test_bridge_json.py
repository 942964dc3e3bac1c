"""ArduPilot JSON backend: skyherd's physics answering ArduPilot's SIM_JSON protocol.

The peer is `hil.bridge_peers.ArduPilotJsonPeer`, a scripted re-telling of ArduPilot's
libraries/SITL/SIM_JSON.cpp that follows the published protocol byte for byte (servo
packet layout, frame_rate ramp, frame_count rules, re-send after 1 s, and the reply parsed
with strstr + sscanf("[%f, %f, %f]") as `parse_sensors` does). Real UDP sockets on
127.0.0.1, instances 75-79 (UDP 9752..9792). The real ArduCopter runs in
tests/e2e/test_bridge_autopilots.py (opt-in).
"""

from __future__ import annotations

import re
import struct
import threading

import numpy as np
import pytest

from skyherd.hil.ardupilot_json import MAGIC_32, ArduPilotJsonBridge, json_port
from skyherd.hil.bridge_peers import ArduPilotJsonPeer, RecvFdm, parse_sensors, scan_vector

SERVO16 = struct.Struct("<HHI16H")
SERVO32 = struct.Struct("<HHI32H")


def feed(bridge: ArduPilotJsonBridge, packet: bytes, now: float = 0.0):
    bridge._rx[: len(packet)] = np.frombuffer(packet, dtype=np.uint8)
    return bridge.handle(len(packet), now)


def servo(fc: int, rate: int = 400, pwm: int = 1000) -> bytes:
    return SERVO16.pack(18458, rate, fc, pwm, pwm, pwm, pwm, *([0] * 12))


def test_reply_is_one_line_arduPilot_parses_exactly():
    b = ArduPilotJsonBridge(instance=75)
    for fc in range(400):  # spin up and leave the ground: non-trivial numbers
        stepped, reply = feed(b, servo(fc, pwm=1800))
        assert stepped
    text = reply.decode()
    assert text.startswith("\n{") and text.endswith("}\n") and text.count("\n") == 2
    assert ": " not in text and ", " not in text  # sscanf needs '[' right after "key":
    assert re.search(r'"timestamp":\d+\.\d{9},', text)
    keys = re.findall(r'"([a-z_]+)":', text)
    assert keys == ["timestamp", "imu", "gyro", "accel_body", "position", "quaternion", "velocity"]
    got = parse_sensors(text.strip("\n"))
    assert got is not None and set(got) == {
        "timestamp",
        "gyro",
        "accel_body",
        "position",
        "quaternion",
        "velocity",
    }
    s = b.state
    assert got["timestamp"] == pytest.approx(s.t, abs=1e-9)
    np.testing.assert_allclose(got["position"], s.pos_ned, atol=1e-6)
    np.testing.assert_allclose(got["velocity"], s.vel_ned, rtol=1e-6, atol=1e-6)
    np.testing.assert_allclose(got["quaternion"], s.quat, atol=1e-7)
    np.testing.assert_allclose(got["gyro"], s.omega_frd, atol=1e-6)
    np.testing.assert_allclose(got["accel_body"], s.accel_frd, rtol=1e-6, atol=1e-6)
    assert s.pos_ned[2] < -0.05  # it flew


def test_arduPilot_reader_rejects_what_it_would_reject():
    # a space after ':' makes sscanf miss the '['; a line without the leading '\n' is not read
    assert scan_vector(" [1, 2, 3]", 3, True) is None
    assert scan_vector("[1,2,3]", 3, True) == [1.0, 2.0, 3.0]
    assert scan_vector("[1 ,2,3]", 3, True) is None  # ',' must follow the number at once
    r = RecvFdm()
    assert r.feed(b'{"timestamp":1.0}\n') is None  # only one NUL: no complete line yet
    bad = '{"timestamp":1.0,"imu":{"gyro": [0,0,0],"accel_body":[0,0,-9.8]},"position":[0,0,0],"quaternion":[1,0,0,0],"velocity":[0,0,0]}'
    assert "gyro" not in (parse_sensors(bad) or {})


def test_ground_contact_shows_in_accel_body():
    b = ArduPilotJsonBridge(instance=75)
    _, reply = feed(b, servo(0, pwm=1000))
    got = parse_sensors(reply.decode().strip("\n"))
    assert got["accel_body"] == pytest.approx([0.0, 0.0, -9.80665], abs=1e-5)
    assert got["position"] == [0.0, 0.0, 0.0]  # ground at down = 0 = home


def test_each_packet_steps_by_its_own_frame_rate():
    b = ArduPilotJsonBridge(instance=75)
    rates = list(range(300, 420))
    for fc, r in enumerate(rates):
        assert feed(b, servo(fc, rate=r))[0]
    assert b.t == pytest.approx(sum(1.0 / r for r in rates), abs=1e-12)
    assert b.stats.frames == len(rates)


def test_duplicate_does_not_step_and_resends_only_when_old():
    b = ArduPilotJsonBridge(instance=75)
    stepped, first = feed(b, servo(0, pwm=1700), now=10.0)
    assert stepped
    t = b.t
    assert feed(b, servo(0, pwm=1700), now=10.2) == (False, None)  # too young: silent
    assert feed(b, servo(0, pwm=1700), now=10.6) == (False, first)  # lost reply: re-sent
    assert feed(b, servo(0, pwm=1700), now=10.7) == (False, None)
    assert b.t == t and b.stats.duplicates == 3 and b.stats.resends == 1
    assert feed(b, servo(1, pwm=1700), now=10.8)[0] and b.t > t


def test_frame_count_going_back_resets_the_physics():
    b = ArduPilotJsonBridge(instance=75)
    for fc in range(800):
        feed(b, servo(fc, pwm=1900))
    assert b.state.pos_ned[2] < -1.0
    stepped, reply = feed(b, servo(0, pwm=1000))  # ArduPilot restarted
    assert stepped and b.stats.restarts == 1
    assert b.t == pytest.approx(1 / 400) and b.state.pos_ned[2] == 0.0
    assert parse_sensors(reply.decode().strip("\n"))["timestamp"] == pytest.approx(1 / 400)


def test_bad_packets_are_counted_not_stepped():
    b = ArduPilotJsonBridge(instance=75)
    for pkt in (b"\x00" * 3, servo(0)[:-2], struct.pack("<HHI16H", 1234, 400, 0, *([0] * 16))):
        assert feed(b, pkt) == (False, None)
    assert feed(b, SERVO16.pack(18458, 0, 0, *([1500] * 16))) == (False, None)  # rate 0
    assert b.stats.bad_packets == 4 and b.t == 0.0
    assert feed(b, SERVO32.pack(MAGIC_32, 400, 0, *([1000] * 32)))[0]  # 32 channels


def test_fixedwing_servo_functions_move_the_jsbsim_plane():
    b = ArduPilotJsonBridge(airframe="fixedwing", instance=75)
    pwm = [1500, 1500, 2000, 1500] + [0] * 12  # full throttle, surfaces centred
    for fc in range(1200):  # 3 s at 400 Hz
        stepped, reply = feed(b, SERVO16.pack(18458, 400, fc, *pwm))
    text = reply.decode()
    assert '"airspeed":' in text and parse_sensors(text.strip("\n"))["airspeed"] > 3.0
    assert b.state.vel_ned[0] > 3.0  # rolled forward along the runway (heading north)
    pwm[0] = 1900  # right aileron at speed: roll rate to the right
    for fc in range(1200, 1300):
        feed(b, SERVO16.pack(18458, 400, fc, *pwm))
    assert b.state.omega_frd[0] > 0.0


def _fly(port: int, frames: int, speedup: float, pause_at: int | None = None) -> list[dict]:
    peer = ArduPilotJsonPeer(port, speedup=speedup)
    try:
        if pause_at is None:
            return peer.run(frames)
        peer.run(pause_at)
        threading.Event().wait(0.3)  # a pause: nothing may move while nobody asks
        return peer.run(frames - pause_at)
    finally:
        peer.close()


def _serve(bridge: ArduPilotJsonBridge, frames: int) -> threading.Thread:
    th = threading.Thread(target=bridge.serve, kwargs={"max_frames": frames, "idle_timeout_s": 20})
    th.start()
    return th


def test_real_sockets_hover_and_bit_identical_at_1x_and_unpaced():
    runs = []
    for instance, speedup, pause in ((76, 0.0, None), (77, 1.0, None), (78, 0.0, 500)):
        frames = 1200 if speedup == 0 else 800  # 1× run: 2 s of wall time
        with ArduPilotJsonBridge(instance=instance) as b:
            assert b.port == json_port(instance)
            th = _serve(b, frames)
            got = _fly(b.port, frames, speedup, pause)
            th.join(30)
        assert b.stats.frames == frames and b.stats.duplicates == 0
        runs.append(got)
    n = len(runs[1])
    assert runs[0][:n] == runs[1] and runs[0] == runs[2]  # bit for bit
    alt = -runs[0][-1]["position"][2]
    assert 0.5 < alt < 4.0  # the peer's altitude hold took it up towards 3 m


def test_lost_reply_is_resent_once_without_a_step_walltime():
    with ArduPilotJsonBridge(instance=79) as b:
        peer = ArduPilotJsonPeer(b.port)
        try:
            peer.sock.sendto(peer.packet([1000] * 16), ("127.0.0.1", b.port))
            assert b.step_once(5.0)
            peer.sock.settimeout(5.0)
            peer.sock.recv(65000)  # the reply is "lost": the peer drops it
            th = threading.Thread(target=b.serve, kwargs={"max_frames": 2, "idle_timeout_s": 5})
            th.start()
            got = peer.exchange(peer.packet([1000] * 16))  # same frame_count: re-sent after 1 s
            peer.frame_count += 1
            nxt = peer.exchange(peer.packet([1000] * 16))  # and lockstep goes on
            th.join(10)
        finally:
            peer.close()
    assert got is not None and got["timestamp"] == pytest.approx(1 / 300)
    assert b.stats.frames == 2 and b.stats.resends == 1
    assert nxt["timestamp"] == pytest.approx(2 / 300)


def test_make_bridge_gives_both_bridges_one_api():
    from skyherd.hil.bridge_select import make_bridge
    from skyherd.hil.px4_sim import Px4SimBridge

    for autopilot, port in (("px4", 4560 + 75), ("ardupilot", 9002 + 750)):
        b = make_bridge(autopilot, instance=75, seed=3).open_port()
        try:
            assert b.port == port and b.t == 0.0 and b.state.on_ground
        finally:
            b.close()
    assert isinstance(make_bridge("px4"), Px4SimBridge)
    assert make_bridge("ardupilot", airframe="fixedwing").airframe == "fixedwing"
    with pytest.raises(ValueError):
        make_bridge("inav")


def test_no_packet_no_step():
    with ArduPilotJsonBridge(instance=79) as b:
        assert not b.step_once(0.05)
        assert b.t == 0.0 and b.stats.frames == 0


def test_a_restarted_autopilot_on_another_port_is_answered_after_a_gap():
    """The bridge's socket is connected to the autopilot after its first answer (no address per
    frame). When that autopilot vanishes (its port closed: the answer is refused) or the wait
    runs out, the socket is disconnected again, and an ArduPilot restarted from another port
    (its frame_count from 0) is heard, answered, and resets the physics."""
    with ArduPilotJsonBridge(instance=79) as b:
        first, second = ArduPilotJsonPeer(b.port), ArduPilotJsonPeer(b.port)
        try:
            for k in range(4):
                first.sock.sendto(first.packet([1000] * 16), ("127.0.0.1", b.port))
                if k == 3:
                    first.close()  # gone before its answer arrives
                assert b.step_once(5.0)
                if k < 3:
                    first.sock.recv(65000)
                first.frame_count += 1
            second.sock.sendto(second.packet([1000] * 16), ("127.0.0.1", b.port))
            assert not b.step_once(0.2)  # refused / not its sender: nothing steps
            th = threading.Thread(target=b.step_once, args=(5.0,))
            th.start()
            got = second.exchange(second.packet([1000] * 16))  # ArduPilot re-sends after 1 s
            th.join(10)
            assert got is not None and got["timestamp"] == pytest.approx(1 / 300)
            assert b.stats.restarts == 1 and b.stats.frames == 5
        finally:
            first.close()
            second.close()
