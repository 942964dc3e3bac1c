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
from pathlib import Path

import pytest

A_IP, B_IP = "10.213.0.1", "10.213.0.2"  # test hosts inside namespaces made below
INSTANCE = 17
PEER = Path(__file__).resolve().parents[1] / "zenoh_peer.py"


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


@pytest.mark.slow
def test_sim_and_companion_on_two_hosts_fly_through_a_router(two_hosts, tmp_path):
    ns_a, ns_b = two_hosts
    run = tmp_path / "run"
    run.mkdir()
    router = _zenoh_config(tmp_path / "router.json5", "router", "listen")
    client = _zenoh_config(tmp_path / "client.json5", "client", "connect")
    skyherd = [sys.executable, "-m", "skyherd.scripts.cli"]
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


def _peer(ns: str, config, tag: str, *args: str, timeout_s: float = 180.0) -> dict:
    """tests/zenoh_peer.py in namespace `ns`: its JSON result line."""
    r = subprocess.run(["ip", "netns", "exec", ns, sys.executable, str(PEER), str(config),
                        "--tag", tag, *args], capture_output=True, text=True, timeout=timeout_s)  # fmt: skip
    lines = [x for x in r.stdout.splitlines() if x.startswith("{")]
    assert lines, f"{tag}: no result ({r.returncode}): {r.stderr[-1500:]}"
    return json.loads(lines[-1])


@pytest.mark.slow
def test_a_closed_two_host_flight_mutual_tls_and_access_control_wallclock(two_hosts, tmp_path):
    """`skyherd certs` for the router's address; the flight through a router that takes only
    mutual TLS, then who may do what on that router: a plain TCP client and a certificate of
    another CA are not let in; the viewer watches but its frames never arrive; the companion's
    decisions arrive, its frames do not. Wall time: each peer waits at most its --timeout (the
    denials are read off the router after a later allowed message has come through)."""
    from skyherd.scripts.cli import main

    ns_a, ns_b = two_hosts
    pki, rogue = tmp_path / "pki", tmp_path / "rogue"
    assert main(["certs", "--out", str(pki), "--router-host", A_IP]) == 0
    assert main(["certs", "--out", str(rogue), "--router-host", A_IP]) == 0  # another CA
    run = tmp_path / "run"
    run.mkdir()
    skyherd = [sys.executable, "-m", "skyherd.scripts.cli"]
    sim = subprocess.Popen(
        ["ip", "netns", "exec", ns_a, *skyherd, "sim", "--instance", str(INSTANCE), "--speedup", "0",
         "--bind", A_IP, "--remote", B_IP, "--zenoh-config", str(pki / "router.json5"),
         "--run-dir", str(run)],
        stdout=open(run / "sim.log", "wb"), stderr=subprocess.STDOUT,
    )  # fmt: skip
    try:
        comp = subprocess.run(
            ["ip", "netns", "exec", ns_b, *skyherd, "companion", "--instance", str(INSTANCE),
             "--connect", f"udpin:{B_IP}:{14540 + INSTANCE}", "--zenoh-config",
             str(pki / "companion.json5"), "--duration", "5", "--run-dir", str(run)],
            capture_output=True, text=True, timeout=900,
        )  # fmt: skip
    finally:
        sim.send_signal(2)
        sim.wait(30)
    assert comp.returncode == 0, comp.stderr[-2000:]
    out = json.loads((run / "companion.json").read_text())
    assert (
        out["outcome"] == "completed" and out["frames"]["ok"] >= 50 and out["frames"]["lost"] == 0
    )

    frame, decision = "skyherd/uav0/camera/frame", "skyherd/uav0/decision"
    router = subprocess.Popen(
        ["ip", "netns", "exec", ns_a, sys.executable, str(PEER), str(pki / "router.json5"),
         "--tag", "sim", "--sub", "skyherd/**", "--beat", frame, "--until", "companion-end",
         "--timeout", "300"], stdout=subprocess.PIPE, text=True,
    )  # fmt: skip
    try:
        assert router.stdout.readline().strip() == "ready"
        tcp = tmp_path / "plain.json5"
        tcp.write_text(json.dumps({"mode": "client", "connect": {"endpoints": [f"tcp/{A_IP}:7447"]},
                                   "scouting": {"multicast": {"enabled": False}}}))  # fmt: skip
        plain = _peer(ns_b, tcp, "plain", "--sub", "skyherd/**", "--until", "sim", "--timeout", "5")
        other_ca = _peer(ns_b, rogue / "companion.json5", "rogue", "--sub", "skyherd/**",
                         "--until", "sim", "--timeout", "5")  # fmt: skip
        viewer = _peer(ns_b, pki / "viewer.json5", "viewer", "--sub", "skyherd/**", "--until",
                       "sim", "--put", frame, "--n", "20", "--timeout", "60")  # fmt: skip
        comp_frames = _peer(ns_b, pki / "companion.json5", "companion-frame", "--put", frame,
                            "--n", "20")  # fmt: skip
        comp_dec = _peer(ns_b, pki / "companion.json5", "companion", "--put", decision,
                         "--n", "20", "--end")  # fmt: skip
        got = json.loads(router.communicate(timeout=300)[0].strip().splitlines()[-1])["got"]
    finally:
        if router.poll() is None:
            router.kill()
    for refused in (plain, other_ca):  # not let in: no session, or a session that hears nothing
        assert refused["open"] != "ok" or not refused["got"].get("sim"), refused
    assert viewer["open"] == "ok" and viewer["got"].get("sim", 0) > 0  # it watches ...
    assert got.get("viewer", 0) == 0  # ... and its 20 frames never reached the router
    assert comp_frames["open"] == "ok" and got.get("companion-frame", 0) == 0
    assert comp_dec["open"] == "ok" and got.get("companion") == 20 and got.get("companion-end") == 1
    assert got.get("sim", 0) > 0
