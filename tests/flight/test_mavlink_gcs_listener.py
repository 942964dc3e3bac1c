"""The ground-station link streams only heartbeats while nothing listens at its remote (14550):
a datagram to a loopback port nobody has bound comes back as ICMP port unreachable, read from
the socket's error queue (IP_RECVERR). The heartbeat goes on and finds the next listener; a
client that has spoken on the link is answered whatever the remote does. Real sockets on
loopback; the vehicle is stepped on the simulation clock, so no wall time counts."""

from __future__ import annotations

import socket
import sys

import pytest
from pymavlink.dialects.v20 import ardupilotmega as M

from skyherd.flight.airframes_registry import make_autopilot
from skyherd.flight.clock import SimClock
from skyherd.flight.mavlink import EndpointConfig, MavlinkEndpoint
from skyherd.flight.mavlink.link import UdpLink
from skyherd.flight.mavlink.streams import GCS_RATES_HZ

pytestmark = pytest.mark.skipif(
    not sys.platform.startswith("linux"), reason="IP_RECVERR is Linux's (elsewhere: streams as PX4)"
)

REMOTE_HOST = "127.0.0.4"  # the vehicle's remotes live here: no other test listens on it
INSTANCE = 61


def _listener(port: int) -> socket.socket:
    s = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    s.bind((REMOTE_HOST, port))
    s.setblocking(False)
    return s


def _drain(s: socket.socket) -> list:
    mav = M.MAVLink(None)
    mav.robust_parsing = True
    out = []
    while True:
        try:
            data = s.recv(65535)
        except BlockingIOError:
            return out
        out += [m for m in mav.parse_buffer(data) or [] if not isinstance(m, M.MAVLink_bad_data)]


def _frame(link: UdpLink) -> None:
    link.send(M.MAVLink_heartbeat_message(2, 12, 0, 0, 3, 3))
    link.flush()


def test_a_link_learns_that_nobody_listens_and_that_someone_does_again():
    link = UdpLink("gcs", ("127.0.0.1", 0), (REMOTE_HOST, 14799), 1, 1, watch_remote=True)
    plain = UdpLink("api", ("127.0.0.1", 0), (REMOTE_HOST, 14798), 1, 1)
    try:
        assert link.watch_remote and not link.nobody_listens()  # nothing sent yet: no evidence
        _frame(link)
        assert link.nobody_listens()  # refused
        _frame(link)  # the kernel reports the refusal on the next send too: it is sent again
        assert link.send_errors == 0 and link.nobody_listens()
        assert link.nobody_listens()  # nothing sent since: the last answer stands
        rx = _listener(14799)
        try:
            _frame(link)
            assert not link.nobody_listens() and len(_drain(rx)) == 1
        finally:
            rx.close()
        _frame(link)
        assert link.nobody_listens()
        _frame(plain)  # a link that does not watch its remote never says so
        assert not plain.nobody_listens() and plain.send_errors == 0
    finally:
        link.close()
        plain.close()


def test_a_client_that_spoke_on_the_link_is_answered_whatever_the_remote_does():
    link = UdpLink("gcs", ("127.0.0.1", 0), (REMOTE_HOST, 14797), 1, 1, watch_remote=True)
    client = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    client.bind(("127.0.0.1", 0))
    try:
        _frame(link)
        assert link.nobody_listens()
        mav = M.MAVLink(None, 255, 190)
        client.sendto(mav.heartbeat_encode(6, 8, 0, 0, 0).pack(mav), link.sock.getsockname())
        assert len(link.receive()) == 1 and link.peer == client.getsockname()
        assert not link.nobody_listens()
    finally:
        link.close()
        client.close()


def test_the_ground_station_link_streams_heartbeats_until_a_listener_binds():
    ap = make_autopilot("quadrotor", clock=SimClock(), instance=INSTANCE)
    ep = MavlinkEndpoint(ap, EndpointConfig(instance=INSTANCE, remote_host=REMOTE_HOST))

    def run(seconds: float) -> None:
        for _ in range(round(seconds / ap.control_dt)):
            ap.step()
            ep.update()

    per_s = sum(GCS_RATES_HZ.values()) - GCS_RATES_HZ[M.MAVLINK_MSG_ID_HEARTBEAT]
    try:
        run(10.0)  # nobody at 127.0.0.4:14550: all but the heartbeat held back
        unheard = ep.stats["tx_stream_unheard"]
        assert 0.8 * 10 * per_s <= unheard <= 10 * per_s, unheard
        rx = _listener(14550)
        try:
            t_bound = ap.clock.t
            run(4.0)
            msgs = _drain(rx)
        finally:
            rx.close()
        late = ep.stats["tx_stream_unheard"] - unheard  # held back until the next heartbeat
        assert late <= 1.1 * per_s, late
        unheard += late
        assert msgs[0].get_type() == "HEARTBEAT"  # the probe that found the listener
        att = [m.time_boot_ms / 1000 for m in msgs if m.get_type() == "ATTITUDE"]
        assert t_bound < att[0] <= t_bound + 1.0 + 1 / 15 + 0.01  # from the next heartbeat on
        rate = (len(att) - 1) / (att[-1] - att[0])
        assert rate == pytest.approx(GCS_RATES_HZ[M.MAVLINK_MSG_ID_ATTITUDE], rel=0.05)
        kinds = {m.get_type() for m in msgs}
        assert {"SYS_STATUS", "GLOBAL_POSITION_INT", "HOME_POSITION", "VFR_HUD"} <= kinds
        run(5.0)  # the listener has gone: held back again
        assert ep.stats["tx_stream_unheard"] - unheard >= 0.8 * 4 * per_s
    finally:
        ep.close()
