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

from safety.config import ENVELOPE_DIR, load_envelope
from scripts.cli import main


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
    assert all(r["proposed"]["pos_ned"][2] == -band for r in down)
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
