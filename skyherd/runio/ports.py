"""Every port a vehicle instance owns: the one source of truth (CONVENTIONS.md, "MAVLink
endpoints", **contract**: the PX4 SITL layout; and Zenoh's).

For instance N (0..MAX_INSTANCE):

| what | port |
| --- | --- |
| API / offboard link, we bind (UDP) | API_BIND_BASE + N |
| ... it sends to the companion / MAVSDK (UDP) | API_REMOTE_BASE + N |
| ground-station link, we bind (UDP) | GCS_BIND_BASE + N |
| ... it sends to the ground station (UDP, every instance) | GCS_REMOTE_PORT |
| PX4 simulator_mavlink on our physics, we listen (TCP) | PX4_SIM_BASE + N |
| ArduPilot JSON on our physics, we listen (UDP) | JSON_BASE + JSON_STRIDE N |
| the simulator's Zenoh peer, we listen (TCP on 127.0.0.1) | ZENOH_BASE + N |

The numbers are in runio/constants.py; instance 0 keeps the well-known defaults (PX4's and
Zenoh's). Two overlaps are the PX4 layout's own (kept: it is the contract MAVSDK users know):
instance N+40's companion port is instance N's API port, and instance 10's companion port is
the ground stations' 14550. Vehicles flown together take their instances from
`disjoint_instances` (or are checked by `first_clash`), whose port sets meet nowhere.
"""

from __future__ import annotations

from skyherd.runio.constants import (  # noqa: F401  (the bases are part of this module's API)
    API_BIND_BASE,
    API_REMOTE_BASE,
    GCS_BIND_BASE,
    GCS_REMOTE_PORT,
    JSON_BASE,
    JSON_STRIDE,
    LOOPBACK,
    MAX_INSTANCE,
    PX4_SIM_BASE,
    ZENOH_BASE,
)


def check_instance(n: int, flag: str = "--instance") -> None:
    """ValueError with a one-line reason (and what to do) unless 0 <= n <= MAX_INSTANCE."""
    if isinstance(n, bool) or not isinstance(n, int) or not 0 <= n <= MAX_INSTANCE:
        raise ValueError(
            f"{flag} {n}: instance must be in [0, {MAX_INSTANCE}] (an integer N; its ports "
            f"are {API_REMOTE_BASE}+N, {API_BIND_BASE}+N, {GCS_BIND_BASE}+N, {ZENOH_BASE}+N, ...): "
            "pick one in that range"
        )


def check_port(port: int, flag: str) -> None:
    """ValueError with a one-line reason unless `port` is a TCP/UDP port one may listen on."""
    if isinstance(port, bool) or not isinstance(port, int) or not 1 <= port <= 65535:
        raise ValueError(f"{flag} {port}: a port is an integer in [1, 65535]")


def api_bind_port(n: int) -> int:
    return API_BIND_BASE + n


def api_remote_port(n: int) -> int:
    """Where the companion (MAVSDK, `skyherd companion`) of instance N listens."""
    return API_REMOTE_BASE + n


def gcs_bind_port(n: int) -> int:
    return GCS_BIND_BASE + n


def px4_sim_port(n: int) -> int:
    return PX4_SIM_BASE + n


def json_port(n: int) -> int:
    return JSON_BASE + JSON_STRIDE * n


def zenoh_port(n: int) -> int:
    """The simulator's Zenoh port of instance N (`--instance N` moves it with the rest)."""
    return ZENOH_BASE + n


def checked_zenoh_port(n: int, given: int | None) -> int:
    """The instance checked, and its Zenoh port: `given` (`--zenoh-port`) or ZENOH_BASE+N, checked
    (ValueError, one line): what `skyherd fly` and `skyherd sim` both accept."""
    check_instance(n)
    port = zenoh_port(n) if given is None else given
    check_port(port, "--zenoh-port")
    return port


def companion_address(n: int) -> str:
    """The companion's default MAVLink address for instance N (pymavlink form)."""
    return f"udpin:{LOOPBACK}:{api_remote_port(n)}"


def zenoh_address(n: int, host: str = LOOPBACK) -> str:
    """The simulator's Zenoh address of instance N (`tcp:HOST:PORT`, the one address syntax)."""
    return f"tcp:{host}:{zenoh_port(n)}"


def instance_ports(n: int) -> dict[str, int]:
    """Every port instance N owns or sends to, by name (for messages and config.json)."""
    check_instance(n)
    return {
        "api_bind_udp": api_bind_port(n),
        "api_remote_udp": api_remote_port(n),
        "gcs_bind_udp": gcs_bind_port(n),
        "gcs_remote_udp": GCS_REMOTE_PORT,
        "px4_sim_tcp": px4_sim_port(n),
        "ardupilot_json_udp": json_port(n),
        "zenoh_tcp": zenoh_port(n),
    }


def _owned(n: int) -> set[tuple[str, int]]:
    """(protocol, port) of every port instance N binds or sends to but the shared 14550."""
    return {("udp", api_bind_port(n)), ("udp", api_remote_port(n)), ("udp", gcs_bind_port(n)),
            ("tcp", px4_sim_port(n)), ("udp", json_port(n)), ("tcp", zenoh_port(n))}  # fmt: skip


def first_clash(instances: list[int]) -> tuple[int, int, int] | None:
    """The first two of these instances that share a port, or one whose companion port is the
    ground stations' GCS_REMOTE_PORT (then both are that instance), as (a, b, port); None if
    their port sets are disjoint: vehicles that can fly side by side."""
    seen: dict[tuple[str, int], int] = {}
    for n in instances:
        check_instance(n)
        if api_remote_port(n) == GCS_REMOTE_PORT:
            return n, n, GCS_REMOTE_PORT
        owned = _owned(n)
        for key in sorted(owned):
            if key in seen:
                return seen[key], n, key[1]
        seen.update(dict.fromkeys(owned, n))
    return None


def disjoint_instances(base: int, n: int) -> list[int]:
    """The first n instances from `base` up whose port sets meet nowhere (`first_clash` finds
    none): instance 10 is skipped (its companion port is 14550), and so is N+40 once N is taken
    (N+40's companion port is N's API port). ValueError (one line) if MAX_INSTANCE comes first."""
    out: list[int] = []
    for i in range(base, MAX_INSTANCE + 1):
        if len(out) == n:
            break
        if first_clash([*out, i]) is None:
            out.append(i)
    if len(out) < n:
        raise ValueError(f"{n} vehicles from instance {base} need instances past {MAX_INSTANCE} "
                         "(N and N+40 share a port); pick a smaller base instance")  # fmt: skip
    return out


def taken_udp_port(instances: list[int], host: str = LOOPBACK) -> tuple[int, int, str] | None:
    """The first UDP port of these instances that cannot be bound on `host` now — each
    instance's API and ground-station ports, then its companion's — as (instance, port, the
    operating system's reason); None if every one is free. A probe: nothing stays bound."""
    import socket

    for n in instances:
        for port in (api_bind_port(n), gcs_bind_port(n), api_remote_port(n)):
            with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
                try:
                    s.bind((host, port))
                except OSError as e:
                    return n, port, e.strerror
    return None


# the command line's help, built from the bases (one home for every number in it)
MAVLINK_PORTS_HELP = f"MAVLink ports ({API_REMOTE_BASE}+N, {API_BIND_BASE}+N, {GCS_BIND_BASE}+N)"
ZENOH_PORT_HELP = f"Zenoh port {ZENOH_BASE}+N"
COMPANION_ADDRESS_HELP = f"udpin:{LOOPBACK}:{API_REMOTE_BASE}+N"
ZENOH_ADDRESS_HELP = f"tcp:{LOOPBACK}:{ZENOH_BASE}+N"


GCS_STREAM = f"udpin:{LOOPBACK}:{GCS_REMOTE_PORT}"  # an autopilot's ground-station stream


def check_ports_free(instances: list[int], host: str = LOOPBACK) -> None:
    """ValueError (one line) if a UDP port of these instances is taken now (taken_udp_port)."""
    taken = taken_udp_port(instances, host)
    if taken is not None:
        inst, port, why = taken
        raise ValueError(
            f"UDP port {port} of instance {inst} is taken ({why}); pick another --instance"
        )
