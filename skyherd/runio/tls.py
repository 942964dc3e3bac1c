"""A flight's own certificate authority and the Zenoh configurations of a closed two-host
flight: mutual TLS (each side proves who it is with a certificate the flight's CA signed) and
the router's access control (only the simulator publishes the world's keys, only the companion
its decisions and events; a viewer may only watch).

    pki = make_pki(Path("flight-tls"), router_host="10.0.0.1")   # ca + sim / companion / viewer
    write_zenoh_configs(pki, router_host="10.0.0.1")             # router.json5, companion.json5, ...

Keys are EC P-256, certificates X.509 v3 with serverAuth and clientAuth, the role as the common
name (Zenoh's access control matches `cert_common_names`), the router's address as a subject
alternative name (the clients verify it). Private keys are written 0600. `skyherd certs` is the
command (docs/topology.md, "Two hosts, closed"): copy its folder to both hosts (each needs
ca.pem, its own .pem/.key and its .json5; keep ca.key on neither), then

    host A: skyherd sim --bind A --remote B --zenoh-config DIR/router.json5 ...
    host B: skyherd companion --connect udpin:B:PORT --zenoh-config DIR/companion.json5 ...
"""

from __future__ import annotations

import datetime as dt
import ipaddress
import json
from dataclasses import dataclass
from pathlib import Path

from skyherd.runio.constants import ZENOH_BASE
from skyherd.runio.runfolder import atomic_file, atomic_write_bytes, atomic_write_text, owner_only

ROLES = ("sim", "companion", "viewer")
"""The identities of a flight: the simulator (the Zenoh router), the onboard computer, and a
watcher (a recorder or `skyherd watch`) that may subscribe and nothing else."""

WORLD_KEYS = ("skyherd/*/camera/frame", "skyherd/*/camera/info", "skyherd/ugv/*/state",
              "skyherd/sim/clock")  # fmt: skip
"""What only the simulator publishes (CONVENTIONS.md key table)."""
COMPANION_KEYS = ("skyherd/*/decision", "skyherd/*/safety/event")
"""What only the companion publishes."""


@dataclass(frozen=True)
class Pki:
    folder: Path
    ca: Path  # the CA's certificate (every side trusts it)

    def cert(self, role: str) -> Path:
        return self.folder / f"{role}.pem"

    def key(self, role: str) -> Path:
        return self.folder / f"{role}.key"


def _write_private(path: Path, data: bytes) -> None:
    """A private key, whole or not at all (a kill mid-write keeps the old file), owner-only from
    its first byte (a new file each time: an old file's wider mode is not inherited)."""
    with atomic_file(path, "wb", opener=owner_only) as f:
        f.write(data)


def _san(host: str):
    from cryptography import x509

    try:
        return x509.IPAddress(ipaddress.ip_address(host))
    except ValueError:
        return x509.DNSName(host)


def make_pki(folder: Path, router_host: str, days: int = 365, roles=ROLES) -> Pki:
    """A CA and one key + certificate per role in `folder` (created; existing files replaced).
    The sim's certificate names `router_host` (and 127.0.0.1, localhost) as its addresses."""
    from cryptography import x509
    from cryptography.hazmat.primitives import hashes, serialization
    from cryptography.hazmat.primitives.asymmetric import ec
    from cryptography.x509.oid import ExtendedKeyUsageOID, NameOID

    if days <= 0:
        raise ValueError(f"days must be > 0, got {days}")
    folder.mkdir(parents=True, exist_ok=True)
    now = dt.datetime.now(dt.UTC) - dt.timedelta(minutes=5)  # clocks a little apart
    end = now + dt.timedelta(days=days)

    def name(cn: str):
        return x509.Name([x509.NameAttribute(NameOID.ORGANIZATION_NAME, "skyherd flight"),
                          x509.NameAttribute(NameOID.COMMON_NAME, cn)])  # fmt: skip

    def pem_key(k) -> bytes:
        return k.private_bytes(serialization.Encoding.PEM, serialization.PrivateFormat.PKCS8,
                               serialization.NoEncryption())  # fmt: skip

    ca_key = ec.generate_private_key(ec.SECP256R1())
    ca_cert = (
        x509.CertificateBuilder().subject_name(name("skyherd flight CA"))
        .issuer_name(name("skyherd flight CA")).public_key(ca_key.public_key())
        .serial_number(x509.random_serial_number()).not_valid_before(now).not_valid_after(end)
        .add_extension(x509.BasicConstraints(ca=True, path_length=0), critical=True)
        .add_extension(x509.KeyUsage(digital_signature=True, key_cert_sign=True, crl_sign=True,
                                     content_commitment=False, key_encipherment=False,
                                     data_encipherment=False, key_agreement=False,
                                     encipher_only=False, decipher_only=False), critical=True)
        .sign(ca_key, hashes.SHA256())
    )  # fmt: skip
    atomic_write_bytes(folder / "ca.pem", ca_cert.public_bytes(serialization.Encoding.PEM))
    _write_private(folder / "ca.key", pem_key(ca_key))
    pki = Pki(folder, folder / "ca.pem")
    for role in roles:
        key = ec.generate_private_key(ec.SECP256R1())
        hosts = [router_host, "127.0.0.1", "localhost"] if role == "sim" else [role]
        cert = (
            x509.CertificateBuilder().subject_name(name(role)).issuer_name(ca_cert.subject)
            .public_key(key.public_key()).serial_number(x509.random_serial_number())
            .not_valid_before(now).not_valid_after(end)
            .add_extension(x509.SubjectAlternativeName([_san(h) for h in dict.fromkeys(hosts)]),
                           critical=False)
            .add_extension(x509.BasicConstraints(ca=False, path_length=None), critical=True)
            .add_extension(x509.ExtendedKeyUsage([ExtendedKeyUsageOID.SERVER_AUTH,
                                                  ExtendedKeyUsageOID.CLIENT_AUTH]), critical=False)
            .sign(ca_key, hashes.SHA256())
        )  # fmt: skip
        atomic_write_bytes(pki.cert(role), cert.public_bytes(serialization.Encoding.PEM))
        _write_private(pki.key(role), pem_key(key))
    return pki


def access_control() -> dict:
    """The router's rules: deny by default; the sim's world keys and the companion's keys may
    come in only from their own certificates; everyone the CA signed may subscribe and
    receive. (The router is the sim's own session: its publications are local, not ingress.)"""
    sub_all = ["skyherd/**"]
    return {
        "enabled": True,
        "default_permission": "deny",
        "rules": [
            {"id": "watch", "permission": "allow", "flows": ["ingress"],
             "messages": ["declare_subscriber", "declare_liveliness_subscriber"],
             "key_exprs": sub_all},
            {"id": "receive", "permission": "allow", "flows": ["egress"],
             "messages": ["put", "delete"], "key_exprs": sub_all},
            {"id": "world", "permission": "allow", "flows": ["ingress"],
             "messages": ["put"], "key_exprs": list(WORLD_KEYS)},
            {"id": "decisions", "permission": "allow", "flows": ["ingress"],
             "messages": ["put"], "key_exprs": list(COMPANION_KEYS)},
        ],
        "subjects": [{"id": role, "cert_common_names": [role]} for role in ROLES],
        "policies": [
            {"id": "sim", "rules": ["watch", "receive", "world"], "subjects": ["sim"]},
            {"id": "companion", "rules": ["watch", "receive", "decisions"],
             "subjects": ["companion"]},
            {"id": "viewer", "rules": ["watch", "receive"], "subjects": ["viewer"]},
        ],
    }  # fmt: skip


def zenoh_config(pki: Pki, role: str, router_host: str, port: int = ZENOH_BASE) -> dict:
    """One side's Zenoh configuration: the sim listens as the router (mutual TLS, access
    control), every other role connects to it as a client with its own certificate."""
    endpoint = f"tls/{router_host}:{port}"
    tls = {"root_ca_certificate": str(pki.ca.resolve()), "enable_mtls": True}
    if role == "sim":
        tls |= {"listen_private_key": str(pki.key(role).resolve()),
                "listen_certificate": str(pki.cert(role).resolve())}  # fmt: skip
        return {"mode": "router", "listen": {"endpoints": [endpoint]},
                "scouting": {"multicast": {"enabled": False}},
                "transport": {"link": {"tls": tls}}, "access_control": access_control()}  # fmt: skip
    tls |= {"connect_private_key": str(pki.key(role).resolve()),
            "connect_certificate": str(pki.cert(role).resolve()), "verify_name_on_connect": True}  # fmt: skip
    return {"mode": "client", "connect": {"endpoints": [endpoint]},
            "scouting": {"multicast": {"enabled": False}}, "transport": {"link": {"tls": tls}}}  # fmt: skip


def write_zenoh_configs(pki: Pki, router_host: str, port: int = ZENOH_BASE) -> dict[str, Path]:
    """router.json5 (the sim's), companion.json5 and viewer.json5 beside the certificates."""
    out = {}
    for role, fname in (("sim", "router.json5"), ("companion", "companion.json5"),
                        ("viewer", "viewer.json5")):  # fmt: skip
        path = pki.folder / fname
        conf = zenoh_config(pki, role, router_host, port)
        atomic_write_text(path, f"// skyherd certs: the {role}'s side of a closed two-host "
                          f"flight\n{json.dumps(conf, indent=2)}\n")  # fmt: skip
        out[role] = path
    return out


def router_host(text: str) -> str:
    """The router's address as the companion connects to it (an IP or a host name); ValueError
    for a wildcard address or something that is neither."""
    host = text.strip()
    try:
        ip = ipaddress.ip_address(host)
    except ValueError:
        if not host or any(c.isspace() for c in host):
            raise ValueError(f"{text!r} is neither an IP address nor a host name") from None
        return host
    if ip.is_unspecified:
        raise ValueError(f"{host}: give the address the companion connects to, not a wildcard")
    return host


def file_table(confs: dict[str, Path]) -> list[list[str]]:
    """(file, which host to copy it to, what it is) for every file `skyherd certs` wrote;
    `confs`: each role's Zenoh configuration (write_zenoh_configs)."""
    rows = [["ca.pem", "both hosts", "the flight's CA certificate (trusted by every side)"],
            ["ca.key", "neither", "the CA's private key: keep it off the flight's hosts"]]  # fmt: skip
    for role, where in (("sim", "host A"), ("companion", "host B"), ("viewer", "a watcher")):
        rows.append(
            [f"{role}.pem, {role}.key", where, f"the {role}'s certificate and key (CN {role})"]
        )
        rows.append([confs[role].name, where, f"the {role}'s Zenoh configuration"])
    return rows
