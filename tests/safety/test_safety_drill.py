"""Drills in SITL: the real MultirotorAutopilot in OFFBOARD behind the supervisor."""

import csv
import json

import numpy as np
import pytest

from skyherd.flight.airframes_registry import make_autopilot
from skyherd.flight.multirotor.autopilot import MultirotorAutopilot
from skyherd.flight.state import VehicleState
from skyherd.safety.config import (
    GUARD_KEYS,
    default_envelope_path,
    fill_dataclass,
    load_envelope,
    parse_envelope,
)
from skyherd.safety.drills import (
    DrillParams,
    behave_orbit,
    fixedwing_floor_m,
    random_drill,
    run_drill,
    scripted_drills,
)
from skyherd.safety.supervisor import SupervisorParams
from skyherd.scripts.cli import main

SPEC, _ = load_envelope(default_envelope_path("quadrotor"))


@pytest.mark.slow
def test_drill_command_short_run(tmp_path, capsys):
    rc = main(
        [
            "drill",
            "--only",
            "lateral,nan,link",
            "--random",
            "3",
            "--seed",
            "3",
            "--duration",
            "25",
            "--runs-dir",
            str(tmp_path),
        ]
    )
    out = capsys.readouterr().out
    assert rc == 0, out
    run = next(tmp_path.iterdir())
    cfg = json.loads((run / "config.json").read_text())
    assert cfg["plans"][0]["constraint_set_version"] == SPEC.version and cfg["seed"] == 3
    rows = list(csv.DictReader(open(run / "metrics.csv")))
    assert [r["drill"] for r in rows][:3] == ["lateral fence", "nan action", "link loss"] and len(
        rows
    ) == 6
    assert all(r["passed"] == "True" and float(r["excursion_m"]) <= 0 for r in rows)
    ev = [json.loads(line) for line in (run / "events.jsonl").read_text().splitlines()]
    first = [e for e in ev if e["drill"] == "lateral fence" and e["event"] == "switch"][0]
    assert (
        first["to"] == "fallback"
        and first["reason"].startswith("field edge")
        and first["action"] is not None
    )
    assert any(
        e["drill"] == "nan action" and e["reason"] == "non-finite action (NaN/inf)" for e in ev
    )
    assert any(
        e["drill"] == "link loss" and e["reason"].startswith("MAVLink link lost") for e in ev
    )
    for name in ("quadrotor-lateral-fence.png", "quadrotor-nan-action.png", "quadrotor-random.png"):
        assert (run / name).stat().st_size > 10_000
    assert f"quadrotor-field {SPEC.version}" in (run / "summary.md").read_text()
    assert "| lateral fence" in out and "ground-truth breaches beyond the tolerance: 0" in out


def test_judge_catches_a_breach_when_the_net_is_too_wide():
    """Same attack, but the safety net believes the fence is 400 m out: ground truth breaches."""
    doc = {
        "envelope": {"name": "wide", "version": "wide-1", "airframe": "quadrotor"},
        "guards": dict.fromkeys(GUARD_KEYS, "off"),
        "fence": {
            "inclusion": [
                {"name": "far", "points_ne": [[-400, -400], [400, -400], [400, 400], [-400, 400]]}
            ]
        },
    }
    p = DrillParams(duration_s=25.0)
    lateral = scripted_drills(SPEC, p)[0]
    r = run_drill(
        lateral, MultirotorAutopilot(), SPEC, SupervisorParams(), p, net_spec=parse_envelope(doc)
    )
    assert not r.passed and r.excursion_m > 5.0 and r.why.startswith("failed: fence: closest")
    assert [c.name for c in r.checks if not c.ok] == ["fence", "caught"]  # the judge's names
    assert r.switches == 0  # the too-wide net never intervened


def test_drill_fails_when_the_attack_is_not_caught():
    p = DrillParams(duration_s=16.0)
    script = scripted_drills(SPEC, p)[0]
    script.expect = ("ceiling",)  # the lateral attack is caught by a fence edge, not the ceiling
    r = run_drill(script, MultirotorAutopilot(), SPEC, SupervisorParams(), p)
    assert not r.passed and "expected a fallback" in r.why and r.excursion_m <= 0
    assert r.reasons[0].startswith("field edge") and r.rejected > 0


@pytest.mark.parametrize(
    "argv, msg", [(["--only", "nosuchdrill"], "matches no drill"), (["--random", "-1"], "--random")]
)
def test_drill_bad_usage_exits_2(tmp_path, capsys, argv, msg):
    assert main(["drill", *argv, "--runs-dir", str(tmp_path)]) == 2
    assert msg in capsys.readouterr().err


@pytest.mark.slow
def test_fixedwing_drill_loiters_and_recovers(tmp_path, capsys):
    """JSBSim fixed-wing: the lateral attack ends in its HOLD loiter, then the AI flies again."""
    rc = main(
        [
            "drill",
            "--airframe",
            "fixedwing",
            "--only",
            "lateral",
            "--duration",
            "45",
            "--runs-dir",
            str(tmp_path),
        ]
    )
    assert rc == 0, capsys.readouterr().out
    run = next(tmp_path.iterdir())
    row = next(csv.DictReader(open(run / "metrics.csv")))
    assert row["airframe"] == "fixedwing" and row["passed"] == "True"
    assert row["first_reason"] == "field edge 2" and float(row["excursion_m"]) < -20.0
    ev = [json.loads(line) for line in (run / "events.jsonl").read_text().splitlines()]
    sw = [e for e in ev if e["event"] == "switch"]
    assert [e["to"] for e in sw][:3] == ["fallback", "pid", "ai"]
    assert sw[1]["t"] - sw[0]["t"] == pytest.approx(6.0, abs=0.03)  # loiter hold_min_s of the set


@pytest.mark.slow
def test_notched_fence_drills(tmp_path, capsys):
    """A non-convex constraint set (another mission's file) through the same command."""
    env = default_envelope_path("quadrotor").with_name("quadrotor_notched.toml")
    rc = main(
        [
            "drill",
            "--envelope",
            str(env),
            "--only",
            "lateral",
            "--random",
            "4",
            "--seed",
            "5",
            "--runs-dir",
            str(tmp_path),
        ]
    )
    out = capsys.readouterr().out
    assert rc == 0, out
    assert "quadrotor-notched-field 2026.12-r3" in out and "breaches beyond the tolerance: 0" in out
    rows = list(csv.DictReader(open(next(tmp_path.iterdir()) / "metrics.csv")))
    assert float(rows[0]["excursion_m"]) < -5.0  # exact clearance, not the 0 of a split


@pytest.mark.slow
def test_campaign_drills_hold_under_faults(tmp_path, capsys):
    """`skyherd drill --campaign`: one of each adversarial kind per airframe on the fault
    plans, judged on ground truth: no breach, no overridden failsafe, table and PNG."""
    from skyherd.safety.campaign import kinds_for

    n = len(kinds_for("quadrotor"))
    rc = main(["drill", "--campaign", str(n), "--airframe", "quadrotor", "--seed", "5",
               "--runs-dir", str(tmp_path)])  # fmt: skip
    out = capsys.readouterr().out
    assert rc == 0, out
    run = next(tmp_path.iterdir())
    rows = list(csv.DictReader(open(run / "metrics.csv")))
    assert sorted(r["kind"] for r in rows) == sorted(kinds_for("quadrotor"))
    assert all(r["breach"] == "False" and r["overridden"] == "0" for r in rows), out
    by = {r["kind"]: r for r in rows}
    assert by["battery"]["yielded"] in ("RTL", "LAND")
    assert (
        "overridden autopilot failsafes: 0" in out
        and "Closest approaches" in (run / "summary.md").read_text()
    )
    assert (run / "campaign.png").stat().st_size > 10_000
    ev = [json.loads(line) for line in (run / "events.jsonl").read_text().splitlines()]
    assert any(e["event"] == "yield" and e["drill"].startswith("battery") for e in ev)


FW_SPEC, _FW_TABLE = load_envelope(default_envelope_path("fixedwing"))


def _random_fw(seed: int, k: int):
    rng = np.random.default_rng(seed)
    p = DrillParams()
    return [random_drill(i, rng, FW_SPEC, p) for i in range(k + 1)][k], p


@pytest.mark.parametrize(
    ("seed", "k", "was"),
    [(2, 13, "floor: drawn at 55.9 m"), (2, 28, "climb rate: orbit at 106.6 m, 22 m/s")],
)
def test_random_fixedwing_drill_recovers(seed, k, was):
    """Issue 26, "17 of 620 random fixed-wing drills end not recovered". Two causes, both in
    the drill's well-behaved AI, each replayed here from its seed:
    - floor: starts were drawn from floor + 25 = 55 m, below the floor row since the set keeps
      the gust sink reserve (floor 30 + margin 10 + 19 m + the stopping term); the AI's orbit
      flew back into the floor row after every hand-back (2/13: FALLBACK at 0.0, 42.7, 74.2 s);
    - climb rate: the orbit flew 22 m/s against the net's 24 m/s and slewed its climb demand
      1 m/s from the measured climb; above the recovery's 102 m hand-back altitude, TECS turned
      the deceleration into a 3.5 m/s climb and the AI's next demand crossed the 2.5 m/s row
      (2/28: a fallback 1 s after every hand-back, 17 of them)."""
    script, p = _random_fw(seed, k)
    assert -script.start_ned[2] >= fixedwing_floor_m(FW_SPEC)
    sp = fill_dataclass(SupervisorParams, _FW_TABLE, "supervisor")
    r = run_drill(script, make_autopilot("fixedwing", seed=seed), FW_SPEC, sp, p)
    assert r.passed, f"{was}: {r.why}"
    assert r.track["mode"][-1] == 0
    assert r.switches <= 6, r.reasons  # no fallback <-> hand-back ping-pong


def test_behave_orbit_climb_demand_stays_inside_the_climb_row():
    """A gust (or TECS's speed-to-height exchange) lifts the aircraft at 3.5 m/s below its
    orbit altitude: the well-behaved AI asks for its own gentle climb at the trim airspeed, not
    'the measured climb less 1 m/s' (2.5 m/s: on the climb row) at 22 m/s."""
    p = DrillParams()
    act = behave_orbit(106.6, p)
    s = VehicleState(t=0.0, pos_ned=np.array([-200.0, -100.0, -101.5]),
                     vel_ned=np.array([13.0, -18.4, -3.5]), quat=np.array([1.0, 0.0, 0.0, 0.0]),
                     omega_frd=np.zeros(3), accel_frd=np.zeros(3), on_ground=False)  # fmt: skip
    u = act(0.0, s).vel_ned
    assert -u[2] <= p.behave_climb_mps + 1e-9 < FW_SPEC.limits.climb_mps
    assert float(np.hypot(u[0], u[1])) == pytest.approx(p.fixedwing_speed_mps)
