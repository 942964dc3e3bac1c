"""`skyherd fly --connect ADDRESS --signing-key FILE --setup-signing`: an outside autopilot (here
the built-in vehicle in this process, standing in for one that holds no key) is given the key
(SETUP_SIGNING) before anything else, answers signed, and the whole flight is signed — the
companion's link and the world's (`sim --follow`). Free-running on the vehicle's clock at 1x:
wall time by nature (test_fly_connect.py says why)."""

import json

import pytest

from skyherd.flight.airframes_registry import make_autopilot
from skyherd.flight.mavlink import EndpointConfig
from skyherd.flight.mavlink.signing import load_key, save_key
from skyherd.flight.sitl import Sitl
from skyherd.scripts.cli import main

INSTANCE = 37  # the outside vehicle: API 14580+37 → companion 14577, ground station → 14550


@pytest.mark.slow
def test_setup_signing_gives_an_outside_autopilot_the_key_then_flies_signed_walltime(tmp_path):
    key = tmp_path / "flight.key"
    save_key(key, bytes(range(1, 33)))
    ap = make_autopilot("quadrotor", seed=0)
    sitl = Sitl(ap, EndpointConfig(instance=INSTANCE), speedup=1.0)
    assert not sitl.endpoint.signing.enabled  # it holds no key: it takes anyone's commands
    with sitl.start():
        rc = main(["fly", "--connect", f"udpin:127.0.0.1:{14540 + INSTANCE}", "--duration", "10",
                   "--signing-key", str(key), "--setup-signing", "--zenoh-port", "7436",
                   "--instance", "36", "--timeout", "600", "--runs-dir", str(tmp_path / "runs")])  # fmt: skip
    (run,) = (tmp_path / "runs").iterdir()
    comp = json.loads((run / "companion.json").read_text())
    assert rc == 0, (run / "summary.md").read_text()
    assert sitl.endpoint.stats["setup_signing"] >= 1
    assert sitl.endpoint.signing.enabled and sitl.endpoint.signing.key == load_key(key)
    assert comp["outcome"] == "completed" and comp["frames"]["ok"] > 50  # the world's link too
    assert comp["mavlink"]["signed"] is True
    assert "MAVLink signing: key file" in (run / "summary.md").read_text()


def test_setup_signing_without_a_key_or_an_outside_autopilot_is_refused(tmp_path, capsys):
    runs = tmp_path / "runs"
    assert main(["fly", "--setup-signing", "--runs-dir", str(runs)]) == 2
    assert main(["fly", "--connect", "udpin:127.0.0.1:14599", "--setup-signing",
                 "--runs-dir", str(runs)]) == 2  # fmt: skip
    err = capsys.readouterr().err
    assert err.count("--setup-signing gives an outside autopilot your key") == 2
    assert not runs.exists()
