"""runio.ports.taken_udp_port: the probe `skyherd fly --mission formation` runs before it starts
K vehicles (pytest's own network namespace: nothing else binds these ports)."""

from __future__ import annotations

import socket

from skyherd.runio import ports


def test_a_taken_port_is_named_with_its_instance_and_the_probe_keeps_nothing_bound():
    assert ports.taken_udp_port([152, 153]) is None
    assert ports.taken_udp_port([152, 153]) is None  # the first probe left nothing bound
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.bind((ports.LOOPBACK, ports.api_remote_port(153)))  # instance 153's companion
        inst, port, why = ports.taken_udp_port([152, 153])
    assert (inst, port) == (153, ports.api_remote_port(153)) and why
    assert ports.taken_udp_port([152, 153]) is None
