"""Past one machine: `skyherd sim` on one host and `skyherd companion` on another, frames through
a Zenoh router, MAVLink over UDP to the other host, a flight completed.

The two hosts are network namespaces this test creates (a veth pair with private test
addresses, nothing else), removed afterwards. Zenoh's shared memory is off, so every frame
crosses the veth link. Skipped, saying why, only where the machine forbids namespaces.
"""

import json
import os
import shutil
import subprocess
import sys
import uuid

import pytest

A_IP, B_IP = "10.213.0.1", "10.213.0.2"  # test hosts inside namespaces made below
INSTANCE = 17


def _ip(*args: str) -> None:
    subprocess.run(["ip", *args], check=True, capture_output=True)


@pytest.fixture
def two_hosts():
    if shutil.which("ip") is None or os.geteuid() != 0:
        pytest.skip("needs root and iproute2 to create network namespaces")
    tag = uuid.uuid4().hex[:6]
    a, b = f"skyherd-a-{tag}", f"skyherd-b-{tag}"
    try:
        _ip("netns", "add", a)
    except subprocess.CalledProcessError as e:
        pytest.skip(f"this machine forbids network namespaces: {e.stderr.decode().strip()}")
    try:
        _ip("netns", "add", b)
        _ip("link", "add", f"sk{tag}a", "type", "veth", "peer", "name", f"sk{tag}b")
        for ns, dev, addr in ((a, f"sk{tag}a", A_IP), (b, f"sk{tag}b", B_IP)):
            _ip("link", "set", dev, "netns", ns)
            _ip("-n", ns, "addr", "add", f"{addr}/30", "dev", dev)
            _ip("-n", ns, "link", "set", dev, "up")
            _ip("-n", ns, "link", "set", "lo", "up")
        yield a, b
    finally:
        for ns in (a, b):
            subprocess.run(["ip", "netns", "del", ns], capture_output=True)


def _zenoh_config(path, mode: str, endpoint_key: str) -> str:
    conf = {"mode": mode, endpoint_key: {"endpoints": [f"tcp/{A_IP}:7447"]},
            "scouting": {"multicast": {"enabled": False}},
            "transport": {"shared_memory": {"enabled": False}}}  # fmt: skip
    path.write_text(json.dumps(conf))
    return str(path)


def test_sim_and_companion_on_two_hosts_fly_through_a_router(two_hosts, tmp_path):
    ns_a, ns_b = two_hosts
    run = tmp_path / "run"
    run.mkdir()
    router = _zenoh_config(tmp_path / "router.json5", "router", "listen")
    client = _zenoh_config(tmp_path / "client.json5", "client", "connect")
    skyherd = [sys.executable, "-m", "scripts.cli"]
    sim = subprocess.Popen(
        ["ip", "netns", "exec", ns_a, *skyherd, "sim", "--instance", str(INSTANCE), "--speedup", "0",
         "--bind", A_IP, "--remote", B_IP, "--zenoh-config", router, "--run-dir", str(run)],
        stdout=open(run / "sim.log", "wb"), stderr=subprocess.STDOUT,
    )  # fmt: skip
    try:
        comp = subprocess.run(
            ["ip", "netns", "exec", ns_b, *skyherd, "companion", "--instance", str(INSTANCE),
             "--connect", f"udpin:{B_IP}:{14540 + INSTANCE}", "--zenoh-config", client,
             "--duration", "5", "--run-dir", str(run)],
            capture_output=True, text=True, timeout=900,
        )  # fmt: skip
    finally:
        sim.send_signal(2)
        sim.wait(30)
    out = json.loads((run / "companion.json").read_text())
    assert comp.returncode == 0, comp.stderr[-2000:]
    assert out["outcome"] == "completed" and out["decisions"] >= 10
    assert out["frames"]["ok"] >= 50 and out["frames"]["lost"] == 0  # every tick's frame came
    stats = json.loads((run / "sim_stats.json").read_text())
    assert stats["lockstep"] and stats["ticks_closed"] == out["ticks"]
