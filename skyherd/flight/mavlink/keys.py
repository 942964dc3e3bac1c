"""MAVLink 2 signing keys and how a flight is signed, apart from the signing itself
(flight.mavlink.signing, which re-exports them): `skyherd fly`'s checks and its per-run key,
and the recorder's key, need no MAVLink dialect.

A key file holds exactly 32 raw bytes, mode 0600, written atomically.
"""

from __future__ import annotations

import hashlib
import os
from dataclasses import dataclass
from pathlib import Path

from skyherd.runio.runfolder import atomic_file, owner_only

KEY_LEN = 32


class SigningError(ValueError):
    """A key or key file that cannot be used; the message says why."""


def key_from_passphrase(text: str) -> bytes:
    """The 32-byte key MAVProxy and QGroundControl derive from a passphrase: SHA-256 of it."""
    return hashlib.sha256(text.encode("utf-8")).digest()


def load_key(path: Path) -> bytes:
    """The key in `path` (exactly 32 raw bytes). Raises SigningError with what to do."""
    path = Path(path)
    try:
        data = path.read_bytes()
    except OSError as e:
        raise SigningError(f"cannot read signing key {path}: {e.strerror or e}") from e
    if len(data) != KEY_LEN:
        raise SigningError(
            f"signing key {path} holds {len(data)} bytes, a key file holds exactly {KEY_LEN} "
            "(e.g. head -c 32 /dev/urandom > FILE)"
        )
    return data


def key_option(path) -> bytes:
    """The key of the `--signing-key` file `path` (load_key); SigningError naming the option."""
    try:
        return load_key(Path(path))
    except SigningError as e:
        raise SigningError(f"--signing-key: {e}") from None


def save_key(path: Path, key: bytes) -> None:
    """Write the key atomically, readable by its owner only."""
    if len(key) != KEY_LEN:
        raise SigningError(f"a signing key has {KEY_LEN} bytes, got {len(key)}")
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    with atomic_file(path, "wb", opener=owner_only) as f:
        f.write(key)


PER_RUN_KEY_FILE = "signing.key"  # a flight's own key in its run folder


@dataclass(frozen=True)
class FlightSigning:
    """How one flight signs its MAVLink links and its Zenoh records: with a key file given
    (`key_file`), unsigned (`off`), or with a new key per run. A per-run key is for the built-in
    vehicles only: an outside autopilot (`outside`) signs with its own key, or not at all.
    `setup`: give the outside autopilot the key file first (SETUP_SIGNING)."""

    key_file: str | None = None
    off: bool = False
    outside: bool = False
    setup: bool = False

    def checked_key_file(self) -> str | None:
        """The key file's absolute path, its key read (None: a per-run key, or unsigned);
        ValueError naming the option otherwise."""
        if self.key_file and self.off:
            raise ValueError("--signing-key and --no-signing contradict each other: drop one")
        if self.setup and (not self.outside or not self.key_file):
            raise ValueError("--setup-signing gives an outside autopilot your key: it needs "
                             "--connect ADDRESS and --signing-key FILE (the built-in vehicle is "
                             "signed by default)")  # fmt: skip
        if not self.key_file:
            return None
        key_option(self.key_file)
        return str(Path(self.key_file).resolve())

    def mode(self) -> str:
        """How the flight is signed, as its config.json and summary.md say it."""
        if self.key_file:
            return f"key file {Path(self.key_file).resolve()}"
        if self.off:
            return "off (--no-signing)"
        if self.outside:
            return "off (outside autopilot: give --signing-key FILE with the autopilot's key)"
        return "on (per-run key)"

    def per_run_key(self, run_dir: Path) -> Path | None:
        """With the built-in vehicle(s) and neither a key file nor `off`: a new key
        `<run>/signing.key` (32 random bytes, mode 0600) for every program of the flight."""
        if self.key_file or self.off or self.outside:
            return None
        path = Path(run_dir) / PER_RUN_KEY_FILE
        save_key(path, os.urandom(KEY_LEN))
        return path
