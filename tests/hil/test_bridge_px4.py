"""PX4 simulator interface: skyherd's physics answering PX4's simulator_mavlink over TCP.

The peer is `hil.bridge_peers.Px4SimPeer`, a scripted stand-in for PX4's simulator_mavlink
that follows the published protocol byte for byte: it connects to TCP 4560+N, and every
frame is encoded / decoded by pymavlink (MAVLink 2, common dialect); it answers each
HIL_SENSOR with one HIL_ACTUATOR_CONTROLS stamped with that sensor's time_usec, as PX4's
lockstep does. Real TCP on 127.0.0.1, instances 75-79. The real PX4 runs in
tests/e2e/test_bridge_autopilots.py (opt-in).
"""

from __future__ import annotations

import dataclasses
import math
import threading

import numpy as np
import pytest
from pymavlink.dialects.v20 import common as mavlink

from skyherd.flight.frames import quat_to_dcm
from skyherd.flight.geo import DEFAULT_HOME, ned_to_geodetic
from skyherd.hil import bridge_mavlink as wire
from skyherd.hil.bridge_peers import Px4SimPeer
from skyherd.hil.bridge_sensors import MagField, SensorNoise, isa_pressure_pa
from skyherd.hil.px4_sim import Px4BridgeConfig, Px4SimBridge, px4_sim_port

QUIET = Px4BridgeConfig(noise=SensorNoise(0, 0, 0, 0, 0, 0), boot_wait_s=10.0)


def connected(instance: int, config=QUIET, speedup=0.0) -> tuple[Px4SimBridge, Px4SimPeer]:
    b = Px4SimBridge(instance=instance, config=config, speedup=speedup).listen()
    peer = Px4SimPeer(b.port)
    th = threading.Thread(target=peer.connect)
    th.start()
    assert b.accept(10.0)
    th.join(10)
    return b, peer


def run_both(b: Px4SimBridge, peer: Px4SimPeer, steps: int) -> list[np.ndarray]:
    """Peer answers `steps` sensors in a thread; the bridge steps; returns the positions."""
    th = threading.Thread(target=peer.run, args=(steps,))
    th.start()
    traj = []
    for _ in range(steps):
        assert b.step_once()
        traj.append(np.concatenate([b.body.out, b.body.model.x[13:]]))
    th.join(20)
    return traj


def test_frames_decode_with_pymavlink_and_carry_the_truth():
    b, peer = connected(75)
    try:
        run_both(b, peer, 400)  # 1.6 s: spun up and climbing
        th = threading.Thread(target=peer.run, args=(1,), kwargs={"answer": False})
        th.start()
        s = b.state  # the state the next frame reports
        b.step_once(timeout_s=0.0)  # sends the frame, no answer: no step
        th.join(10)
    finally:
        b.close()
        peer.close()
    m = peer.sensors[-1]
    assert m.time_usec == 400 * 4000 + QUIET.time_offset_us and m.id == 0
    np.testing.assert_allclose([m.xacc, m.yacc, m.zacc], s.accel_frd, rtol=1e-6, atol=1e-6)
    np.testing.assert_allclose([m.xgyro, m.ygyro, m.zgyro], s.omega_frd, rtol=1e-6, atol=1e-6)
    mag_b = quat_to_dcm(s.quat).T @ np.array(MagField.wmm(DEFAULT_HOME).ned_gauss)
    np.testing.assert_allclose([m.xmag, m.ymag, m.zmag], mag_b, atol=1e-6)  # frame 400: mag due
    alt = DEFAULT_HOME.alt_m - s.pos_ned[2]
    assert m.abs_pressure == pytest.approx(isa_pressure_pa(alt) / 100.0, rel=1e-6)
    assert m.pressure_alt == pytest.approx(alt, abs=1e-3)
    assert (
        m.fields_updated
        == wire.FIELDS_ACCEL | wire.FIELDS_GYRO | wire.FIELDS_MAG | wire.FIELDS_BARO
    )
    assert s.pos_ned[2] < -0.3  # the peer's altitude hold lifted it
    g = peer.gps[-1]
    lat, lon, alt_gps = ned_to_geodetic(DEFAULT_HOME, s.pos_ned)
    assert (g.lat, g.lon, g.alt) == (round(lat * 1e7), round(lon * 1e7), round(alt_gps * 1000))
    assert g.fix_type == 3 and g.vd == round(s.vel_ned[2] * 100)
    q = peer.truth[-1]
    np.testing.assert_allclose(q.attitude_quaternion, s.quat, atol=1e-7)
    # the field schedule: mag every 2nd frame, baro every 5th
    flags = [x.fields_updated for x in peer.sensors[:10]]
    assert [bool(f & wire.FIELDS_MAG) for f in flags] == [k % 2 == 0 for k in range(10)]
    assert [bool(f & wire.FIELDS_BARO) for f in flags] == [k % 5 == 0 for k in range(10)]
    assert b.truth_interval_us == 5000  # the peer asked for HIL_STATE_QUATERNION at 200 Hz
    # ... and gets it at the bridge's cap, 50 Hz (every 5th of the 250 Hz frames)
    assert 400 // 5 <= len(peer.truth) <= 400 // 5 + 1


def test_no_step_without_an_answer_and_stale_answers_ignored():
    b, peer = connected(76)
    try:
        run_both(b, peer, 10)
        assert b.in_lockstep and b.t == pytest.approx(0.04)
        th = threading.Thread(target=peer.run, args=(1,), kwargs={"answer": False})
        th.start()
        assert not b.step_once(timeout_s=0.2)  # frame sent, PX4 silent: time stands
        th.join(10)
        assert b.t == pytest.approx(0.04) and b.stats.frames == 10
        # an answer for an older frame does not count
        old = peer.mav.hil_actuator_controls_encode(1_036_000, [1.0] * 16, 129, 1).pack(peer.mav)
        peer.sock.sendall(old)
        assert not b.step_once(timeout_s=0.2)
        ok = peer.mav.hil_actuator_controls_encode(1_040_000, [0.5] * 16, 129, 1).pack(peer.mav)
        peer.sock.sendall(ok)
        assert b.step_once(timeout_s=5.0)
        assert b.stats.stale_answers == 1 and b._controls == [0.5] * 4 and b.px4_armed
        assert peer.sensors[-1].time_usec == 1_040_000  # the frame was sent once, not again
    finally:
        b.close()
        peer.close()


def test_boot_frames_step_with_motors_off_until_px4_answers():
    cfg = Px4BridgeConfig(boot_wait_s=0.001)
    b, peer = connected(77, config=cfg)
    try:
        th = threading.Thread(target=peer.run, args=(5,), kwargs={"answer": False})
        th.start()
        for _ in range(5):
            assert b.step_once()
        th.join(10)
        assert not b.in_lockstep and b.stats.unanswered_boot == 5 and b.state.on_ground
        b.config = dataclasses.replace(cfg, boot_wait_s=10.0)  # answers now always in time
        run_both(b, peer, 3)
        assert b.in_lockstep and b.stats.answered == 3
    finally:
        b.close()
        peer.close()


def test_bit_identical_at_1x_and_as_fast_as_possible():
    trajs = []
    for instance, speedup in ((78, 0.0), (79, 1.0)):
        b, peer = connected(instance, config=Px4BridgeConfig(boot_wait_s=10.0), speedup=speedup)
        try:
            trajs.append(run_both(b, peer, 250))  # 1 s of simulated flight, noise on
        finally:
            b.close()
            peer.close()
    assert len(trajs[0]) == len(trajs[1]) == 250
    for a, c in zip(*trajs):
        assert np.array_equal(a, c)
    assert trajs[0][-1][8] < -0.05  # climbing: the comparison is not of a vehicle at rest


def test_frame_parser_survives_garbage_splits_bad_crc_and_v1():
    mav = mavlink.MAVLink(None, srcSystem=1, srcComponent=1)
    act = mav.hil_actuator_controls_encode(123, [0.25] * 16, 129, 1).pack(mav)
    hb = mav.heartbeat_encode(2, 12, 0, 0, 0).pack(mav)
    bad = bytearray(act)
    bad[20] ^= 0xFF
    mav1 = mavlink.MAVLink(None, srcSystem=1, srcComponent=1)
    mav1.WIRE_PROTOCOL_VERSION = "1.0"
    v1 = mav1.hil_actuator_controls_encode(456, [0.5] * 16, 1, 1).pack(mav1, force_mavlink1=True)
    stream = b"\x00garbage" + bytes(bad) + act + hb + v1
    p = wire.FrameParser()
    frames = []
    for i in range(0, len(stream), 7):  # frames split over reads
        frames += p.feed(stream[i : i + 7])
    ids = [f.msgid for f in frames]
    assert ids == [wire.HIL_ACT_ID, wire.HEARTBEAT_ID, wire.HIL_ACT_ID]
    t0, t1 = (wire.HIL_ACT.unpack(f.payload)[0] for f in (frames[0], frames[2]))
    assert (t0, t1) == (123, 456) and p.dropped > 0
    assert p.feed(b"\xfe" * 70000) == [] and len(p._buf) < 70000


def test_built_frames_are_valid_mavlink2():
    f = wire.Framer()
    payload = wire.HIL_SENSOR.pack(7, *([0.0] * 13), 0, 0)  # trailing zeros truncated
    frame = f.frame(wire.HIL_SENSOR_ID, wire.HIL_SENSOR_CRC, payload)
    assert frame[1] == 1  # only time_usec's low byte survives truncation
    m = mavlink.MAVLink(None).parse_buffer(frame)[0]
    assert m.get_type() == "HIL_SENSOR" and m.time_usec == 7 and math.isclose(m.zacc, 0.0)


def test_bad_settings_and_ports_are_refused():
    with pytest.raises(ValueError):
        Px4BridgeConfig(rate_hz=200)
    with pytest.raises(ValueError):
        px4_sim_port(70000)
    with pytest.raises(ValueError):
        Px4SimBridge(airframe="fixedwing")
    a = Px4SimBridge(instance=75).listen()
    try:
        with pytest.raises(OSError, match="pick another --instance"):
            Px4SimBridge(instance=75).listen()
    finally:
        a.close()
    with pytest.raises(ConnectionError):
        Px4SimBridge(instance=75).step_once()
