"""runio/tls.py: the flight's CA and role certificates (chain, names, usage, key modes) and the
router's access-control rules (what each role may publish). The rules at work, over real TLS
between two network namespaces: tests/e2e/test_two_hosts.py."""

import os
import stat

import pytest
from cryptography import x509
from cryptography.x509.oid import ExtendedKeyUsageOID, NameOID

from skyherd.runio.tls import (
    COMPANION_KEYS,
    ROLES,
    WORLD_KEYS,
    access_control,
    make_pki,
    zenoh_config,
)


def test_each_role_has_a_ca_signed_certificate_named_for_it_and_a_private_key_0600(tmp_path):
    pki = make_pki(tmp_path / "pki", "10.0.0.1", days=30)
    ca = x509.load_pem_x509_certificate(pki.ca.read_bytes())
    assert ca.extensions.get_extension_for_class(x509.BasicConstraints).value.ca
    for role in ROLES:
        cert = x509.load_pem_x509_certificate(pki.cert(role).read_bytes())
        cert.verify_directly_issued_by(ca)  # raises if another key signed it
        assert cert.subject.get_attributes_for_oid(NameOID.COMMON_NAME)[0].value == role
        eku = cert.extensions.get_extension_for_class(x509.ExtendedKeyUsage).value
        assert {ExtendedKeyUsageOID.SERVER_AUTH, ExtendedKeyUsageOID.CLIENT_AUTH} <= set(eku)
        assert 29 <= (cert.not_valid_after_utc - cert.not_valid_before_utc).days <= 31
        assert stat.S_IMODE(pki.key(role).stat().st_mode) == 0o600
    assert stat.S_IMODE((pki.folder / "ca.key").stat().st_mode) == 0o600
    sim = x509.load_pem_x509_certificate(pki.cert("sim").read_bytes())
    san = sim.extensions.get_extension_for_class(x509.SubjectAlternativeName).value
    assert "10.0.0.1" in {str(a) for a in san.get_values_for_type(x509.IPAddress)}
    other = x509.load_pem_x509_certificate(make_pki(tmp_path / "other", "10.0.0.1").ca.read_bytes())
    try:
        sim.verify_directly_issued_by(other)
        raise AssertionError("another CA verified the sim's certificate")
    except Exception as e:  # noqa: BLE001 - InvalidSignature (or ValueError): not its issuer
        assert not isinstance(e, AssertionError)


def test_the_router_denies_by_default_and_gives_each_role_only_its_keys(tmp_path):
    acl = access_control()
    assert acl["enabled"] and acl["default_permission"] == "deny"
    rules = {r["id"]: r for r in acl["rules"]}
    pol = {p["id"]: set(p["rules"]) for p in acl["policies"]}
    puts = {role: {k for r in pol[role] if rules[r]["flows"] == ["ingress"]
                   and "put" in rules[r]["messages"] for k in rules[r]["key_exprs"]}
            for role in ROLES}  # fmt: skip
    assert puts == {"sim": set(WORLD_KEYS), "companion": set(COMPANION_KEYS), "viewer": set()}
    pki = make_pki(tmp_path / "pki", "10.0.0.1")
    router = zenoh_config(pki, "sim", "10.0.0.1")
    assert router["listen"]["endpoints"] == ["tls/10.0.0.1:7447"]
    assert router["transport"]["link"]["tls"]["enable_mtls"]
    client = zenoh_config(pki, "companion", "10.0.0.1")["transport"]["link"]["tls"]
    assert client["verify_name_on_connect"] and client["connect_certificate"].endswith(
        "companion.pem"
    )


def test_the_router_host_is_an_address_the_companion_can_reach(tmp_path):
    """`skyherd certs --router-host`: an IP or a host name (trimmed); a wildcard or a name with
    a space is refused with the reason; every written file has its row, its host and its use."""
    import pytest

    from skyherd.runio.tls import file_table, router_host, write_zenoh_configs

    assert router_host(" 10.0.0.1 ") == "10.0.0.1" and router_host("sim-a.local") == "sim-a.local"
    for bad in ("0.0.0.0", "::"):
        with pytest.raises(ValueError, match="not a wildcard"):
            router_host(bad)
    for bad in ("a b", "  "):
        with pytest.raises(ValueError, match="neither an IP address nor a host name"):
            router_host(bad)
    pki = make_pki(tmp_path / "pki", "10.0.0.1", days=1)
    rows = file_table(write_zenoh_configs(pki, "10.0.0.1"))
    files = {f for row in rows for f in row[0].split(", ")}
    assert files == {p.name for p in (tmp_path / "pki").iterdir()}
    assert dict((r[0], r[1]) for r in rows)["ca.key"] == "neither"


def test_a_new_pki_over_an_old_one_replaces_each_key_whole_and_owner_only(tmp_path, monkeypatch):
    """Keys are written through runio's atomic_file: a folder made again gets new keys that are
    0600 even where the old file had a wider mode, and a write that fails keeps the old key
    whole with no temporary file beside it (a kill or a full disk mid-write)."""
    pki = make_pki(tmp_path, "10.0.0.1", roles=("companion",))
    old = pki.key("companion").read_bytes()
    pki.key("companion").chmod(0o644)
    again = make_pki(tmp_path, "10.0.0.1", roles=("companion",))
    assert again.key("companion").read_bytes() != old
    assert stat.S_IMODE(again.key("companion").stat().st_mode) == 0o600
    kept = again.key("companion").read_bytes()

    def full_disk(fd):
        raise OSError(28, "No space left on device")

    monkeypatch.setattr(os, "fsync", full_disk)
    with pytest.raises(OSError):
        make_pki(tmp_path, "10.0.0.1", roles=("companion",))
    assert (tmp_path / "ca.key").exists() and again.key("companion").read_bytes() == kept
    assert sorted(p.name for p in tmp_path.iterdir() if p.name.startswith(".")) == []
