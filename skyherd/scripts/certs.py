"""`skyherd certs`: the certificates and Zenoh configurations of a closed two-host flight.

A certificate authority of the flight's own, a key and certificate for each role (sim,
companion, viewer), and three Zenoh configurations: `router.json5` for `skyherd sim` (listens
with mutual TLS; access control: only the sim's certificate may publish the world's keys, only
the companion's its decisions and events, the viewer's may only watch), `companion.json5` and
`viewer.json5` (connect with their own certificate, verify the router's address). Copy the
folder to both hosts (each needs ca.pem, its own .pem/.key and its .json5; keep ca.key on
neither), then:

    host A: skyherd sim --bind A --remote B --zenoh-config DIR/router.json5 ...
    host B: skyherd companion --connect udpin:B:PORT --zenoh-config DIR/companion.json5 ...

See docs/topology.md ("Two hosts, closed") and runio/tls.py. Exit codes: 0 written; 2 bad usage.
"""

from __future__ import annotations

import argparse
import ipaddress
from pathlib import Path

from skyherd.runio.constants import ZENOH_BASE


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--out", type=Path, default=Path("flight-tls"),
                        help="folder to write (created; existing files replaced)")  # fmt: skip
    parser.add_argument("--router-host", required=True, metavar="ADDRESS",
                        help="the simulator's address on the link to the companion (an IP or a "
                             "host name): the router listens there, the clients verify it")  # fmt: skip
    parser.add_argument("--port", type=int, default=ZENOH_BASE,
                        help=f"the router's TLS port (default {ZENOH_BASE})")  # fmt: skip
    parser.add_argument("--days", type=int, default=365, help="validity of every certificate")


def run(args: argparse.Namespace) -> int:
    from skyherd.runio import markdown_table
    from skyherd.runio.tls import make_pki, write_zenoh_configs
    from skyherd.scripts.cli import UsageError

    host = args.router_host.strip()
    try:
        if ipaddress.ip_address(host).is_unspecified:
            raise UsageError(f"--router-host {host}: give the address the companion connects to, "
                             "not a wildcard")  # fmt: skip
    except ValueError:
        if not host or any(c.isspace() for c in host):
            raise UsageError(f"--router-host {args.router_host!r} is neither an IP address nor "
                             "a host name") from None  # fmt: skip
    if not 0 < args.port < 65536:
        raise UsageError(f"--port {args.port}: give a TCP port in 1..65535")
    if args.days <= 0:
        raise UsageError(f"--days {args.days}: give a positive number of days")
    pki = make_pki(args.out, host, args.days)
    confs = write_zenoh_configs(pki, host, args.port)
    rows = [["ca.pem", "both hosts", "the flight's CA certificate (trusted by every side)"],
            ["ca.key", "neither", "the CA's private key: keep it off the flight's hosts"]]  # fmt: skip
    for role, where in (("sim", "host A"), ("companion", "host B"), ("viewer", "a watcher")):
        rows.append(
            [f"{role}.pem, {role}.key", where, f"the {role}'s certificate and key (CN {role})"]
        )
        rows.append([confs[role].name, where, f"the {role}'s Zenoh configuration"])
    print(markdown_table(["file", "copy to", "what"], rows))
    print(
        f"skyherd certs: wrote {args.out}/ (router tls/{host}:{args.port}, valid {args.days} days)"
    )
    return 0
