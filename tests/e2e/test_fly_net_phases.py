"""Take-off and landing behind the net (issue 26 item 3), through `skyherd fly`'s two programs:

- the take-off column is certified before the take-off: a home the envelope does not allow
  (here inside an exclusion zone) is refused with the reason, the vehicle never arms;
- the landing's descent is flown behind the net like the mission's pilot (decisions of the
  `descend` pilot, in OFFBOARD, certified), and the autopilot's LAND starts only at the
  envelope's floor + margin (+ 1 m).

Lockstep: the same flight at any load (--speedup 0)."""

import csv
import json
import re

import numpy as np
import pytest

from skyherd.safety.config import ENVELOPE_DIR, load_envelope
from skyherd.safety.envelope import SignedDistance
from skyherd.scripts.cli import main


def _fly(tmp_path, *extra):
    args = ["fly", "--duration", "6", "--speedup", "0", "--timeout", "600", "--instance", "21",
            "--zenoh-port", "7461", "--runs-dir", str(tmp_path), *extra]  # fmt: skip
    rc = main(args)
    (run,) = tmp_path.iterdir()
    return rc, run


def test_the_landing_descends_behind_the_net_to_the_floor_band(tmp_path):
    rc, run = _fly(tmp_path)
    assert rc == 0
    spec, _ = load_envelope(ENVELOPE_DIR / "quadrotor_groundair.toml")
    band = spec.limits.floor_m + spec.limits.margin_m + 1.0  # FlightPlan.descend_above_floor_m
    rows = [json.loads(x) for x in (run / "decisions.jsonl").read_text().splitlines()]
    down = [r for r in rows if r["pilot"] == "descend"]
    assert len(down) >= 10 and all(r["autopilot_mode"] == "OFFBOARD" for r in down)
    assert all(r["proposed"]["vel_ned"][2] >= -0.01 for r in down)  # down, never up
    assert {r["verdict"] for r in down} <= {"accepted", "projected"}  # certified, never a switch
    track = list(csv.DictReader(open(run / "metrics.csv")))
    phases = [r["phase"] for r in track]
    assert phases.index("descend") < phases.index("land")
    first_land = next(r for r in track if r["phase"] == "land")
    assert -float(first_land["down"]) < band + 0.6  # LAND flies only the column below the band
    assert max(-float(r["down"]) for r in track if r["phase"] == "land") < band + 0.6
    assert all(r["mode"] == "OFFBOARD" for r in track if r["phase"] == "descend")
    # the mission's metrics are the policy's decisions only
    summary = (run / "summary.md").read_text()
    n_policy = sum(1 for r in rows if r["pilot"] == "policy")
    (shown,) = re.findall(r"\|\s*decisions\s*\|\s*(\d+)\s*\|", summary)
    assert int(shown) == n_policy < len(rows)


@pytest.mark.slow
def test_a_home_the_envelope_does_not_allow_is_refused_before_the_take_off(tmp_path):
    src = (ENVELOPE_DIR / "quadrotor_groundair.toml").read_text()
    env = tmp_path / "home_in_a_zone.toml"
    env.write_text(
        src + '\n[[fence.exclusion]]\nname = "pad"\ncenter_ne = [3.0, 0.0]\nradius_m = 8.0\n'
    )
    runs = tmp_path / "runs"
    rc, run = _fly(runs, "--envelope", str(env))
    assert rc == 1
    comp = json.loads((run / "companion.json").read_text())
    assert "refusing to take off" in comp["reason"] and "take-off column" in comp["reason"]
    assert "refusing to take off" in (run / "summary.md").read_text()
    world = list(csv.DictReader(open(run / "world.csv")))
    assert world and all(r["armed"] == "0" for r in world)  # never armed
    assert np.all([abs(float(r["down"])) < 0.05 for r in world])


@pytest.mark.parametrize(
    "drill,keyword",
    [("lateral-fence", "field"), ("exclusion-zone", "barn"), ("nan-action", "non-finite")],
)
@pytest.mark.slow
def test_a_named_drill_flies_the_missions_code_through_fly(tmp_path, drill, keyword):
    """A drill = a mission with an adversarial pilot: the drill's scripted AI flies through
    `skyherd fly` (MAVLink, lockstep, the companion's SafetyNet), the net catches the attack
    with the drill's reason, the truth stays inside the field's fence, and the flight ends
    completed and landed."""
    field = ENVELOPE_DIR / "quadrotor_field.toml"
    rc, run = _fly(tmp_path, "--pilot", f"drill:{drill}", "--envelope", str(field),
                   "--duration", "60")  # fmt: skip
    assert rc == 0, (run / "summary.md").read_text()
    events = [json.loads(x) for x in (run / "events.jsonl").read_text().splitlines()]
    caught = [e for e in events if e.get("event") == "switch" and keyword in e.get("reason", "")]
    assert caught, [e.get("reason") for e in events]
    spec, _ = load_envelope(field)
    signed = SignedDistance(spec)
    world = list(csv.DictReader(open(run / "world.csv")))
    above = [r for r in world if -float(r["down"]) > spec.limits.floor_m]
    worst = max(signed(np.array([float(r["north"]), float(r["east"]), float(r["down"])]))
                for r in above)  # fmt: skip
    assert worst <= 0.0  # never beyond the fence, a zone, the floor or the ceiling
    assert world[-1]["armed"] == "0" and abs(float(world[-1]["down"])) < 0.3


def test_an_unknown_drill_is_bad_usage(tmp_path, capsys):
    args = ["fly", "--pilot", "drill:meteor", "--runs-dir", str(tmp_path), "--instance", "21",
            "--zenoh-port", "7461", "--speedup", "0", "--timeout", "120"]  # fmt: skip
    assert main(args) == 2
    err = capsys.readouterr().err
    assert "no such drill" in err and "drill:lateral-fence" in err
    assert not any(tmp_path.iterdir())  # refused before anything started or was written
