"""MAVLink 2 signing, cross-checked against pymavlink's implementation in both directions.

Endpoint side: a pymavlink peer signing with the vehicle's key is heard; unsigned, wrongly
signed, replayed and stale frames are not (RADIO_STATUS unsigned is, as ArduPilot does); the
vehicle's own frames verify in pymavlink; SETUP_SIGNING turns signing on (key file, 32 bytes,
0600), survives a restart, and only a signed zero key turns it off. Client side (hil.link):
the same rules against a pymavlink-signed sender, and pymavlink accepts what we sign.
Signature timestamps are wall time by the spec; no assertion depends on timing."""

from __future__ import annotations

import os
import socket
import stat

import pytest
from mavlink_rig import Peer, Rig
from pymavlink.dialects.v20 import ardupilotmega as M

from skyherd.flight.mavlink import signing as sg
from skyherd.hil.link import MavlinkLink

INSTANCE = 62  # mav helper: instances 60-64
KEY = sg.key_from_passphrase("skyherd test key")
OTHER_KEY = sg.key_from_passphrase("not the key")


def _sign_with_pymavlink(peer: Peer, key: bytes, link_id: int = 3, timestamp: int | None = None):
    s = peer.mav.signing
    s.secret_key, s.link_id, s.sign_outgoing = key, link_id, True
    s.timestamp = sg.now_units() if timestamp is None else timestamp


def _verifier(key: bytes) -> M.MAVLink:
    """pymavlink's parser that accepts only frames correctly signed with `key`."""
    v = M.MAVLink(None)
    v.robust_parsing = True
    v.signing.secret_key = key
    v.signing.allow_unsigned_callback = None
    return v


def _key_file(tmp_path, key: bytes = KEY):
    path = tmp_path / "uav.key"
    sg.save_key(path, key)
    return path


def _autopilot_version_acks(rig: Rig, frame: bytes, peer: Peer) -> int:
    peer.recv()
    peer.send(frame, rig.api)
    rig.step()
    return sum(m.get_type() == "COMMAND_ACK" for m in peer.recv())


def test_endpoint_accepts_signed_rejects_unsigned_wrong_replayed_and_stale(tmp_path):
    with Rig(INSTANCE, signing_key=_key_file(tmp_path)) as rig:
        peer = rig.client
        req = peer.mav.command_long_encode(rig.sys, 1, M.MAV_CMD_REQUEST_MESSAGE, 0,
                                           M.MAVLINK_MSG_ID_AUTOPILOT_VERSION, 0, 0, 0, 0, 0, 0)  # fmt: skip
        unsigned = bytes(req.pack(peer.mav))
        assert _autopilot_version_acks(rig, unsigned, peer) == 0
        _sign_with_pymavlink(peer, KEY)
        signed = bytes(req.pack(peer.mav))
        assert sg.is_signed(signed)
        assert _autopilot_version_acks(rig, signed, peer) == 1
        assert _autopilot_version_acks(rig, signed, peer) == 0  # the same frame again: replay
        assert _autopilot_version_acks(rig, bytes(req.pack(peer.mav)), peer) == 1  # fresh
        tampered = bytearray(bytes(req.pack(peer.mav)))
        tampered[-1] ^= 0x01
        assert _autopilot_version_acks(rig, bytes(tampered), peer) == 0
        wrong = Peer()
        _sign_with_pymavlink(wrong, OTHER_KEY)
        assert _autopilot_version_acks(rig, bytes(req.pack(wrong.mav)), wrong) == 0
        # A stream not seen before (another link id) more than a minute behind: stale.
        stale = Peer()
        _sign_with_pymavlink(stale, KEY, link_id=9, timestamp=sg.now_units() - 2 * sg.REPLAY_WINDOW)
        assert _autopilot_version_acks(rig, bytes(req.pack(stale.mav)), stale) == 0
        _sign_with_pymavlink(
            stale, KEY, link_id=10, timestamp=sg.now_units() - sg.REPLAY_WINDOW // 2
        )
        assert _autopilot_version_acks(rig, bytes(req.pack(stale.mav)), stale) == 1
        # RADIO_STATUS is accepted unsigned (a SiK radio cannot sign), as ArduPilot does.
        radio = Peer()
        radio.send(radio.mav.radio_status_encode(200, 190, 100, 90, 80, 0, 0), rig.api)
        rig.step()
        assert rig.ep.rx_types["RADIO_STATUS"] == 1
        stats = rig.ep.signing.stats
        assert stats["rejected_unsigned"] == 1 and stats["rejected_replayed"] == 1
        assert stats["rejected_bad"] == 2 and stats["rejected_timestamp"] == 1
        assert stats["unsigned_accepted"] == 1
        for p in (wrong, stale, radio):
            p.close()


def _frames(datagram: bytes) -> list[bytes]:
    """The MAVLink 2 frames of one datagram, cut by their headers (length, signed flag)."""
    out, i = [], 0
    while i < len(datagram):
        assert datagram[i] == 0xFD, "a datagram holds whole MAVLink 2 frames"
        n = 10 + datagram[i + 1] + 2 + (13 if datagram[i + 2] & sg.IFLAG_SIGNED else 0)
        out.append(datagram[i : i + n])
        i += n
    return out


def test_endpoint_frames_verify_in_pymavlink_and_fail_with_another_key(tmp_path):
    with Rig(INSTANCE, signing_key=_key_file(tmp_path)) as rig:
        rig.step(2.0)
        raw = []  # each frame on its own (a step's frames leave in one datagram)
        while True:
            try:
                raw += _frames(rig.client.sock.recv(65535))
            except BlockingIOError:
                break
        assert len(raw) > 50 and all(sg.is_signed(f) for f in raw)
        good, bad = _verifier(KEY), _verifier(OTHER_KEY)
        ok = [m for f in raw for m in good.parse_buffer(f) or []]
        assert len(ok) == len(raw) and all(m.get_signed() for m in ok)
        assert {m.get_type() for m in ok} >= {"HEARTBEAT", "ATTITUDE", "LOCAL_POSITION_NED"}
        refused = [m for f in raw for m in bad.parse_buffer(f) or []]
        assert all(m.get_type() == "BAD_DATA" for m in refused) and bad.signing.badsig_count > 0
        stamps = [int.from_bytes(f[-12:-6], "little") for f in raw]
        assert stamps == sorted(set(stamps))  # strictly increasing across the two links


def test_setup_signing_turns_signing_on_persists_and_only_a_signed_zero_key_turns_it_off(tmp_path):
    with Rig(INSTANCE, state_dir=tmp_path) as rig:
        key_file = rig.config.key_file("quadrotor")
        peer = rig.client
        assert not rig.ep.signing.enabled
        peer.send(peer.mav.setup_signing_encode(rig.sys, 1, list(KEY), sg.now_units()), rig.api)
        rig.step()
        assert rig.ep.signing.enabled and key_file.read_bytes() == KEY
        assert stat.S_IMODE(os.stat(key_file).st_mode) == 0o600
        assert rig.command(M.MAV_CMD_REQUEST_MESSAGE, 148) is None  # unsigned: not heard
        # An unsigned SETUP_SIGNING (a new key or a zero key) from anyone is not heard either.
        peer.send(peer.mav.setup_signing_encode(rig.sys, 1, list(OTHER_KEY), 0), rig.api)
        peer.send(peer.mav.setup_signing_encode(rig.sys, 1, [0] * 32, 0), rig.api)
        rig.step()
        assert rig.ep.signing.key == KEY
        _sign_with_pymavlink(peer, KEY)
        assert rig.command(M.MAV_CMD_REQUEST_MESSAGE, 148).result == M.MAV_RESULT_ACCEPTED
    with Rig(INSTANCE, state_dir=tmp_path) as rig:  # restart: the key file is used
        assert rig.ep.signing.key == KEY
        peer = rig.client
        _sign_with_pymavlink(peer, KEY, link_id=4)
        assert rig.command(M.MAV_CMD_REQUEST_MESSAGE, 148).result == M.MAV_RESULT_ACCEPTED
        peer.send(peer.mav.setup_signing_encode(rig.sys, 1, [0] * 32, 0), rig.api)
        rig.step()
        assert not rig.ep.signing.enabled and not key_file.exists()
        peer.mav.signing.sign_outgoing = False
        assert rig.command(M.MAV_CMD_REQUEST_MESSAGE, 148).result == M.MAV_RESULT_ACCEPTED


def test_client_accepts_pymavlink_signed_rejects_unsigned_and_replayed_and_signs_for_it(tmp_path):
    port = 14540 + INSTANCE + 1
    link = MavlinkLink.open(f"udpin:127.0.0.1:{port}", signing_key=_key_file(tmp_path), link_id=2)
    sender = Peer()
    try:

        def heard(frame: bytes) -> list:
            sender.send(frame, ("127.0.0.1", port))
            return link.recv(0.5)

        hb = sender.mav.heartbeat_encode(M.MAV_TYPE_QUADROTOR, M.MAV_AUTOPILOT_PX4, 0, 7, 0)
        assert heard(bytes(hb.pack(sender.mav))) == []  # unsigned
        _sign_with_pymavlink(sender, KEY, link_id=0)
        signed = bytes(hb.pack(sender.mav))
        assert [m.custom_mode for m in heard(signed)] == [7]
        assert heard(signed) == []  # replayed
        assert [m.get_type() for m in heard(bytes(hb.pack(sender.mav)))] == ["HEARTBEAT"]
        wrong = Peer()
        _sign_with_pymavlink(wrong, OTHER_KEY)
        wrong.send(bytes(hb.pack(wrong.mav)), ("127.0.0.1", port))
        assert link.recv(0.5) == []
        wrong.close()
        assert link.rejected_packets == 3
        # What we send verifies in pymavlink (the link answers the last sender: `sender`).
        link.send(M.MAVLink_heartbeat_message(M.MAV_TYPE_GCS, M.MAV_AUTOPILOT_INVALID, 0, 0, 0, 3))
        sender.sock.setblocking(True)
        sender.sock.settimeout(2.0)
        frame = sender.sock.recv(65535)
        (m,) = _verifier(KEY).parse_buffer(frame)
        assert m.get_type() == "HEARTBEAT" and m.get_signed() and frame[-13] == 2  # our link id
    finally:
        sender.close()
        link.close()


def test_client_setup_signing_gives_the_vehicle_our_key(tmp_path):
    key_path = _key_file(tmp_path)
    with Rig(INSTANCE, state_dir=tmp_path / "state") as rig:
        rig.client.close()  # the link takes the API link's client port
        link = MavlinkLink.open(f"udpin:127.0.0.1:{14540 + INSTANCE}", signing_key=key_path)
        try:
            rig.step(1.0)
            link.recv(0.2)  # learns the vehicle's address from its telemetry
            link.setup_signing(rig.sys)
            rig.step()
            assert rig.ep.signing.key == KEY
            link.send(M.MAVLink_command_long_message(rig.sys, 1, M.MAV_CMD_REQUEST_MESSAGE, 0,
                                                     148, 0, 0, 0, 0, 0, 0))  # fmt: skip
            rig.step()
            acks = []
            for _ in range(2000):  # one datagram per recv: telemetry queued before the ack
                acks += [m for m in link.recv(0.01) if m.get_type() == "COMMAND_ACK"]
                if acks:
                    break
            assert acks and acks[0].result == M.MAV_RESULT_ACCEPTED
            # From here on the vehicle's telemetry is signed and accepted (the unsigned frames
            # it sent before the key was set were rejected on the way).
            while link.recv(0.01):
                pass
            rejected = link.rejected_packets
            rig.step(1.0)
            got = []
            while batch := link.recv(0.05):
                got += batch
            assert len(got) > 50 and link.rejected_packets == rejected
        finally:
            link.close()


def test_bad_key_files_fail_with_one_line(tmp_path):
    short = tmp_path / "short.key"
    short.write_bytes(b"x" * 31)
    for path in (short, tmp_path / "missing.key"):
        with pytest.raises(sg.SigningError) as e:
            sg.load_key(path)
        assert "\n" not in str(e.value) and str(path) in str(e.value)
        with pytest.raises(sg.SigningError):
            MavlinkLink.open("udpin:127.0.0.1:14603", signing_key=path)
        with pytest.raises(sg.SigningError):
            Rig(INSTANCE, signing_key=path)


def test_client_over_tcp_applies_the_same_rules(tmp_path):
    """A byte stream (TCP): frames split across reads are verified like datagrams."""
    server = socket.socket(socket.AF_INET, socket.SOCK_STREAM)
    server.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
    server.bind(("127.0.0.1", 14540 + 64))
    server.listen(1)
    link = MavlinkLink.open(f"tcp:127.0.0.1:{14540 + 64}", signing_key=_key_file(tmp_path))
    conn, _ = server.accept()
    try:
        peer = Peer()
        mav = peer.mav
        hb = [mav.heartbeat_encode(6, 8, 0, k, 0) for k in range(4)]
        stream = bytes(hb[0].pack(mav))  # unsigned
        _sign_with_pymavlink(peer, KEY)
        signed = bytes(hb[1].pack(mav))
        stream += signed + signed + bytes(hb[2].pack(mav))  # a replay in the middle
        for i in range(0, len(stream), 7):  # 7-byte pieces: frames span reads
            conn.sendall(stream[i : i + 7])
        got = []
        for _ in range(50):
            got += link.recv(0.05)
            if len(got) >= 2:
                break
        assert [m.custom_mode for m in got] == [1, 2] and link.rejected_packets == 2
        peer.close()
    finally:
        conn.close()
        server.close()
        link.close()


def test_our_verify_on_pymavlink_frames_and_rekeying():
    mav = M.MAVLink(None, 255, 190)
    mav.signing.secret_key, mav.signing.sign_outgoing = KEY, True
    mav.signing.timestamp = sg.now_units()
    frame = bytes(mav.heartbeat_encode(6, 8, 0, 0, 0).pack(mav))
    s = sg.Signing(KEY)
    assert s.verify(frame, 0, 255, 190) is None
    s.set_key(KEY)  # the same key again (a repeated SETUP_SIGNING): still a replay
    assert s.verify(frame, 0, 255, 190) == "replayed"
    s.set_key(OTHER_KEY)
    assert s.verify(frame, 0, 255, 190) == "bad signature"
    # And pymavlink verifies what we sign.
    vehicle = M.MAVLink(None, 1, 1)
    unsigned = bytes(vehicle.heartbeat_encode(2, 12, 0, 0, 0).pack(vehicle))
    ours = sg.Signing(KEY).sign(unsigned, link_id=5)
    (m,) = _verifier(KEY).parse_buffer(ours)
    assert m.get_signed() and m.get_type() == "HEARTBEAT" and ours[-13] == 5


def test_a_stream_instants_batch_is_signed_frame_by_frame_and_verifies_in_pymavlink():
    """`Codec.pack_payloads`: one clock reading for the batch, each frame its own signature and
    the next timestamp; pymavlink reads all of them from one datagram, and our verifier refuses
    the same datagram a second time (replays)."""
    from skyherd.flight.mavlink.codec import Codec
    from skyherd.flight.mavlink.payload import packer

    hb, pos = packer(M.MAVLINK_MSG_ID_HEARTBEAT), packer(M.MAVLINK_MSG_ID_LOCAL_POSITION_NED)
    payloads = [hb(2, 12, 0, 0, 3), pos(1000, 1.0, 2.0, -3.0, 0.1, 0.2, 0.3), hb(2, 12, 0, 0, 4)]
    tx = Codec(7, 1, sg.Signing(KEY), link_id=1)
    frames = tx.pack_payloads(payloads)
    stamps = [int.from_bytes(f[-12:-6], "little") for f in frames]
    assert stamps == [stamps[0], stamps[0] + 1, stamps[0] + 2] and tx.signing.timestamp == stamps[2]
    assert [f[4] for f in frames] == [0, 1, 2] and all(f[-13] == 1 for f in frames)  # seq, link
    msgs = _verifier(KEY).parse_buffer(b"".join(frames))
    assert [m.get_type() for m in msgs] == ["HEARTBEAT", "LOCAL_POSITION_NED", "HEARTBEAT"]
    assert all(m.get_signed() for m in msgs) and msgs[1].z == -3.0
    rx = Codec(255, 190, sg.Signing(KEY))
    assert len(rx.parse(b"".join(frames))) == 3 and rx.stats.rx_rejected == 0
    assert rx.parse(b"".join(frames)) == [] and rx.stats.rx_rejected == 3
    assert tx.pack_payloads(payloads[:1])[0][-12:-6] != frames[0][-12:-6]  # time moves on
