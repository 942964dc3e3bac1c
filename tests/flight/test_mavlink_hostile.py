"""The endpoint and its run files under hostile conditions (issue 11, item 8).

Floods of distinct requesters stay bounded; the tlog holds each parsed frame (trailing
garbage and two frames per datagram); command parameters with hostile floats are refused
before anything changes; one client cannot stop the heartbeat or hijack another's mission
upload; a full disk or a read-only directory stops logging, not the vehicle; a corrupt
params.json falls back to defaults with a one-line warning. Every test steps the vehicle
itself (tests/mavlink_rig.py): nothing depends on wall time or load."""

from __future__ import annotations

import logging
import math
import os
from pathlib import Path

import numpy as np
import pytest
from mavlink_rig import Peer, Rig, texts
from pymavlink import mavutil
from pymavlink.dialects.v20 import ardupilotmega as M

from skyherd.flight.mavlink import commands as cmds
from skyherd.flight.mavlink.mission import MAX_RETRIES, RETRY_S
from skyherd.flight.mavlink.params import MAX_LIST_REQUESTERS, ParamFile
from skyherd.flight.mavlink.tlog import TlogWriter
from skyherd.hil.link import MavlinkLink

INSTANCE = 60  # mav helper: instances 60-64
REL = M.MAV_FRAME_GLOBAL_RELATIVE_ALT_INT


def _tlog_messages(path: Path) -> list:
    """Every record of a tlog as pymavlink's own tlog reader returns it (bad ones too)."""
    log = mavutil.mavlink_connection(str(path), robust_parsing=True)
    out = []
    while (m := log.recv_msg()) is not None:
        out.append(m)
    return out


# --- bounded tables ---------------------------------------------------------------------------
def test_param_list_flood_is_bounded_and_a_legit_client_still_gets_its_list():
    with Rig(INSTANCE) as rig:
        ep = rig.ep
        n_params = len(ep.params.names)
        flood = Peer()
        try:
            for i in range(2000):  # 2,000 distinct (system, component)
                flood.mav.srcSystem, flood.mav.srcComponent = 1 + i // 200, i % 200
                flood.send(flood.mav.param_request_list_encode(rig.sys, 1), rig.api)
                if i % 100 == 99:
                    rig.step()
            rig.step()
            assert len(ep.params._lists) == MAX_LIST_REQUESTERS
            assert ep.params.evicted_lists == 2000 - MAX_LIST_REQUESTERS
            assert ep.params.queued() <= MAX_LIST_REQUESTERS * n_params
            # A client asking now is served round-robin with the others: all of its list.
            rig.client.send(rig.client.mav.param_request_list_encode(rig.sys, 1), rig.api)
            got: dict[int, str] = {}
            for _ in range(4 * MAX_LIST_REQUESTERS * n_params // ep.params.per_update + 10):
                rig.step()
                for m in rig.client.recv():
                    if m.get_type() == "PARAM_VALUE":
                        got[m.param_index] = m.param_id
                if not ep.params._lists:
                    break
            assert sorted(got) == list(range(n_params))
            assert ep.stats["rx_handler_error"] == 0
        finally:
            flood.close()


def test_command_retry_table_is_bounded_and_expires_on_sim_time():
    with Rig(INSTANCE) as rig:
        flood = Peer()
        try:
            for i in range(3000):  # distinct (sender, command): each answered UNSUPPORTED
                flood.mav.srcSystem, flood.mav.srcComponent = 1 + i // 250, i % 250
                flood.send(flood.mav.command_long_encode(rig.sys, 1, 40_000 + i % 7, 0,
                                                         0, 0, 0, 0, 0, 0, 0), rig.api)  # fmt: skip
                if i % 100 == 99:
                    rig.step()
            rig.step()
            assert len(rig.ep.commands._last) == cmds.MAX_RETRY_ENTRIES
            rig.step(cmds.RETRY_WINDOW_S + 0.1)
            assert rig.command(31_000).result == M.MAV_RESULT_UNSUPPORTED
            assert len(rig.ep.commands._last) == 1  # everything older expired
        finally:
            flood.close()


# --- the tlog ---------------------------------------------------------------------------------
def _hostile_datagrams(n: int, seed: int = 0) -> tuple[list[bytes], set[int]]:
    """n datagrams: two HEARTBEATs each (custom_mode numbers them), most with trailing junk."""
    rng = np.random.default_rng(seed)
    mav = M.MAVLink(None, 255, 190)
    grams, sent = [], set()
    for i in range(n):
        a = bytes(mav.heartbeat_encode(6, 8, 0, 2 * i, 0).pack(mav))
        b = bytes(mav.heartbeat_encode(6, 8, 0, 2 * i + 1, 0).pack(mav))
        sent |= {2 * i, 2 * i + 1}
        junk = rng.integers(0, 256, int(rng.integers(0, 40)), dtype=np.uint8).tobytes()
        if i % 3 == 0:
            junk = b"\xfd" + junk  # looks like the start of another frame
        grams.append(a + b + junk)
    return grams, sent


def test_endpoint_tlog_holds_each_parsed_frame_readable_by_pymavlink(tmp_path):
    tlog = tmp_path / "telemetry.tlog"
    grams, sent = _hostile_datagrams(1000)
    with Rig(INSTANCE, tlog=tlog) as rig:
        for i, g in enumerate(grams):
            rig.client.send(g, rig.api)
            if i % 50 == 49:
                rig.step()
                rig.client.recv()
        rig.step()
    msgs = _tlog_messages(tlog)
    assert [m for m in msgs if m.get_type() == "BAD_DATA"] == []
    inbound = [
        m.custom_mode for m in msgs if m.get_type() == "HEARTBEAT" and m.get_srcSystem() == 255
    ]
    assert sorted(inbound) == sorted(sent)  # 2,000 frames from 1,000 datagrams, each once
    ours = [m for m in msgs if m.get_srcSystem() == 1 + INSTANCE]
    assert any(m.get_type() == "ATTITUDE" for m in ours)


def test_client_tlog_holds_each_parsed_frame_readable_by_pymavlink(tmp_path):
    tlog = tmp_path / "client.tlog"
    grams, sent = _hostile_datagrams(1000, seed=1)
    port = 14540 + INSTANCE + 1
    link = MavlinkLink.open(f"udpin:127.0.0.1:{port}", tlog=tlog)
    sender = Peer()
    got = []
    try:
        for i, g in enumerate(grams):
            sender.send(g, ("127.0.0.1", port))
            if i % 50 == 49:
                while len(got) < 2 * (i + 1) and (batch := link.recv(0.5)):
                    got += batch
        while len(got) < len(sent) and (batch := link.recv(0.5)):
            got += batch
    finally:
        sender.close()
        link.close()
    assert len(got) == len(sent)
    msgs = _tlog_messages(tlog)
    assert [m for m in msgs if m.get_type() == "BAD_DATA"] == []
    assert sorted(m.custom_mode for m in msgs) == sorted(sent)


# --- commands ---------------------------------------------------------------------------------
HOSTILE = [math.nan, math.inf, -math.inf, 1e38, -1e38, 3.4e38, 1e-45, -0.0, 1e7, -1e7, 91.0,
           -181.0, 2.0**31, 21196.0, 0.0, 1.0]  # fmt: skip


def _snapshot(rig: Rig) -> dict:
    ap, ep = rig.ap, rig.ep
    return {
        "armed": ap.armed,
        "mode": ap.mode,
        "params": {n: ap.get_param(n) for n in ap.param_names()},
        "mission": list(ep.missions.lists[0]),
        "current": ap.mission_progress.current,
        "rates": {k: dict(v.rates) for k, v in ep.streams.items()},
        "target": np.array(getattr(ap, "_target", np.zeros(3)), dtype=float).round(9).tolist(),
        "yaw_sp": getattr(ap, "_yaw_sp", None),
    }


def _must_deny(command: int, p: tuple) -> bool:
    """What the MAVLink spec makes invalid whatever the vehicle's state."""
    if any(math.isinf(v) for v in p):
        return True
    if command in (M.MAV_CMD_NAV_TAKEOFF, M.MAV_CMD_NAV_LAND, M.MAV_CMD_DO_REPOSITION):
        lat, lon = p[4], p[5]
        return (not math.isnan(lat) and abs(lat) > 90) or (not math.isnan(lon) and abs(lon) > 180)
    return False


HOSTILE_INT = [2**31 - 1, -(2**31), 2**31 - 2, 0, 900_000_001, -1_800_000_001, 1]  # x, y (deg·1e7)


def _send_fuzz(rig: Rig, i: int, command: int, p: tuple, rng) -> tuple:
    """COMMAND_LONG, or every third case COMMAND_INT with hostile x/y; → (ack, params as seen)."""
    mav = rig.client.mav
    if i % 3:
        msg = mav.command_long_encode(rig.sys, 1, command, 0, *p)
        seen = p
    else:
        x, y = (int(HOSTILE_INT[k]) for k in rng.integers(0, len(HOSTILE_INT), 2))
        frame = (M.MAV_FRAME_GLOBAL_INT, REL)[i % 2]
        msg = mav.command_int_encode(rig.sys, 1, frame, command, 0, 0, *p[:4], x, y, p[6])
        deg = [math.nan if v == 2**31 - 1 else v / 1e7 for v in (x, y)]
        seen = (*p[:4], *deg, p[6])
    acks = [m for m in rig.exchange(msg) if m.get_type() == "COMMAND_ACK" and m.command == command]
    return (acks[-1] if acks else None), seen


def test_fuzz_every_handled_command_with_hostile_floats():
    rng = np.random.default_rng(7)
    with Rig(INSTANCE) as rig:
        rig.fly(10.0)
        handled = sorted(rig.ep.commands.handled)
        denied = changed = 0
        for i in range(1500):
            command = handled[i % len(handled)]
            p = tuple(float(HOSTILE[j]) if rng.random() < 0.5 else float(rng.normal(0, 30))
                      for j in rng.integers(0, len(HOSTILE), 7))  # fmt: skip
            if command == M.MAV_CMD_COMPONENT_ARM_DISARM and p[0] == 0.0:
                p = (1.0,) + p[1:]  # a plain disarm in the air is the autopilot's call, not ours
            before = _snapshot(rig)
            ack, seen = _send_fuzz(rig, i, command, p, rng)
            assert ack is not None, (command, seen)
            if _must_deny(command, seen):
                assert ack.result == M.MAV_RESULT_DENIED, (command, seen, ack.result)
            if ack.result == M.MAV_RESULT_DENIED:
                denied += 1
                assert _snapshot(rig) == before, (command, seen)
            elif _snapshot(rig) != before:
                changed += 1
            if not rig.ap.armed or rig.ap.state.altitude < 3.0:  # keep flying
                if not rig.ap.armed:
                    rig.ap.arm()
                rig.ap.takeoff(10.0)
                rig.step(8.0)
        assert rig.ep.stats["rx_handler_error"] == 0
        assert denied > 700 and changed > 0  # both paths were exercised


def test_nav_land_with_absurd_position_is_denied_with_a_reason():
    with Rig(INSTANCE) as rig:
        rig.fly(10.0)
        mode = rig.ap.mode
        for p6, p7 in ((1e38, 0.0), (0.0, -math.inf), (math.nan, 1e9)):
            rig.client.recv()
            rig.client.send(rig.client.mav.command_long_encode(
                rig.sys, 1, M.MAV_CMD_NAV_LAND, 0, 0, 0, 0, math.nan, math.nan, p6, p7), rig.api)  # fmt: skip
            rig.step()
            got = rig.client.recv()
            ack = next(m for m in got if m.get_type() == "COMMAND_ACK")
            assert ack.result == M.MAV_RESULT_DENIED and rig.ap.mode == mode
            assert any("out of range" in t or "infinite" in t for t in texts(got))
        # NaN position = land here: accepted.
        assert (
            rig.command(M.MAV_CMD_NAV_LAND, 0, 0, 0, math.nan, math.nan, math.nan, math.nan).result
            == 0
        )


def test_one_client_cannot_stop_or_slow_the_heartbeat_for_everyone():
    with Rig(INSTANCE) as rig:
        hb = M.MAVLINK_MSG_ID_HEARTBEAT
        for interval in (-1, 5e6):
            rig.client.recv()
            ack = rig.command(M.MAV_CMD_SET_MESSAGE_INTERVAL, hb, interval)
            assert ack.result == M.MAV_RESULT_DENIED
        assert rig.command(M.MAV_CMD_SET_MESSAGE_INTERVAL, hb, 0).result == 0  # default: fine
        assert rig.command(M.MAV_CMD_SET_MESSAGE_INTERVAL, hb, 5e5).result == 0  # faster: fine
        rig.client.recv()
        rig.step(3.0)
        beats = [m for m in rig.client.recv() if m.get_type() == "HEARTBEAT"]
        assert len(beats) >= 5  # 2 Hz for 3 s of simulation time


# --- mission uploads --------------------------------------------------------------------------
def _items(rig: Rig, n: int) -> list:
    lat, lon = int(rig.ap.home.lat_deg * 1e7), int(rig.ap.home.lon_deg * 1e7)
    return [(REL, 16, 0, 0, 0, math.nan, lat + 100 * k, lon, 5.0) for k in range(n)]


def _item(peer: Peer, rig: Rig, seq: int, it: tuple):
    frame, command, p1, p2, p3, p4, x, y, z = it
    return peer.mav.mission_item_int_encode(
        rig.sys, 1, seq, frame, command, 0, 1, p1, p2, p3, p4, x, y, z, 0
    )


def test_a_second_clients_upload_is_denied_while_one_runs_and_the_first_times_out():
    with Rig(INSTANCE) as rig:
        a, b = rig.client, Peer(system=77, component=190)
        try:
            items_a, items_b = _items(rig, 3), _items(rig, 2)
            got = rig.exchange(a.mav.mission_count_encode(rig.sys, 1, 3, 0), a)
            assert [m.seq for m in got if m.get_type() == "MISSION_REQUEST_INT"] == [0]
            got = rig.exchange(b.mav.mission_count_encode(rig.sys, 1, 2, 0), b)
            acks = [m for m in got if m.get_type() == "MISSION_ACK"]
            assert [m.type for m in acks] == [M.MAV_MISSION_DENIED]
            for seq in range(3):  # A's upload goes on undisturbed
                got = rig.exchange(_item(a, rig, seq, items_a[seq]), a)
            assert [m.type for m in got if m.get_type() == "MISSION_ACK"] == [
                M.MAV_MISSION_ACCEPTED
            ]
            assert len(rig.ep.missions.lists[0]) == 3
            # A starts again and goes silent: B is refused until A's upload times out.
            rig.exchange(a.mav.mission_count_encode(rig.sys, 1, 3, 0), a)
            got = rig.exchange(b.mav.mission_count_encode(rig.sys, 1, 2, 0), b)
            assert [m.type for m in got if m.get_type() == "MISSION_ACK"] == [M.MAV_MISSION_DENIED]
            a.recv()
            rig.step(RETRY_S * (MAX_RETRIES + 1) + 0.1)
            got = a.recv()
            acks = [m.type for m in got if m.get_type() == "MISSION_ACK"]
            assert acks == [M.MAV_MISSION_OPERATION_CANCELLED]
            got = rig.exchange(b.mav.mission_count_encode(rig.sys, 1, 2, 0), b)
            for seq in range(2):
                got = rig.exchange(_item(b, rig, seq, items_b[seq]), b)
            assert [m.type for m in got if m.get_type() == "MISSION_ACK"] == [
                M.MAV_MISSION_ACCEPTED
            ]
            assert len(rig.ep.missions.lists[0]) == 2
        finally:
            b.close()


# --- logging failures -------------------------------------------------------------------------
def _unwritable_dir(tmp_path: Path) -> Path:
    """A directory this process cannot create files in (as root, chmod is not enough: /sys)."""
    ro = tmp_path / "ro"
    ro.mkdir()
    ro.chmod(0o555)
    return ro if not os.access(ro, os.W_OK) else Path("/sys")


@pytest.mark.parametrize("where", ["full disk", "read-only dir"])
def test_tlog_failure_stops_logging_not_the_vehicle(tmp_path, where, caplog):
    tlog = Path("/dev/full") if where == "full disk" else _unwritable_dir(tmp_path) / "t.tlog"
    with caplog.at_level(logging.WARNING), Rig(INSTANCE, tlog=tlog) as rig:
        rig.fly(5.0)  # 12 s of telemetry: /dev/full refuses the first buffer flushed
        got = []
        for _ in range(3):
            rig.step(1.0)
            got += rig.client.recv()
        warned = [t for t in texts(got) if "tlog" in t]
        assert len(warned) == 1 and ("No space left" in warned[0] or "ermission" in warned[0])
        assert rig.ep._tlog.error and not rig.ep._tlog.active
        ack = rig.command(M.MAV_CMD_REQUEST_MESSAGE, M.MAVLINK_MSG_ID_AUTOPILOT_VERSION)
        assert ack.result == M.MAV_RESULT_ACCEPTED and rig.ap.state.altitude > 4.0
    assert sum("telemetry logging stopped" in r.message for r in caplog.records) == 1


@pytest.mark.parametrize("where", ["full disk", "read-only dir"])
def test_client_tlog_failure_keeps_the_link_working(tmp_path, where, caplog):
    tlog = Path("/dev/full") if where == "full disk" else _unwritable_dir(tmp_path) / "c.tlog"
    port = 14540 + INSTANCE + 2
    with caplog.at_level(logging.WARNING):
        rx = MavlinkLink.open(f"udpin:127.0.0.1:{port}", tlog=tlog)
        tx = MavlinkLink.open(f"udpout:127.0.0.1:{port}")
        try:
            got = []
            for i in range(5):
                tx.send(M.MAVLink_heartbeat_message(6, 8, 0, i, 0, 3))
                got += rx.recv(1.0)
                rx.send(M.MAVLink_heartbeat_message(6, 8, 0, 100 + i, 0, 3))
            assert [m.custom_mode for m in got] == list(range(5))
            assert rx.tlog_error is not None and "logging stopped" in rx.tlog_error
        finally:
            rx.close()
            tx.close()
    assert sum("telemetry logging stopped" in r.message for r in caplog.records) == 1


def test_tlog_writer_after_close_and_never_logs_the_signing_key(tmp_path):
    path = tmp_path / "t.tlog"
    w = TlogWriter(path)
    mav = M.MAVLink(None, 255, 190)
    w.write(bytes(mav.setup_signing_encode(1, 1, list(range(32)), 5).pack(mav)))
    w.write(bytes(mav.heartbeat_encode(6, 8, 0, 0, 0).pack(mav)))
    w.close()
    w.write(b"late")  # a receive thread finishing after close: ignored
    assert [m.get_type() for m in _tlog_messages(path)] == ["HEARTBEAT"]


# --- parameter file ---------------------------------------------------------------------------
@pytest.mark.parametrize(
    "content", ["[" * 200_000, '{"version": 1, "params": {' + '"A": 1.0, ' * 200_000 + "}}"]
)
def test_deep_or_huge_params_json_gives_defaults_with_one_line(tmp_path, caplog, content):
    path = tmp_path / "quadrotor-60" / "params.json"
    path.parent.mkdir(parents=True)
    path.write_text(content)
    with caplog.at_level(logging.WARNING):
        assert ParamFile(path).load() == {}
    (rec,) = [r for r in caplog.records if "unreadable" in r.message]
    assert "\n" not in rec.getMessage() and "using defaults" in rec.getMessage()
    assert not path.exists() and path.with_name("params.json.corrupt").exists()
    path.write_text("[" * 200_000)
    with Rig(INSTANCE, state_dir=tmp_path) as rig:  # the vehicle starts on its defaults
        assert rig.ap.get_param("MPC_XY_CRUISE") == pytest.approx(5.0)
        ack = rig.command(M.MAV_CMD_REQUEST_MESSAGE, M.MAVLINK_MSG_ID_AUTOPILOT_VERSION)
        assert ack.result == M.MAV_RESULT_ACCEPTED
