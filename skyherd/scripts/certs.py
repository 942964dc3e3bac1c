"""`skyherd certs`: the certificates and Zenoh configurations of a closed two-host flight: a
certificate authority of the flight's own, a key and certificate for each role (sim, companion,
viewer), and their Zenoh configurations with mutual TLS and the router's access control
(runio.tls says what each holds and how to use them). Exit codes: 0 written; 2 bad usage.
"""

from __future__ import annotations

import argparse
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
    from skyherd.runio import UsageError, markdown_table
    from skyherd.runio.tls import file_table, make_pki, router_host, write_zenoh_configs

    try:
        host = router_host(args.router_host)
    except ValueError as e:
        raise UsageError(f"--router-host {e}") from None
    if not 0 < args.port < 65536:
        raise UsageError(f"--port {args.port}: give a TCP port in 1..65535")
    if args.days <= 0:
        raise UsageError(f"--days {args.days}: give a positive number of days")
    pki = make_pki(args.out, host, args.days)
    confs = write_zenoh_configs(pki, host, args.port)
    print(markdown_table(["file", "copy to", "what"], file_table(confs)))
    print(
        f"skyherd certs: wrote {args.out}/ (router tls/{host}:{args.port}, valid {args.days} days)"
    )
    return 0
