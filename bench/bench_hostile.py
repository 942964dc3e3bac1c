"""Benchmark: the vehicle's MAVLink endpoint under hostile floods (issue 11, item 8).

Three floods of real UDP datagrams into one endpoint (instance 60, the quadrotor hovering,
the SITL runner's own `step()` = autopilot step + `endpoint.update()`), each measured in the
same run:

    baseline        N HEARTBEATs from one sender (what a link costs anyway)
    param lists     N PARAM_REQUEST_LIST, each from a distinct (system, component)
    commands        N COMMAND_LONG, each a distinct (system, component, command)

Printed per flood: packets per second through the endpoint (wall, and per CPU second of this
process, the steadier figure on a shared machine), the slowest single step in CPU time (the
simulation "freezes" that long), the RSS growth of this process, the sizes of the endpoint's
per-requester tables, and the ratio to the baseline.

    .venv/bin/python bench/bench_hostile.py [--quick]
"""

from __future__ import annotations

import argparse
import gc
import socket
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from pymavlink.dialects.v20 import ardupilotmega as M  # noqa: E402

from skyherd.flight.airframes_registry import make_autopilot  # noqa: E402
from skyherd.flight.clock import SimClock  # noqa: E402
from skyherd.flight.mavlink import EndpointConfig  # noqa: E402
from skyherd.flight.sitl import Sitl  # noqa: E402
from skyherd.runio.ports import LOOPBACK, api_remote_port  # noqa: E402
from skyherd.runio.runfolder import markdown_table  # noqa: E402

INSTANCE = 60  # mav helper's instances: 60-64
SYS = 1 + INSTANCE
BATCH = 100  # datagrams sent before the endpoint catches up (stays under the socket buffer)


def _rss_mb() -> float:
    with open("/proc/self/statm") as f:
        pages = int(f.read().split()[1])
    return pages * 4096 / 1e6


def _frames(kind: str, n: int) -> list[bytes]:
    out = []
    for i in range(n):
        sysid, compid = 1 + (i // 256) % 254, i % 256
        mav = M.MAVLink(
            None, sysid if kind != "baseline" else 255, compid if kind != "baseline" else 190
        )
        if kind == "baseline":
            msg = mav.heartbeat_encode(6, 8, 0, 0, 0)
        elif kind == "params":
            msg = mav.param_request_list_encode(SYS, 1)
        else:  # distinct (sender, command): unknown commands are answered UNSUPPORTED
            cmd = 40_000 + i // (254 * 256)
            msg = mav.command_long_encode(SYS, 1, cmd, 0, 0, 0, 0, 0, 0, 0, 0)
        out.append(bytes(msg.pack(mav)))
    return out


def _tables(ep) -> str:
    p = ep.params
    q = len(p._queue) if hasattr(p, "_queue") else 0
    q = p.queued() if hasattr(p, "queued") else q
    return f"param queue {q}, retry table {len(ep.commands._last)}"


def flood(kind: str, n: int, drain_sim_s: float = 2.0) -> dict:
    frames = _frames(kind, n)
    ap = make_autopilot("quadrotor", clock=SimClock())
    ap.arm()
    ap.takeoff(10.0)
    gc.collect()
    with Sitl(ap, EndpointConfig(instance=INSTANCE), speedup=0.0) as sitl:
        for _ in range(500):  # 2 s of simulation: airborne, streams running
            sitl.step()
        link = sitl.endpoint.api
        tx = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        tx.bind(("127.0.0.1", 0))
        rx = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)  # the replies' default peer
        rx.bind((LOOPBACK, api_remote_port(INSTANCE)))
        rx.setblocking(False)
        rss0, rx0 = _rss_mb(), link.rx_datagrams
        worst = 0.0
        t0, c0 = time.perf_counter(), time.process_time()
        try:
            for i in range(0, n, BATCH):
                for f in frames[i : i + BATCH]:
                    tx.sendto(f, link.bind_addr)
                while link.rx_datagrams - rx0 < min(i + BATCH, n):
                    s0 = time.process_time()
                    sitl.step()
                    worst = max(worst, time.process_time() - s0)
                    _drain(rx)
            t_rx, c_rx = time.perf_counter() - t0, time.process_time() - c0
            t_end = sitl.clock.t + drain_sim_s  # the replies still queued go out
            while sitl.clock.t < t_end:
                s0 = time.process_time()
                sitl.step()
                worst = max(worst, time.process_time() - s0)
                _drain(rx)
            wall = time.perf_counter() - t0
        finally:
            tx.close()
            rx.close()
        gc.collect()
        return {
            "kind": kind,
            "n": n,
            "pps": n / t_rx,
            "pps_cpu": n / c_rx,
            "wall": wall,
            "worst_ms": worst * 1e3,
            "rss_mb": _rss_mb() - rss0,
            "tables": _tables(sitl.endpoint),
            "handler_errors": sitl.endpoint.stats["rx_handler_error"],
        }


def _drain(sock: socket.socket) -> None:
    while True:
        try:
            sock.recv(65535)
        except BlockingIOError:
            return


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--quick", action="store_true", help="2,000 list requests, 30,000 commands")
    p.add_argument("--params", type=int, default=None, help="PARAM_REQUEST_LIST count (2000)")
    p.add_argument("--commands", type=int, default=None, help="COMMAND_LONG count (300000)")
    args = p.parse_args(argv)
    n_par = args.params or 2000
    n_cmd = args.commands or (30_000 if args.quick else 300_000)
    make_autopilot("quadrotor").step()  # compile (numba) outside the timings
    runs = [flood("baseline", n_cmd), flood("params", n_par), flood("commands", n_cmd)]
    base = runs[0]
    rows = [
        [r["kind"], f"{r['n']}", f"{r['pps']:.0f}", f"{r['pps_cpu']:.0f}",
         f"{r['pps_cpu'] / base['pps_cpu']:.2f}",
         f"{r['worst_ms']:.1f}", f"{r['rss_mb']:+.1f}", r["tables"], f"{r['handler_errors']}"]
        for r in runs
    ]  # fmt: skip
    print("hostile floods into one endpoint (quadrotor hovering, real UDP, SITL step loop)\n")
    head = ["flood", "packets", "packets/s (wall)", "packets/CPU-s", "vs baseline (CPU)",
            "slowest step [CPU ms]", "RSS [MB]",
            "tables after", "handler errors"]  # fmt: skip
    print(markdown_table(head, rows))
    print(
        "\nRSS: growth of this process over the flood (the tables' memory; the kernel keeps freed pages)"
    )
    return 0


if __name__ == "__main__":
    sys.exit(main())
