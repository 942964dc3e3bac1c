"""Bad input never crashes the vehicle and never changes its state.

Part 1: valid frames carrying NaN, infinite or out-of-range values are refused (COMMAND_ACK
DENIED / UNSUPPORTED, the old PARAM_VALUE, a MISSION_ACK error) or dropped (setpoints).
Part 2: a fuzz run of 12,000 malformed frames (random bytes, truncated frames, bad CRC, wrong
target ids, unknown message ids, broken headers, MAVLink 1 junk) over the real socket; then
the vehicle still answers and its state, parameters, mission, fence and stream rates are
exactly what they were.
"""

from __future__ import annotations

import math
import socket
import time

import numpy as np
import pytest
from mavlink_support import Client, running_sitl
from pymavlink.dialects.v20 import ardupilotmega as M

from skyherd.flight.autopilot_api import FlightMode, MissionCommand

INSTANCE = 12  # (instance 10's API port would be 14550, where every GCS link sends)
SYS = 1 + INSTANCE


def snapshot(sitl) -> dict:
    ap, ep = sitl.autopilot, sitl.endpoint
    return {
        "armed": ap.armed,
        "mode": ap.mode,
        "pos": np.round(ap.state.pos_ned, 6).tolist(),
        "params": {n: ap.get_param(n) for n in ap.param_names()},
        "mission": list(ep.missions.lists[0]),
        "fence": list(ep.missions.lists[1]),
        "ap_items": len(ap._items),
        "rates": {k: dict(v.rates) for k, v in ep.streams.items()},
    }


def _setup_mission_and_fence(c: Client) -> None:
    rel = M.MAV_FRAME_GLOBAL_RELATIVE_ALT_INT
    lat, lon = int(-35.363261e7), int(149.165230e7)
    mission = [(rel, MissionCommand.TAKEOFF, 0, 0, 0, math.nan, 0, 0, 5.0),
               (rel, MissionCommand.WAYPOINT, 0, 0, 0, math.nan, lat + 900, lon, 5.0),
               (rel, MissionCommand.LAND, 0, 0, 0, math.nan, lat + 900, lon, 0.0)]  # fmt: skip
    assert c.mission_upload(mission).type == M.MAV_MISSION_ACCEPTED
    fence = [(M.MAV_FRAME_GLOBAL, 5003, 80.0, 0, 0, 0, lat, lon, 0.0)]
    assert c.mission_upload(fence, mission_type=1).type == M.MAV_MISSION_ACCEPTED


def test_out_of_range_and_nan_values_are_refused_without_state_change():
    with running_sitl(instance=INSTANCE, speedup=5.0) as sitl, Client(INSTANCE) as c:
        c.wait_heartbeat()
        _setup_mission_and_fence(c)
        before = snapshot(sitl)
        nan, inf = math.nan, math.inf
        D, U = M.MAV_RESULT_DENIED, M.MAV_RESULT_UNSUPPORTED
        cases = [
            (M.MAV_CMD_COMPONENT_ARM_DISARM, (nan,), D),
            (M.MAV_CMD_COMPONENT_ARM_DISARM, (1.0, 123.0), D),
            (M.MAV_CMD_COMPONENT_ARM_DISARM, (inf,), D),
            (M.MAV_CMD_NAV_TAKEOFF, (0, 0, 0, 0, 0, 0, inf), D),
            (M.MAV_CMD_NAV_TAKEOFF, (0, 0, 0, 0, 0, 0, 584.0 - 10), D),  # below home
            (M.MAV_CMD_DO_SET_MODE, (nan, 4, 3), D),
            (M.MAV_CMD_DO_SET_MODE, (1, 1e9, 0), D),
            (M.MAV_CMD_DO_SET_MODE, (1, 4, nan), D),
            (M.MAV_CMD_DO_REPOSITION, (-1, 1, 0, 0, 1000.0, 149.0, 600.0), D),
            (M.MAV_CMD_DO_REPOSITION, (-1, 1, 0, inf, -35.36, 149.16, 600.0), D),
            (M.MAV_CMD_SET_MESSAGE_INTERVAL, (nan, 1000), D),
            (M.MAV_CMD_SET_MESSAGE_INTERVAL, (M.MAVLINK_MSG_ID_ATTITUDE, -5), D),
            (M.MAV_CMD_SET_MESSAGE_INTERVAL, (M.MAVLINK_MSG_ID_ATTITUDE, nan), D),
            (M.MAV_CMD_REQUEST_MESSAGE, (-1,), D),
            (M.MAV_CMD_REQUEST_MESSAGE, (1e12,), D),
            (M.MAV_CMD_DO_SET_MISSION_CURRENT, (17,), D),
            (M.MAV_CMD_DO_SET_MISSION_CURRENT, (nan,), D),
            (M.MAV_CMD_MISSION_START, (99, 0), D),
            (31000, (1, 2, 3), U),
            (M.MAV_CMD_DO_FLIGHTTERMINATION, (1,), U),
        ]
        for cmd, params, expected in cases:
            ack = c.command(cmd, *params)
            assert ack is not None and ack.result == expected, (cmd, params)
        # COMMAND_INT with a latitude out of range.
        ack = c.command_int(
            M.MAV_CMD_DO_REPOSITION, M.MAV_FRAME_GLOBAL_INT, -1, 1, 0, 0, int(95e7), 0, 600.0
        )
        assert ack.result == D
        # Parameters: NaN, infinite, out of range → the unchanged value comes back.
        for v in (nan, inf, -inf, 1e30, -3.0):
            assert c.param_set("MPC_XY_CRUISE", v).param_value == pytest.approx(5.0)
        # Setpoints and sticks: dropped (no answer exists), counted.
        mask_vel = 0b0000_1111_1100_0111
        for vx in (nan, inf, 1e6):
            c.mav.set_position_target_local_ned_send(
                0, SYS, 1, M.MAV_FRAME_LOCAL_NED, mask_vel, 0, 0, 0, vx, 0, 0, 0, 0, 0, 0, 0
            )
        c.mav.set_position_target_local_ned_send(
            0, SYS, 1, M.MAV_FRAME_LOCAL_NED, 0b0000_1111_1111_1110, 5, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0
        )
        c.mav.set_position_target_local_ned_send(
            0, SYS, 1, M.MAV_FRAME_BODY_FRD, mask_vel, 0, 0, 0, 1, 0, 0, 0, 0, 0, 0, 0
        )
        c.mav.set_position_target_global_int_send(
            0,
            SYS,
            1,
            M.MAV_FRAME_GLOBAL_INT,
            0b0000_1111_1111_1000,
            int(91e7),
            0,
            nan,
            0,
            0,
            0,
            0,
            0,
            0,
            0,
            0,
        )
        c.mav.manual_control_send(SYS, 5000, 0, 500, 0, 0)
        c.mav.manual_control_send(SYS, 0, 0, -20, 0, 0)
        # Missions: too many items, an unknown type, an item out of range.
        c.mav.mission_count_send(SYS, 1, 60000, 0)
        assert c.recv("MISSION_ACK").type == M.MAV_MISSION_NO_SPACE
        c.mav.mission_count_send(SYS, 1, 3, 7)
        assert c.recv("MISSION_ACK").type == M.MAV_MISSION_UNSUPPORTED
        bad = [(M.MAV_FRAME_GLOBAL_RELATIVE_ALT_INT, 16, 0, 0, 0, nan, int(99e7), 0, 5.0)]
        assert c.mission_upload(bad).type == M.MAV_MISSION_INVALID_PARAM5_X
        bad = [(M.MAV_FRAME_GLOBAL_RELATIVE_ALT_INT, 16, 0, 0, 0, nan, 0, 0, nan)]
        assert c.mission_upload(bad).type == M.MAV_MISSION_INVALID_PARAM7
        time.sleep(0.3)
        ep = sitl.endpoint
        assert ep.stats["setpoint_dropped"] == 6 and ep.stats["manual_dropped"] == 2
        assert ep.stats["rx_handler_error"] == 0
        assert snapshot(sitl) == before


def _valid_frames(mav) -> list[bytes]:
    """Valid frames of many kinds, addressed to our vehicle (the fuzz corrupts them)."""
    msgs = [
        mav.command_long_encode(SYS, 1, M.MAV_CMD_COMPONENT_ARM_DISARM, 0, 1, 0, 0, 0, 0, 0, 0),
        mav.command_long_encode(SYS, 1, M.MAV_CMD_NAV_TAKEOFF, 0, 0, 0, 0, 0, 0, 0, 600),
        mav.command_int_encode(SYS, 1, 6, M.MAV_CMD_DO_REPOSITION, 0, 0, -1, 1, 0, 0, 1, 2, 3),
        mav.param_set_encode(SYS, 1, b"MPC_XY_CRUISE", 9.0, M.MAV_PARAM_TYPE_REAL32),
        mav.mission_count_encode(SYS, 1, 2, 0),
        mav.mission_clear_all_encode(SYS, 1, 0),
        mav.mission_item_int_encode(SYS, 1, 0, 6, 16, 0, 1, 0, 0, 0, 0, 1, 2, 3.0, 0),
        mav.set_position_target_local_ned_encode(
            0, SYS, 1, 1, 0b0000_1111_1100_0111, 0, 0, 0, 1, 0, 0, 0, 0, 0, 0, 0
        ),
        mav.manual_control_encode(SYS, 100, 0, 700, 0, 0),
        mav.set_mode_encode(SYS, 1, 6 << 16),
        mav.heartbeat_encode(6, 8, 0, 0, 0),
    ]
    return [bytes(m.pack(mav)) for m in msgs]


def _fuzz_frames(n: int, seed: int = 0) -> list[bytes]:
    rng = np.random.default_rng(seed)
    mav = M.MAVLink(None, 255, 190)
    valid = _valid_frames(mav)
    other = M.MAVLink(None, 255, 190)
    wrong_target = [
        bytes(
            other.command_long_encode(
                SYS + 1, 1, M.MAV_CMD_COMPONENT_ARM_DISARM, 0, 1, 0, 0, 0, 0, 0, 0
            ).pack(other)
        ),
        bytes(
            other.param_set_encode(SYS, 77, b"MPC_XY_CRUISE", 9.0, 9).pack(other)
        ),  # wrong component
        bytes(other.mission_clear_all_encode(200, 1, 0).pack(other)),
        bytes(other.manual_control_encode(3, 100, 0, 700, 0, 0).pack(other)),
    ]
    frames = []
    for i in range(n):
        kind = i % 8
        base = valid[rng.integers(len(valid))]
        if kind == 0:  # random bytes, sometimes starting with a MAVLink magic
            f = bytearray(rng.integers(0, 256, rng.integers(1, 300), dtype=np.uint8).tobytes())
            if rng.random() < 0.5:
                f[0] = 0xFD if rng.random() < 0.5 else 0xFE
        elif kind == 1:  # truncated
            f = base[: rng.integers(1, len(base))]
        elif kind == 2:  # bad CRC or a flipped payload bit
            f = bytearray(base)
            j = rng.integers(10, len(f))
            f[j] ^= 1 << rng.integers(8)
        elif kind == 3:  # wrong target ids, valid CRC
            f = wrong_target[rng.integers(len(wrong_target))]
        elif kind == 4:  # unknown message id, random payload and CRC
            ln = int(rng.integers(0, 60))
            f = bytes([0xFD, ln, 0, 0, 0, 255, 190]) + bytes([0x56, 0x34, 0x12])
            f += rng.integers(0, 256, ln + 2, dtype=np.uint8).tobytes()
        elif kind == 5:  # header lies about the length, or has unknown incompat flags
            f = bytearray(base)
            if rng.random() < 0.5:
                f[1] = (f[1] + int(rng.integers(1, 256))) % 256  # never the true length
            else:
                f[2] = 0x80
        elif kind == 6:  # garbage glued around a corrupted frame
            g = rng.integers(0, 256, rng.integers(1, 40), dtype=np.uint8).tobytes()
            f = bytearray(g + base + g)
            f[len(g) + len(base) - 1] ^= 0xFF
        else:  # MAVLink 1 frame with a bad checksum
            ln = int(rng.integers(0, 40))
            f = bytes([0xFE, ln, 0, 255, 190, int(rng.integers(0, 256))])
            f += rng.integers(0, 256, ln + 2, dtype=np.uint8).tobytes()
        frames.append(bytes(f))
    return frames


def test_fuzz_12000_malformed_frames_over_the_socket():
    n = 12_000
    frames = _fuzz_frames(n)
    with running_sitl(instance=INSTANCE, speedup=10.0) as sitl, Client(INSTANCE) as c:
        c.wait_heartbeat()
        _setup_mission_and_fence(c)
        time.sleep(0.2)
        before = snapshot(sitl)
        link = sitl.endpoint.api
        rx0, bad0 = link.rx_datagrams, link.codec.stats.rx_bad
        s = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        s.bind(("127.0.0.1", 0))
        try:
            give_up = time.monotonic() + 60.0
            for i, f in enumerate(frames):
                s.sendto(f, ("127.0.0.1", 14580 + INSTANCE))
                # Stay under the kernel's socket buffer: let the vehicle catch up.
                while i + 1 - (link.rx_datagrams - rx0) > 200 and time.monotonic() < give_up:
                    time.sleep(0.0005)
        finally:
            s.close()
        deadline = time.monotonic() + 10
        while link.rx_datagrams - rx0 < n and time.monotonic() < deadline:
            time.sleep(0.05)
        received = link.rx_datagrams - rx0
        assert received >= 11_900, f"only {received} of {n} datagrams reached the endpoint"
        ep = sitl.endpoint
        assert link.codec.stats.rx_bad - bad0 >= 0.8 * received
        assert ep.stats["rx_handler_error"] == 0
        assert ep.stats["rx_wrong_target"] >= received // 8 - 50
        # It still answers, and nothing changed. (First empty our own socket: telemetry
        # queued up while we were only sending, and a full buffer drops replies.)
        c.drain()
        assert c.param_read("MPC_XY_CRUISE").param_value == pytest.approx(5.0)
        assert c.command(M.MAV_CMD_REQUEST_MESSAGE, M.MAVLINK_MSG_ID_AUTOPILOT_VERSION).result == 0
        hb = c.recv("HEARTBEAT")
        assert not hb.base_mode & M.MAV_MODE_FLAG_SAFETY_ARMED
        assert sitl.autopilot.mode == FlightMode.HOLD
        assert snapshot(sitl) == before
