"""Benchmark: the MAVLink endpoint's CPU against its autopilot's, for a hovering vehicle with a
formation's streams (issue 31 item 1: "endpoint CPU ≤ 1.0× the autopilot's").

The vehicle: the quadrotor (autopilot 250 Hz, physics 1 kHz) hovering at 10 m, run by the SITL
runner (`flight.sitl.Sitl.run`, as `skyherd sitl` runs it) unpaced (speed-up 0), signing on (a
key, as `skyherd fly` runs it). Its streams are a formation simulator's: on the API link every
default stream but the ones a formation companion turns off (`mission.steps.UNREAD_STREAMS`,
by SET_MESSAGE_INTERVAL as `quiet_streams` does), drained by a separate receiver process bound
where the companion listens (127.0.0.1:14540+N); on the ground-station link nobody at 14550
(its heartbeat only), as in `skyherd fly`.

Measured in each round, alternately: the autopilot alone (`ap.step()` for the same simulated
time: the cost the target is defined against) and the vehicle with its endpoint; the endpoint's
cost is the difference. Printed: CPU per simulated second of each (median over the rounds) and
the ratio endpoint / autopilot. With `--baseline REV` the same measurement runs, alternately,
on the tree at git revision REV (exported to a temporary directory) and on this tree, each
round in a fresh child process: the before/after figures of one run.

    .venv/bin/python bench/bench_endpoint.py [--quick] [--baseline REV] [--instance N]
"""

from __future__ import annotations

import argparse
import json
import socket
import statistics
import subprocess
import sys
import tarfile
import tempfile
import time
from io import BytesIO
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
KEEP_DATAGRAMS = 2000  # API datagrams kept for the companion's receive path (formation set)
SETS = {  # stream sets measured, each against the autopilot alone measured just before it
    "formation": "API link: the streams a formation companion reads; nobody at 14550",
    "all": "every default stream on both links, a ground station listening at 14550",
}

RECEIVER = r"""
import socket, sys
s = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
s.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 4 << 20)
s.bind(("127.0.0.1", int(sys.argv[1])))
print("ready", flush=True)
while s.recv(65535) != b"stop":
    pass
"""


def receiver(port: int) -> subprocess.Popen:
    """A process that reads what arrives at 127.0.0.1:`port` (a companion, a ground station)."""
    p = subprocess.Popen([sys.executable, "-c", RECEIVER, str(port)], stdout=subprocess.PIPE,
                         stderr=subprocess.DEVNULL, text=True)  # fmt: skip
    RECEIVERS.append(p)
    assert p.stdout.readline().strip() == "ready"
    return p


def stop(p: subprocess.Popen, port: int) -> None:
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.sendto(b"stop", ("127.0.0.1", port))
    p.wait(timeout=30)
    RECEIVERS.remove(p)


RECEIVERS: list[subprocess.Popen] = []  # running; ended by `main` whatever happens


def measure(instance: int, sim_s: float, rounds: int) -> dict:
    """In this process (the tree on sys.path): `rounds` rounds of the autopilot alone and each
    stream set (`SETS`), alternated; CPU s per simulated s and the endpoint / autopilot ratios."""
    from pymavlink.dialects.v20 import ardupilotmega as M

    from skyherd.flight.airframes_registry import make_autopilot
    from skyherd.flight.clock import SimClock
    from skyherd.flight.mavlink import EndpointConfig
    from skyherd.flight.mavlink.streams import DEFAULT_RATES_HZ
    from skyherd.flight.sitl import Sitl
    from skyherd.mission.steps import UNREAD_STREAMS
    from skyherd.runio.ports import api_remote_port

    unread = {getattr(M, f"MAVLINK_MSG_ID_{n}") for n in UNREAD_STREAMS}
    recv = receiver(api_remote_port(instance))
    out: dict = {}
    with tempfile.TemporaryDirectory() as tmp:
        key = Path(tmp) / "bench.key"
        key.write_bytes(bytes(range(32)))
        ap = make_autopilot("quadrotor", clock=SimClock())
        cfg = EndpointConfig(instance=instance, signing_key=key)
        with Sitl(ap, cfg, speedup=0.0) as sitl:
            ep = sitl.endpoint

            def streams(name: str) -> None:
                for m in DEFAULT_RATES_HZ:
                    ep.streams["api"].set_interval(
                        m, -1 if name == "formation" and m in unread else 0
                    )
                    ep.streams["gcs"].set_interval(m, 0)

            assert ap.arm().ok and ap.takeoff(10.0).ok
            sitl.run(duration_s=15.0)  # climbed, holding 10 m (and numba's kernels loaded)
            n = round(sim_s / ap.control_dt)
            cost = {"autopilot": [], **{name: [] for name in SETS}}
            frames = {name: {link.name: 0 for link in ep.links} for name in SETS}
            datagrams = {name: {link.name: 0 for link in ep.links} for name in SETS}
            sent = {link.name: 0 for link in ep.links}  # datagrams each link sent (sendto)
            kept = {"on": False, "datagrams": []}  # the API link's, in the formation's rounds
            for link in ep.links:
                link._sendto = _counted(link._sendto, sent, link.name,
                                        kept if link is ep.api else None)  # fmt: skip
            for _ in range(rounds):
                for name in SETS:
                    c0 = time.process_time()
                    for _ in range(n):
                        ap.step()
                    cost["autopilot"].append((time.process_time() - c0) / sim_s)
                    streams(name)
                    gcs = receiver(cfg.gcs_remote[1]) if name == "all" else None  # listens
                    kept["on"] = name == "formation"  # what a formation's companion receives
                    tx0 = {link.name: link.codec.stats.tx_frames for link in ep.links}
                    sent0 = dict(sent)
                    c0 = time.process_time()
                    sitl.run(duration_s=sim_s)
                    cost[name].append((time.process_time() - c0) / sim_s)
                    for link in ep.links:
                        frames[name][link.name] += link.codec.stats.tx_frames - tx0[link.name]
                        datagrams[name][link.name] += sent[link.name] - sent0[link.name]
                    if gcs is not None:
                        stop(gcs, cfg.gcs_remote[1])
                    if abs(ap.state.altitude - 10.0) > 0.5:  # e.g. a low battery's landing
                        raise SystemExit(f"the vehicle left its hover ({ap.mode.name} at "
                                         f"{ap.state.altitude:.1f} m, t = {ap.clock.t:.0f} s): "
                                         "fewer rounds or shorter ones")  # fmt: skip
            out["altitude"] = float(ap.state.altitude)
            dgs = kept["datagrams"]  # the companion's share: these datagrams' simulated time
            dg_per_s = datagrams["formation"]["api"] / (rounds * sim_s)
            out["companion"] = companion_cost(dgs, key, rounds, len(dgs) / dg_per_s)
            out["signed"] = ep.signing.enabled
    stop(recv, api_remote_port(instance))
    alone = cost["autopilot"]
    out["autopilot"] = statistics.median(alone)
    for i, name in enumerate(SETS):
        mine = cost[name]
        pairs = [(y - x) / x for x, y in zip(alone[i :: len(SETS)], mine, strict=True)]
        out[name] = {
            "with_endpoint": statistics.median(mine),
            "endpoint": statistics.median(mine) - out["autopilot"],
            "ratio": statistics.median(pairs),
            "pair_ratios": pairs,
            "frames_per_sim_s": {k: v / (sim_s * rounds) for k, v in frames[name].items()},
            "datagrams_per_sim_s": {k: v / (sim_s * rounds) for k, v in datagrams[name].items()},
        }
    return out


def companion_cost(dgs: list[bytes], key: Path, rounds: int, sim_s: float) -> dict:
    """The companion's receive path on the vehicle's signed datagrams (`hil.link.MavlinkLink`
    parses each with its Codec: signatures verified, messages decoded): CPU s per simulated
    s, a fresh receiver per round (the same frames again would be replays)."""
    from skyherd.flight.mavlink.codec import Codec
    from skyherd.flight.mavlink.signing import Signing, load_key

    costs, frames = [], 0
    for _ in range(rounds):
        rx = Codec(255, 190, Signing(load_key(key)))
        c0 = time.process_time()
        for dg in dgs:
            frames += len(rx.parse(dg))
        costs.append((time.process_time() - c0) / sim_s)
    return {"parse": statistics.median(costs), "frames": frames / rounds,
            "rejected": rx.stats.rx_rejected}  # fmt: skip


def _counted(sendto, sent: dict, name: str, keep: dict | None = None):
    """`sendto` counting its datagrams; with `keep`, keeping them while keep["on"]."""

    def counted(buf, addr):
        sent[name] += 1
        if keep is not None and keep["on"] and len(keep["datagrams"]) < KEEP_DATAGRAMS:
            keep["datagrams"].append(bytes(buf))
        return sendto(buf, addr)

    return counted


def export_tree(rev: str, dest: Path) -> Path:
    """The tree of git revision `rev` of this repository, written under `dest`."""
    data = subprocess.run(["git", "-C", str(ROOT), "archive", rev], check=True,
                          capture_output=True).stdout  # fmt: skip
    with tarfile.open(fileobj=BytesIO(data)) as tar:
        tar.extractall(dest, filter="data")
    return dest


def child(tree: Path, instance: int, sim_s: float, rounds: int) -> dict:
    out = subprocess.run(
        [sys.executable, __file__, "--child", str(tree), "--instance", str(instance),
         "--sim-s", str(sim_s), "--rounds", str(rounds)],
        capture_output=True, text=True, check=True,
    ).stdout  # fmt: skip
    return json.loads(out.splitlines()[-1])


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--quick", action="store_true", help="shorter runs (3 rounds of 20 s)")  # noqa: E501
    p.add_argument("--sim-s", type=float, default=None, help="simulated seconds per measurement")
    p.add_argument("--rounds", type=int, default=None, help="alternated pairs per process")
    p.add_argument("--baseline", metavar="REV", help="also measure git revision REV, alternately")
    p.add_argument("--repeats", type=int, default=3, help="child processes per tree (--baseline)")
    p.add_argument("--instance", type=int, default=22, help="vehicle instance (ports 14540+N...)")
    p.add_argument("--child", metavar="TREE", help=argparse.SUPPRESS)
    args = p.parse_args(argv)
    sim_s = args.sim_s or (20.0 if args.quick else 30.0)  # 4 x 5 x 30 s: hovers on one battery
    rounds = args.rounds or (3 if args.quick else 5)
    try:
        return run(args, sim_s, rounds)
    finally:
        for r in RECEIVERS:
            r.kill()
            r.wait()


def run(args: argparse.Namespace, sim_s: float, rounds: int) -> int:
    if args.child:
        sys.path.insert(0, args.child)
        print(json.dumps(measure(args.instance, sim_s, rounds)))
        return 0
    sys.path.insert(0, str(ROOT))
    from skyherd.runio.runfolder import markdown_table

    print(f"endpoint benchmark: hovering quadrotor, signing on, speed-up 0; per process "
          f"{rounds} rounds of {sim_s:g} s simulated: the autopilot alone, then the vehicle "
          "with its endpoint, for each stream set:")  # fmt: skip
    for name, what in SETS.items():
        print(f"  {name}: {what}")
    print()
    head = ["tree", "streams", "autopilot [ms CPU / sim s]", "with endpoint", "endpoint",
            "endpoint / autopilot", "per round", "frames / sim s (api, gcs)",
            "datagrams / sim s (api, gcs)"]  # fmt: skip

    def rows_of(tree: str, r: dict) -> list[list[str]]:
        rows = []
        for name in SETS:
            m = r[name]
            f, d = m["frames_per_sim_s"], m["datagrams_per_sim_s"]
            rows.append([tree, name, f"{r['autopilot'] * 1e3:.3f}", f"{m['with_endpoint'] * 1e3:.3f}",
                         f"{m['endpoint'] * 1e3:.3f}", f"{m['ratio']:.2f}x",
                         " ".join(f"{x:.2f}" for x in m["pair_ratios"]),
                         f"{f['api']:.1f}, {f['gcs']:.1f}", f"{d['api']:.1f}, {d['gcs']:.1f}"])  # fmt: skip
        return rows

    if not args.baseline:
        r = measure(args.instance, sim_s, rounds)
        print(markdown_table(head, rows_of("this tree", r)))
        c = r["companion"]
        print(f"\ncompanion receive path (formation, signed): {c['parse'] * 1e3:.3f} ms CPU / sim s "
              f"({c['frames']:.0f} frames a round, {c['rejected']} refused)")  # fmt: skip
        print("endpoint CPU / the autopilot's (target <= 1.0x, formation): "
              + ", ".join(f"{name} {r[name]['ratio']:.2f}x" for name in SETS)
              + f"; altitude {r['altitude']:.2f} m, signed {r['signed']}")  # fmt: skip
        return 0
    with tempfile.TemporaryDirectory() as tmp:
        base = export_tree(args.baseline, Path(tmp) / "base")
        child(base, args.instance, 2.0, 1)  # numba compiles the baseline tree's kernels once
        rows, ratios = [], {(t, n): [] for t in ("baseline", "this tree") for n in SETS}
        parse: dict[str, list[float]] = {"baseline": [], "this tree": []}
        for i in range(args.repeats):  # alternated: baseline, this tree, baseline, ...
            for tree, path in (("baseline", base), ("this tree", ROOT)):
                r = child(path, args.instance, sim_s, rounds)
                for name in SETS:
                    ratios[(tree, name)].append(r[name]["ratio"])
                parse[tree].append(r["companion"]["parse"])
                label = f"{args.baseline}" if tree == "baseline" else "working tree"
                rows += rows_of(f"{label} #{i + 1}", r)
    print(markdown_table(head, rows))
    print(f"\nendpoint CPU / the autopilot's, median of {args.repeats} processes per tree "
          "(target <= 1.0x with the formation's streams):")  # fmt: skip
    for name in SETS:
        mb = statistics.median(ratios[("baseline", name)])
        mt = statistics.median(ratios[("this tree", name)])
        print(f"  {name}: baseline {mb:.2f}x, this tree {mt:.2f}x ({mb / mt:.1f}x less)")
    pb, pt = statistics.median(parse["baseline"]), statistics.median(parse["this tree"])
    print(f"companion receive path (the formation's signed datagrams parsed and verified), "
          f"ms CPU / sim s: baseline {pb * 1e3:.3f}, this tree {pt * 1e3:.3f} ({pb / pt:.1f}x less)")  # fmt: skip
    return 0


if __name__ == "__main__":
    sys.exit(main())
