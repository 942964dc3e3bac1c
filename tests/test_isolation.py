"""The suite's own network namespace (tests/conftest.py): another skyherd vehicle on the machine
sending to UDP 14550 is not heard here."""

import os
import socket
import subprocess
import sys

import conftest
import pytest
from conftest import NETWORK

needs_own = pytest.mark.skipif(
    NETWORK != "its own (loopback only)", reason=f"the session runs in {NETWORK}"
)


@needs_own
def test_the_session_has_its_own_network_namespace():
    fd = conftest.MACHINE_NETNS_FD
    assert os.readlink("/proc/self/ns/net") != os.readlink(f"/proc/self/fd/{fd}")
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:  # loopback is up
        s.bind(("127.0.0.1", 0))
        s.sendto(b"x", s.getsockname())
        assert s.recv(8) == b"x"


@needs_own
def test_a_vehicle_in_the_machines_namespace_is_not_heard():
    """A sender in the machine's namespace (setns to the namespace the session left) reaches its
    own 127.0.0.1:14550, not ours: the test's socket on 14550 receives none of its datagrams."""
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.bind(("127.0.0.1", 14550))
        s.settimeout(0.5)
        fd = conftest.MACHINE_NETNS_FD
        send = (
            "import ctypes, os, socket\n"
            f"assert ctypes.CDLL(None, use_errno=True).setns({fd}, 0x40000000) == 0\n"
            f"assert os.readlink('/proc/self/ns/net') == os.readlink('/proc/self/fd/{fd}')\n"
            "s = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)\n"
            "for _ in range(50): s.sendto(b'HEARTBEAT', ('127.0.0.1', 14550))\n"
            "print('sent')"
        )
        out = subprocess.run([sys.executable, "-c", send], pass_fds=(fd,), capture_output=True,
                             text=True, timeout=60)  # fmt: skip
        assert out.returncode == 0 and out.stdout.strip() == "sent", out.stderr
        with pytest.raises(TimeoutError):
            s.recv(64)
