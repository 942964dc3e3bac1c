"""Benchmark: SITL real-time factor with and without the MAVLink endpoint, and the telemetry
rate it sustains.

Scenario (both runs identical): the quadrotor arms, takes off to 10 m and hovers, autopilot
at 250 Hz with 1 kHz physics. "alone" steps the autopilot only; "with MAVLink" runs the SITL
runner at --speedup 0 with both links streaming at their default rates while a separate
process receives the API link and counts what arrives (and a socket is bound on the ground
stations' port 14550, as QGroundControl binds it: with nobody there the ground-station link
streams only its heartbeat). "signing on" is the same run with a
MAVLink 2 signing key: every frame sent is signed (SHA-256 per frame).

    .venv/bin/python bench/bench_sitl.py [--quick]
"""

from __future__ import annotations

import argparse
import socket
import subprocess
import sys
import tempfile
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from skyherd.flight.airframes_registry import make_autopilot  # noqa: E402
from skyherd.flight.clock import SimClock  # noqa: E402
from skyherd.flight.mavlink import EndpointConfig  # noqa: E402
from skyherd.flight.sitl import Sitl  # noqa: E402
from skyherd.runio.ports import api_remote_port  # noqa: E402
from skyherd.runio.runfolder import markdown_table  # noqa: E402

INSTANCE = 21  # API link: 127.0.0.1:14601 → 14561

RECEIVER = r"""
import socket, sys, time
s = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
s.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 4 << 20)
s.bind(("127.0.0.1", int(sys.argv[1])))
s.settimeout(1.0)
print("ready", flush=True)
n = nbytes = 0
t_first = t_last = None
while True:
    try:
        d = s.recv(65535)
    except socket.timeout:
        if n:
            break
        continue
    t_last = time.monotonic()
    t_first = t_first or t_last
    n += 1
    nbytes += len(d)
print(n, nbytes, (t_last - t_first) if n > 1 else 0.0, flush=True)
"""


def _fly(ap) -> None:
    ap.arm()
    ap.takeoff(10.0)


def bench_alone(sim_s: float) -> tuple[float, float]:
    ap = make_autopilot("quadrotor", clock=SimClock())
    _fly(ap)
    n = round(sim_s / ap.control_dt)
    t0, c0 = time.perf_counter(), time.process_time()
    for _ in range(n):
        ap.step()
    wall, cpu = time.perf_counter() - t0, time.process_time() - c0
    return sim_s / wall, sim_s / cpu, ap.state.altitude


def bench_endpoint(sim_s: float, signing_key: Path | None = None) -> dict:
    recv = subprocess.Popen(
        [sys.executable, "-c", RECEIVER, str(api_remote_port(INSTANCE))],
        stdout=subprocess.PIPE,
        text=True,
    )
    assert recv.stdout.readline().strip() == "ready"
    ap = make_autopilot("quadrotor", clock=SimClock())
    _fly(ap)
    cfg = EndpointConfig(instance=INSTANCE, signing_key=signing_key)
    gcs = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)  # a ground station's port, bound
    try:
        gcs.bind(cfg.gcs_remote)
    except OSError:  # a real ground station has it: it listens too
        pass
    with gcs, Sitl(ap, cfg, speedup=0.0) as sitl:
        c0 = time.process_time()
        stats = sitl.run(duration_s=sim_s)
        cpu = time.process_time() - c0
        tx = {link.name: link.codec.stats.tx_frames for link in sitl.endpoint.links}
        tx_bytes = sum(link.codec.stats.tx_bytes for link in sitl.endpoint.links)
    n_rx, _, _ = (float(v) for v in recv.communicate(timeout=30)[0].split())
    return {
        "rtf": stats.real_time_factor,
        "rtf_cpu": stats.sim_s / cpu,
        "wall": stats.wall_s,
        "tx_per_s": sum(tx.values()) / stats.wall_s,
        "tx_per_sim_s": sum(tx.values()) / stats.sim_s,
        "tx_api": tx["api"],
        "rx_api": int(n_rx),
        "kbytes_per_s": tx_bytes / stats.wall_s / 1e3,
        "altitude": ap.state.altitude,
    }


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--quick", action="store_true", help="shorter runs (20 s of simulation)")
    p.add_argument("--sim-s", type=float, default=None, help="simulated seconds per run")
    args = p.parse_args(argv)
    sim_s = args.sim_s or (20.0 if args.quick else 120.0)
    make_autopilot("quadrotor").step()  # compile (numba) outside the timings
    rtf_alone, cpu_alone, alt_a = bench_alone(sim_s)
    r = bench_endpoint(sim_s)
    with tempfile.TemporaryDirectory() as tmp:
        key = Path(tmp) / "bench.key"
        key.write_bytes(bytes(range(32)))
        rs = bench_endpoint(sim_s, signing_key=key)
    rows = [
        ["autopilot + physics alone", f"{rtf_alone:.0f}x", f"{cpu_alone:.0f}x", "-", "-", f"{alt_a:.2f}"],
        ["with MAVLink endpoint (speedup 0)", f"{r['rtf']:.0f}x", f"{r['rtf_cpu']:.0f}x",
         f"{r['tx_per_s']:.0f}", f"{r['kbytes_per_s']:.0f}", f"{r['altitude']:.2f}"],
        ["with MAVLink endpoint, signing on", f"{rs['rtf']:.0f}x", f"{rs['rtf_cpu']:.0f}x",
         f"{rs['tx_per_s']:.0f}", f"{rs['kbytes_per_s']:.0f}", f"{rs['altitude']:.2f}"],
    ]  # fmt: skip
    print(
        f"SITL benchmark: quadrotor, {sim_s:g} s simulated per run, autopilot 250 Hz, physics 1 kHz\n"
    )
    head = ["run", "real-time factor (wall)", "real-time factor (CPU)", "telemetry msg/s (wall)", "kB/s",
            "final altitude [m]"]  # fmt: skip
    print(markdown_table(head, rows))
    print(
        "CPU: simulated time over this process's CPU time (the wall figure drops on a shared machine)"
    )
    print(
        f"endpoint cost: {cpu_alone / r['rtf_cpu']:.2f}x the CPU per simulated second of the autopilot alone"
    )
    print(
        f"telemetry per simulated second (both links, default rates): {r['tx_per_sim_s']:.1f} messages"
    )
    print(
        f"signing cost: {r['rtf_cpu'] / rs['rtf_cpu']:.2f}x the CPU per simulated second of the unsigned endpoint"
    )
    print(f"API link: {r['tx_api']} sent, {r['rx_api']} received by a separate process "
          f"({100.0 * r['rx_api'] / max(r['tx_api'], 1):.1f} %)")  # fmt: skip
    return 0


if __name__ == "__main__":
    sys.exit(main())
