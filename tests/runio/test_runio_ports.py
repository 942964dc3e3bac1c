"""runio.ports.taken_udp_port: the probe `skyherd fly --mission formation` runs before it starts
K vehicles (pytest's own network namespace: nothing else binds these ports)."""

from __future__ import annotations

import socket

import pytest

from skyherd.runio import ports


def test_a_taken_port_is_named_with_its_instance_and_the_probe_keeps_nothing_bound():
    assert ports.taken_udp_port([152, 153]) is None
    assert ports.taken_udp_port([152, 153]) is None  # the first probe left nothing bound
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.bind((ports.LOOPBACK, ports.api_remote_port(153)))  # instance 153's companion
        inst, port, why = ports.taken_udp_port([152, 153])
    assert (inst, port) == (153, ports.api_remote_port(153)) and why
    assert ports.taken_udp_port([152, 153]) is None


def _bind_all(instances: list[int]) -> str | None:
    """Bind every UDP port these vehicles and their companions listen on, all at once; the
    operating system's refusal, or None if every one binds."""
    held = []
    try:
        for n in instances:
            for port in (ports.api_bind_port(n), ports.gcs_bind_port(n), ports.api_remote_port(n)):
                s = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
                held.append(s)
                try:
                    s.bind((ports.LOOPBACK, port))
                except OSError as e:
                    return f"instance {n} port {port}: {e.strerror}"
        return None
    finally:
        for s in held:
            s.close()


def test_vehicles_flown_together_get_instances_whose_ports_all_bind_at_once():
    chosen = ports.disjoint_instances(0, 60)  # more than 40: the PX4 layout's N/N+40 overlap
    assert len(chosen) == 60 and len(set(chosen)) == 60
    assert 10 not in chosen and not any(n + 40 in chosen for n in chosen)
    assert ports.first_clash(chosen) is None
    assert _bind_all(chosen) is None  # the operating system agrees: no port is shared
    assert ports.disjoint_instances(0, 16) == [*range(10), *range(11, 17)]  # the formation's


def test_the_layouts_own_overlaps_are_found_and_the_os_agrees():
    assert ports.first_clash([0, 40]) == (0, 40, ports.api_bind_port(0))
    assert _bind_all([0, 40]) is not None  # 40's companion port is 0's API port
    assert ports.first_clash([3, 10]) == (10, 10, ports.GCS_REMOTE_PORT)
    assert ports.first_clash([*range(10), *range(11, 40)]) is None


def test_instances_past_the_last_are_refused_with_what_to_do():
    with pytest.raises(ValueError, match="pick a smaller base instance"):
        ports.disjoint_instances(150, 60)
