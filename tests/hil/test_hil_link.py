"""The shared MAVLink link: addresses, real UDP sockets, garbage tolerance and tlogs."""

import os
import socket

import pytest
from pymavlink import mavutil
from pymavlink.dialects.v20 import ardupilotmega as mavlink2

from skyherd.hil.link import LinkError, MavlinkLink, link_address
from skyherd.runio.address import parse_address


def _free_udp_port() -> int:
    s = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    s.bind(("127.0.0.1", 0))
    port = s.getsockname()[1]
    s.close()
    return port


def _recv_until(link: MavlinkLink, n: int, tries: int = 20) -> list:
    """Messages from `link` until at least `n` arrived, giving up after `tries` waits of up to
    0.1 s of wall time each (2 s: a loopback datagram already sent arrives well within it)."""
    got = []
    for _ in range(tries):
        got += link.recv(0.1)
        if len(got) >= n:
            break
    return got


def test_link_address_is_the_one_parser_and_refuses_what_a_link_cannot_open():
    assert link_address("udpin:127.0.0.1:14540") == parse_address("udpin:127.0.0.1:14540")
    assert link_address("udpout:10.0.0.2:14550").scheme == "udpout"
    assert link_address("tcp:127.0.0.1:5760").port == 5760
    assert link_address("/dev/ttyACM0,115200") == parse_address("/dev/ttyACM0,115200")
    for bad in ("udp:14540", "http://x:1", "udpin:127.0.0.1:99999", "/dev/tty,fast", "",
                "tcpin:127.0.0.1:5760"):  # fmt: skip
        with pytest.raises(ValueError):
            link_address(bad)


def test_udp_roundtrip_skips_garbage_and_writes_tlog(tmp_path):
    port = _free_udp_port()
    tlog = tmp_path / "t.tlog"
    rx = MavlinkLink.open(f"udpin:127.0.0.1:{port}", source_system=1, source_component=1, tlog=tlog)
    tx = MavlinkLink.open(f"udpout:127.0.0.1:{port}", source_system=255, source_component=190)
    try:
        hb = mavlink2.MAVLink_heartbeat_message(6, 8, 0, 0, 0, 3)
        tx.transport.send(os.urandom(300))  # garbage first
        for _ in range(3):
            tx.send(hb)
        got = _recv_until(rx, 3)
        assert [m.get_type() for m in got] == ["HEARTBEAT"] * 3
        assert [m.get_seq() for m in got] == [0, 1, 2]
        assert got[0].get_srcSystem() == 255
        # udpin answers whoever sent last
        rx.send(mavlink2.MAVLink_heartbeat_message(2, 12, 0, 0, 0, 3))
        back = _recv_until(tx, 1)
        assert back and back[0].autopilot == 12 and back[0].get_srcSystem() == 1
    finally:
        rx.close()
        tx.close()
    # the tlog holds what rx received and sent, readable by pymavlink's own reader
    log = mavutil.mavlink_connection(str(tlog))
    types = []
    while (m := log.recv_match()) is not None:
        types.append((m.get_type(), m.get_srcSystem()))
    assert types == [("HEARTBEAT", 255)] * 3 + [("HEARTBEAT", 1)]


def test_deferred_tlog_holds_records_until_flush_log_in_order_with_their_stamps(tmp_path):
    """A lockstep companion writes its tick's tlog records after the tick's close: nothing is
    in the file before `flush_log()`, then what was received and sent, in that order, each
    with the stamp of the moment it crossed the link (not of the flush)."""
    port = _free_udp_port()
    tlog = tmp_path / "t.tlog"
    rx = MavlinkLink.open(f"udpin:127.0.0.1:{port}", source_system=1, source_component=1, tlog=tlog)
    tx = MavlinkLink.open(f"udpout:127.0.0.1:{port}", source_system=255, source_component=190)
    rx.defer_log = True
    try:
        tx.send(mavlink2.MAVLink_heartbeat_message(6, 8, 0, 0, 0, 3))
        got = _recv_until(rx, 1)
        assert got
        rx.send(mavlink2.MAVLink_heartbeat_message(2, 12, 0, 0, 0, 3))
        stamps = [s for s, _ in rx._unlogged]
        assert tlog.stat().st_size == 0  # held
        rx.flush_log()
        size = tlog.stat().st_size
        assert size > 0 and rx._unlogged == []
        rx.flush_log()  # nothing more held: nothing more written
        assert tlog.stat().st_size == size
    finally:
        rx.close()
        tx.close()
    log = mavutil.mavlink_connection(str(tlog))
    rows = []
    while (m := log.recv_match()) is not None:
        rows.append((m.get_type(), m.get_srcSystem(), round(m._timestamp * 1e6)))
    assert [(t, s) for t, s, _ in rows] == [("HEARTBEAT", 255), ("HEARTBEAT", 1)]
    assert [us for _, _, us in rows] == stamps  # the crossing's stamp, µs for µs


def test_tlog_never_records_setup_signing_the_frame_that_carries_the_key(tmp_path):
    """SETUP_SIGNING (MAVLink 2 only, id 256) is dropped from a record batch; MAVLink 1 and 2
    frames around it are kept, in order."""
    from skyherd.flight.mavlink.tlog import TlogWriter

    mav = mavlink2.MAVLink(None, srcSystem=255, srcComponent=190)
    hb = mavlink2.MAVLink_heartbeat_message(6, 8, 0, 0, 0, 3)
    v2_hb = bytes(hb.pack(mav))
    key = bytes(mav.setup_signing_encode(1, 1, list(range(32)), 123).pack(mav))
    mav1 = mavlink2.MAVLink(None, srcSystem=7, srcComponent=1)
    mav1.WIRE_PROTOCOL_VERSION = "1.0"
    v1_hb = bytes(hb.pack(mav1, force_mavlink1=True))
    assert v1_hb[0] == 0xFE and key[0] == 0xFD
    w = TlogWriter(tmp_path / "k.tlog")
    w.write_many([v2_hb, key, v1_hb])
    w.close()
    assert w.records == 2
    data = (tmp_path / "k.tlog").read_bytes()
    assert bytes(range(32)) not in data
    log = mavutil.mavlink_connection(str(tmp_path / "k.tlog"))
    got = []
    while (m := log.recv_match()) is not None:
        got.append((m.get_type(), m.get_srcSystem()))
    assert got == [("HEARTBEAT", 255), ("HEARTBEAT", 7)]


def test_tlog_write_stamped_is_write_many_per_group_in_one_write(tmp_path):
    """A lockstep tick's held records (flush_log) go out as one write and one flush, the same
    bytes as one write_many per (stamp, frames) group; SETUP_SIGNING still dropped."""
    from skyherd.flight.mavlink.tlog import TlogWriter

    mav = mavlink2.MAVLink(None, srcSystem=255, srcComponent=190)
    frames = [
        bytes(mavlink2.MAVLink_heartbeat_message(6, 8, 0, 0, 0, i).pack(mav)) for i in range(5)
    ]
    key = bytes(mav.setup_signing_encode(1, 1, list(range(32)), 123).pack(mav))
    groups = [(1_000_000, frames[:2]), (1_000_250, [key]), (1_000_500, frames[2:])]
    one = TlogWriter(tmp_path / "one.tlog")
    for stamp_us, fr in groups:
        one.write_many(fr, stamp_us)
    one.close()
    w = TlogWriter(tmp_path / "batch.tlog")
    calls = []
    real = w._f

    class Counting:
        def write(self, data):
            calls.append("write")
            return real.write(data)

        def flush(self):
            calls.append("flush")
            return real.flush()

        def close(self):
            return real.close()

    w._f = Counting()
    w.write_stamped(groups)
    assert calls == ["write", "flush"] and w.records == 5
    w.close()
    assert (tmp_path / "batch.tlog").read_bytes() == (tmp_path / "one.tlog").read_bytes()


def test_busy_port_and_refused_tcp_give_clear_errors():
    port = _free_udp_port()
    a = MavlinkLink.open(f"udpin:127.0.0.1:{port}")
    try:
        with pytest.raises(LinkError, match="port in use"):
            MavlinkLink.open(f"udpin:127.0.0.1:{port}")
    finally:
        a.close()
    with pytest.raises(LinkError, match="cannot connect TCP"):
        MavlinkLink.open(f"tcp:127.0.0.1:{_free_udp_port()}")


def test_tcp_connect_wait_retries_a_refused_port_until_it_listens_walltime():
    """ArduPilot SITL binds SERIAL1 only after SERIAL0 has a client: the world's link waits."""
    import threading
    import time

    port = _free_udp_port()
    srv = socket.socket(socket.AF_INET, socket.SOCK_STREAM)
    srv.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)

    def listen_late() -> None:
        time.sleep(0.5)
        srv.bind(("127.0.0.1", port))
        srv.listen(1)

    th = threading.Thread(target=listen_late)
    th.start()
    try:
        link = MavlinkLink.open(f"tcp:127.0.0.1:{port}", connect_wait_s=10.0)
        th.join()
        peer, _ = srv.accept()
        link.send(link.mav.heartbeat_encode(6, 8, 0, 0, 4))
        assert peer.recv(64)[0] == 0xFD  # a MAVLink 2 frame arrived over the late server
        peer.close()
        link.close()
    finally:
        th.join()
        srv.close()
