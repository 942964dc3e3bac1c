"""A Zenoh peer for the two-host tests (run as a script, in a network namespace): open a
session from a configuration, count what arrives on a key by the payload's tag (the text before
the first ':'), put tagged payloads, and print one JSON line: {"open": "ok" | error, "got":
{tag: n}}.

    python tests/zenoh_peer.py CONFIG --tag viewer --put skyherd/uav0/camera/frame --n 20
    python tests/zenoh_peer.py CONFIG --tag sim --sub 'skyherd/**' --beat skyherd/uav0/camera/frame \
        --until companion-end --timeout 120

--beat KEY publishes on KEY every 50 ms while it runs (the router's own world); --until TAG ends
once a payload tagged TAG arrived (or at --timeout). --end puts one payload tagged
<tag>-end on the --put key last, after the others.
"""

import argparse
import json
import sys
import time

import zenoh


def main() -> int:
    ap = argparse.ArgumentParser()
    ap.add_argument("config")
    ap.add_argument("--tag", required=True)
    ap.add_argument("--sub", default=None)
    ap.add_argument("--put", default=None)
    ap.add_argument("--n", type=int, default=0)
    ap.add_argument("--end", action="store_true")
    ap.add_argument("--beat", default=None)
    ap.add_argument("--until", default=None)
    ap.add_argument("--settle", type=float, default=1.0, help="[s] after opening, before putting")
    ap.add_argument("--timeout", type=float, default=30.0)
    a = ap.parse_args()
    got: dict[str, int] = {}
    try:
        s = zenoh.open(zenoh.Config.from_file(a.config))
    except Exception as e:  # noqa: BLE001 - the refusal is the result
        print(json.dumps({"open": f"{type(e).__name__}: {e}", "got": got}))
        return 0

    def on(sample) -> None:
        tag = sample.payload.to_bytes().split(b":", 1)[0].decode(errors="replace")
        got[tag] = got.get(tag, 0) + 1

    if a.sub:
        s.declare_subscriber(a.sub, on)
    print("ready", flush=True)
    end = time.monotonic() + a.timeout
    time.sleep(a.settle)
    for i in range(a.n):
        s.put(a.put, f"{a.tag}:{i}".encode())
        time.sleep(0.02)
    if a.end:
        s.put(a.put, f"{a.tag}-end:".encode())
    while time.monotonic() < end and (a.until is None or a.until not in got):
        if a.beat:
            s.put(a.beat, f"{a.tag}:beat".encode())
        time.sleep(0.05)
        if a.until is None and not a.beat:
            break
    time.sleep(0.5)
    print(json.dumps({"open": "ok", "got": got}), flush=True)
    s.close()
    return 0


if __name__ == "__main__":
    sys.exit(main())
