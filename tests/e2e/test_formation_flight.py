"""`skyherd fly --mission formation`: grid → field mapping, plan checks, separations, and K
quadrotor vehicles (K `skyherd sim` processes) flown end to end by one `skyherd companion` in
lockstep over MAVLink (real loopback sockets), at speed-up 0: nothing here depends on load."""

from __future__ import annotations

import csv
import json
import math
import socket

import numpy as np
import pytest
from pymavlink import mavutil

from skyherd.flight.geo import DEFAULT_HOME
from skyherd.mission.formation_plan import (
    FormationParams,
    PlanError,
    cell_ne,
    field_offsets,
    load_plan,
    plan_moves,
    plan_ne,
    reference,
    separation,
    tracking_error,
    validate_plan,
    vehicle_homes,
    vehicle_instances,
)
from skyherd.policy.sql import Algorithm, GridParams, SQLHyper, build_layout, plan_paths, train
from skyherd.policy.sql.layout import STARTS, TARGET_LATTICE
from skyherd.scripts.cli import main

# Instances far from the other tests' (0..10) so parallel runs do not share ports.
BASE = 120


def _rows(run):
    return list(csv.DictReader(open(run / "metrics.csv")))


# ---- pure parts ----------------------------------------------------------------------------


def test_cell_to_field_mapping_and_vehicle_homes():
    # cell (x, y) → north (y−1)·c, east (x−1)·c
    assert np.allclose(cell_ne((1, 1), 2.0), [0.0, 0.0])
    assert np.allclose(cell_ne((3, 1), 2.0), [0.0, 4.0])  # x is east
    assert np.allclose(cell_ne((1, 50), 2.0), [98.0, 0.0])  # y is north
    paths = [[(1, 1), (2, 1), (2, 2)], [(5, 7), (5, 8), (5, 8)]]
    ne = plan_ne(paths, 3.0)
    assert ne.shape == (2, 3, 2)
    assert np.allclose(ne[0], [[0, 0], [0, 3], [3, 3]])
    assert np.allclose(ne[1, 2], [21.0, 12.0])
    assert plan_moves(paths) == [2, 1]
    # each home sits on its start cell: geodetic round trip back to the field frame < 1 mm
    starts = list(STARTS[9])
    homes = vehicle_homes(DEFAULT_HOME, starts, 2.0)
    offs = field_offsets(DEFAULT_HOME, homes)
    for c, o, h in zip(starts, offs, homes):
        assert np.linalg.norm(o - cell_ne(c, 2.0)) < 1e-3
        assert h.alt_m == DEFAULT_HOME.alt_m
    # (1, 9) is 16 m north: 16 m / (meridian radius 6.357e6 m) = 1.442e-4 degrees of latitude
    assert homes[0].lat_deg - DEFAULT_HOME.lat_deg == pytest.approx(1.442e-4, rel=1e-3)


def test_vehicle_instances_skip_the_one_whose_companion_port_is_the_ground_stations():
    # PX4 layout: instance N's companion listens on 14540+N; for N = 10 that is 14550, where
    # every vehicle's ground-station link sends (a K = 9 flight from instance 5 hung on it)
    assert vehicle_instances(0, 16) == [*range(10), *range(11, 17)]
    assert vehicle_instances(5, 9) == [5, 6, 7, 8, 9, 11, 12, 13, 14]
    assert vehicle_instances(120, 4) == [120, 121, 122, 123]
    assert all(14540 + n != 14550 for n in vehicle_instances(0, 40))


def test_reference_moves_one_cell_per_step_with_feed_forward():
    path = plan_ne([[(1, 1), (2, 1), (2, 1), (2, 2)]], 2.0)[0]
    p, v = reference(path, -1.0, 1.0)  # before the start: first cell, at rest
    assert np.allclose(p, [0, 0]) and np.allclose(v, 0)
    p, v = reference(path, 0.25, 1.0)  # a quarter of the way east, 2 m/s east
    assert np.allclose(p, [0, 0.5]) and np.allclose(v, [0, 2.0])
    p, v = reference(path, 1.5, 1.0)  # a wait: still, no velocity
    assert np.allclose(p, [0, 2]) and np.allclose(v, 0)
    p, v = reference(path, 2.5, 0.5)  # step_s = 0.5: past the end at t = 1.5 s
    assert np.allclose(p, [2, 2]) and np.allclose(v, 0)
    p, v = reference(path, 2.5, 1.0)  # half of the last (north) move, 2 m/s north
    assert np.allclose(p, [1, 2]) and np.allclose(v, [2.0, 0])


def test_plan_validation_rejects_bad_plans(tmp_path):
    good = [[[1, 1], [2, 1]], [[1, 2], [1, 3]]]
    assert validate_plan(good, 2, 50) == [[(1, 1), (2, 1)], [(1, 2), (1, 3)]]
    bad = {
        "one path per agent": ([[[1, 1], [2, 1]]], "2 paths"),
        "jump": ([[[1, 1], [3, 1]], [[1, 2], [1, 3]]], "jumps"),
        "diagonal": ([[[1, 1], [2, 2]], [[1, 2], [1, 3]]], "jumps"),
        "shared cell": ([[[1, 1], [1, 2]], [[1, 2], [1, 2]]], "share a cell"),
        "off grid": ([[[0, 1], [1, 1]], [[1, 2], [1, 3]]], "off the"),
        "ragged": ([[[1, 1], [2, 1], [3, 1]], [[1, 2], [1, 3]]], "same length"),
        "float": ([[[1.5, 1], [2, 1]], [[1, 2], [1, 3]]], "integers"),
        "bool": ([[[True, 1], [2, 1]], [[1, 2], [1, 3]]], "integers"),
        "not a list": ({"a": 1}, "2 paths"),
    }
    for name, (plan, words) in bad.items():
        with pytest.raises(PlanError, match=words):
            validate_plan(plan, 2, 50)
        assert name
    f = tmp_path / "plan.json"
    f.write_text("[[ [1, 1], [2, 1] ], [ [1, 2")  # truncated
    with pytest.raises(PlanError, match="cannot read"):
        load_plan(f, 2)
    f.write_bytes(b"\xff\xfe\x00garbage")
    with pytest.raises(PlanError, match="cannot read"):
        load_plan(f, 2)
    with pytest.raises(PlanError, match="cannot read"):
        load_plan(tmp_path / "missing.json", 2)


def test_params_reject_nan_and_out_of_range():
    assert FormationParams().altitude(3) == pytest.approx(8.0 + 9.0)  # 3 m layers
    assert FormationParams(cell_m=3.0).step_s == pytest.approx(1.5)  # 2 m/s at any cell size
    assert FormationParams(cell_m=20.0, speed_mps=4.0).step_s == pytest.approx(5.0)
    bad_sets = ({"cell_m": math.nan}, {"cell_m": 0.5}, {"speed_mps": 0.0},
                {"speed_mps": math.inf}, {"altitude_step_m": 0.1})  # fmt: skip
    for bad in bad_sets:
        with pytest.raises(ValueError, match="bad formation parameters"):
            FormationParams(**bad)


def test_separation_and_tracking_error_on_hand_made_tracks():
    t = np.linspace(0.0, 10.0, 101)
    # A flies east at 1 m/s at 8 m; B is still at (0, 5) at 8.5 m; C is still at (0, 5) at 20 m
    a = np.stack([t, 0 * t, t, -8 + 0 * t], -1)
    b = np.stack([t, 0 * t, 5 + 0 * t, -8.5 + 0 * t], -1)
    c = np.stack([t, 0 * t, 5 + 0 * t, -20 + 0 * t], -1)
    s = separation([a, b, c], similar_alt_m=1.0)
    assert s.min_horizontal_any == pytest.approx(0.0, abs=1e-9)  # A passes under C and B
    assert s.min_horizontal_similar_alt == pytest.approx(0.0, abs=1e-9)  # A and B: 0.5 m apart
    assert s.min_3d == pytest.approx(0.5) and s.pair_3d == (0, 1) and s.t_3d == pytest.approx(5.0)
    s = separation([a, c], similar_alt_m=1.0)  # 12 m apart vertically: no similar pair
    assert math.isnan(s.min_horizontal_similar_alt) and s.min_3d == pytest.approx(12.0)
    # A against a plan that moves one 1 m cell per second east, then waits: the track is on it
    path = plan_ne([[(1, 1), (2, 1), (3, 1), (3, 1)]], 1.0)[0]
    emax, erms = tracking_error(a, path, 0.0, 1.0)
    assert emax == pytest.approx(1.0, abs=1e-9)  # at t = 3 s A is 1 m past the waiting cell
    assert 0.0 < erms < emax
    assert all(math.isnan(x) for x in tracking_error(a, path, 50.0, 1.0))


# ---- flown end to end: K simulators and one companion in lockstep ---------------------------


def _tracks(run):
    rows = _rows(run)
    return {k: [r for r in rows if r["vehicle"] == str(k)] for k in range(4)}


@pytest.mark.slow
def test_fly_formation_k4_learned_plan_lands_every_vehicle_on_its_target(tmp_path):
    code = main(["fly", "--mission", "formation", "--agents", "4", "--speedup", "0",
                 "--instance", str(BASE), "--timeout", "900", "--runs-dir", str(tmp_path)])  # fmt: skip
    (run,) = tmp_path.iterdir()
    summary = (run / "summary.md").read_text()
    assert code == 0, summary
    assert {"config.json", "metrics.csv", "decisions.jsonl", "events.jsonl", "formation.png",
            "plan.json", "summary.md", "companion.json"} <= {p.name for p in run.iterdir()}  # fmt: skip
    assert "completed" in summary
    plan = json.loads((run / "plan.json").read_text())
    # the plan flown is the fixed-seed SQL-SIE plan (sql seed 0), reproduced here
    res = train(Algorithm.SQL_SIE, build_layout(GridParams(n_agents=4)), SQLHyper(), seed=0)
    assert plan == [[list(c) for c in p] for p in plan_paths(res, 4)]
    assert [tuple(p[0]) for p in plan] == list(STARTS[4])
    lattice = TARGET_LATTICE[4]
    assert sorted(tuple(p[-1]) for p in plan) == sorted((x, y) for x in lattice for y in lattice)
    by = _tracks(run)
    for k in range(4):
        pos = np.array([[float(r["north"]), float(r["east"]), float(r["down"])] for r in by[k]])
        # starts on its start cell, cruises at 8 + 3 k m, lands on its target cell's centre
        assert np.linalg.norm(pos[0, :2] - cell_ne(tuple(plan[k][0]), 2.0)) < 0.05
        assert (-pos[:, 2]).max() == pytest.approx(8.0 + 3.0 * k, abs=0.5)
        assert np.linalg.norm(pos[-1, :2] - cell_ne(tuple(plan[k][-1]), 2.0)) < 1.0
        assert -pos[-1, 2] < 0.3 and by[k][-1]["armed"] == "0"
        assert {"takeoff", "plan", "land"} <= {r["phase"] for r in by[k]}
    # one simulation clock: every vehicle's telemetry carries the same time stamps
    times = [[r["t"] for r in by[k]] for k in range(4)]
    assert all(t == times[0] for t in times)
    # every setpoint of every vehicle went through its net: one decision per vehicle per tick
    dec = [json.loads(x) for x in open(run / "decisions.jsonl")]
    per = {f"uav{k}": [d for d in dec if d["vehicle"] == f"uav{k}"] for k in range(4)}
    assert len({len(v) for v in per.values()}) == 1 and len(per["uav0"]) > 500
    assert all(d["pilot"] == "formation" and d["certified"]["yaw"] == 0.0 for d in dec)
    comp = json.loads((run / "companion.json").read_text())
    assert comp["outcome"] == "completed" and comp["decisions"] == len(dec)
    # each vehicle's tlog is a real MAVLink log: its heartbeats and the companion's setpoints
    for k in range(4):
        log = mavutil.mavlink_connection(str(run / f"uav{k}" / "telemetry.tlog"))
        seen = set()
        while (m := log.recv_match()) is not None:
            seen.add((m.get_type(), m.get_srcSystem(), m.get_srcComponent()))
        n = BASE + k
        assert {("HEARTBEAT", 1 + n, 1), ("LOCAL_POSITION_NED", 1 + n, 1),
                ("SET_POSITION_TARGET_LOCAL_NED", 1 + n, 191)} <= seen  # fmt: skip
        st = json.loads((run / f"uav{k}" / "sim_stats.json").read_text())
        assert st["lockstep"]
        # the flight ends at the last tick the companion closed; the simulator then only waits
        # (until fly stops it): that wait is not in the real-time factor
        assert 0 < st["flight_sim_s"] <= st["sim_s"] and 0 < st["flight_wall_s"] <= st["wall_s"]
        assert st["real_time_factor"] == st["flight_sim_s"] / st["flight_wall_s"]
        assert st["sim_s"] - st["flight_sim_s"] < 0.2  # at most one camera period past it


@pytest.mark.slow
def test_fly_formation_from_a_plan_file_with_3m_cells(tmp_path):
    # a short hand-made plan: four agents step east/north in lock-step, then wait
    plan = [[[1, 5], [2, 5], [3, 5], [3, 6]], [[1, 2], [2, 2], [3, 2], [4, 2]],
            [[2, 1], [3, 1], [4, 1], [5, 1]], [[5, 1], [6, 1], [7, 1], [7, 2]]]  # fmt: skip
    f = tmp_path / "plan_K4.json"
    f.write_text(json.dumps(plan))
    out = tmp_path / "runs"
    code = main(["fly", "--mission", "formation", "--agents", "4", "--policy-file", str(f),
                 "--cell-m", "3", "--speedup", "0", "--instance", str(BASE + 10),
                 "--timeout", "600", "--runs-dir", str(out)])  # fmt: skip
    (run,) = out.iterdir()
    assert code == 0, (run / "summary.md").read_text()
    cfg = json.loads((run / "config.json").read_text())
    assert cfg["plan"]["source"] == "file" and cfg["formation"]["cell_m"] == 3.0
    assert "one per 1.5 s" in (run / "summary.md").read_text()  # 3 m cells at 2 m/s
    rows = _rows(run)
    for k in range(4):
        last = [r for r in rows if r["vehicle"] == str(k)][-1]
        end = cell_ne(tuple(plan[k][-1]), 3.0)
        assert math.hypot(float(last["north"]) - end[0], float(last["east"]) - end[1]) < 1.0


@pytest.mark.slow
def test_the_flight_is_the_same_in_one_simulator_process_or_one_per_vehicle(tmp_path):
    """A fleet (several vehicles stepped in turn by one `skyherd sim --fleet`) flies exactly as
    the same vehicles in a process each: decisions, events, metrics and every world.csv."""
    plan = [[[1, 5], [2, 5], [2, 6]], [[1, 2], [2, 2], [2, 3]], [[2, 1], [3, 1], [4, 1]],
            [[5, 1], [6, 1], [6, 2]]]  # fmt: skip
    f = tmp_path / "plan_K4.json"
    f.write_text(json.dumps(plan))
    runs = {}
    for sims in (4, 1):
        out = tmp_path / f"sims{sims}"
        code = main(["fly", "--mission", "formation", "--agents", "4", "--policy-file", str(f),
                     "--sims", str(sims), "--speedup", "0", "--instance", str(BASE + 40),
                     "--timeout", "600", "--runs-dir", str(out)])  # fmt: skip
        (run,) = out.iterdir()
        assert code == 0, (run / "summary.md").read_text()
        runs[sims] = run
    assert sorted(p.name for p in runs[1].glob("sim*.json")) == ["sim0.json"]
    assert len(list(runs[4].glob("sim*.json"))) == 4
    fleet = json.loads((runs[1] / "sim0.json").read_text())
    assert [v["name"] for v in fleet] == ["uav0", "uav1", "uav2", "uav3"]
    for name in ["decisions.jsonl", "events.jsonl", "metrics.csv"] + [
        f"uav{k}/world.csv" for k in range(4)
    ]:
        assert (runs[1] / name).read_bytes() == (runs[4] / name).read_bytes(), name
    for k in range(4):
        one = json.loads((runs[1] / f"uav{k}" / "sim_stats.json").read_text())
        own = json.loads((runs[4] / f"uav{k}" / "sim_stats.json").read_text())
        assert (one["process_vehicles"], own["process_vehicles"]) == (4, 1)
        assert one["ticks_closed"] == own["ticks_closed"] > 50


def test_sim_groups_share_the_vehicles_in_contiguous_near_equal_groups():
    from skyherd.world.fleet import sim_groups

    assert sim_groups(16, 2) == [list(range(8)), list(range(8, 16))]
    assert sim_groups(9, 2) == [list(range(5)), list(range(5, 9))]
    assert sim_groups(4, 4) == [[0], [1], [2], [3]]
    assert sim_groups(1, 0) == [[0]]
    groups = sim_groups(9, 0)  # one per CPU core, at most K
    assert sorted(k for g in groups for k in g) == list(range(9)) and 1 <= len(groups) <= 9


def test_sim_fleet_file_errors_exit_2_with_the_reason(tmp_path, capsys):
    def fleet(entries) -> str:
        f = tmp_path / "fleet.json"
        f.write_text(entries if isinstance(entries, str) else json.dumps(entries))
        return str(f)

    good = {"name": "uav0", "instance": BASE + 50, "seed": 0, "home": [-35.36, 149.16, 584.0]}
    base = ["sim", "--ugvs", "none", "--runs-dir", str(tmp_path / "runs"), "--fleet"]
    assert main([*base, fleet("[{")]) == 2  # not JSON
    assert main([*base, fleet([])]) == 2  # empty
    assert main([*base, fleet([{**good, "home": [1.0, 2.0]}])]) == 2  # home of two numbers
    assert main([*base, fleet([{**good, "home": [95.0, 2.0, 0.0]}])]) == 2  # latitude out of range
    assert main([*base, fleet([{**good, "instance": 1.5}])]) == 2
    assert main([*base, fleet([{**good, "name": "a/b"}])]) == 2
    assert main([*base, fleet([good, {**good, "name": "uav1"}])]) == 2  # same instance twice
    assert main([*base, fleet([{**good, "instance": 201}])]) == 2  # past EndpointConfig's range
    assert main(["sim", "--fleet", fleet([good]), "--runs-dir", str(tmp_path / "runs")]) == 2
    err = capsys.readouterr().err
    assert "not a readable JSON file" in err and "non-empty JSON list" in err
    assert "vehicle 0 is not" in err and "out of range" in err and "same instance" in err
    assert "instance must be in [0, 200]" in err and "add --ugvs none" in err


def test_fly_formation_bad_usage_exits_2(tmp_path, capsys):
    runs = str(tmp_path / "runs")
    base = ["fly", "--mission", "formation", "--runs-dir", runs]
    assert main([*base, "--connect", "udpin:127.0.0.1:14540"]) == 2
    assert main([*base, "--cell-m", "nan", "--instance", str(BASE)]) == 2
    assert main([*base, "--agents", "4", "--instance", "199"]) == 2
    assert main([*base, "--agents", "4", "--sims", "5", "--instance", str(BASE)]) == 2
    bad = tmp_path / "bad.json"
    bad.write_text("[[1, 2], [3")
    assert main([*base, "--agents", "4", "--policy-file", str(bad)]) == 2
    with pytest.raises(SystemExit):  # argparse: K must be 4, 9 or 16
        main([*base, "--agents", "5"])
    # a port already taken: clear message, exit 2, nothing started
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.bind(("127.0.0.1", 14580 + BASE + 20 + 2))  # vehicle 2's API port
        plan = tmp_path / "p.json"
        plan.write_text(json.dumps([[[1, 5], [2, 5]], [[1, 2], [2, 2]], [[2, 1], [3, 1]],
                                    [[5, 1], [6, 1]]]))  # fmt: skip
        assert main([*base, "--agents", "4", "--policy-file", str(plan),
                     "--instance", str(BASE + 20)]) == 2  # fmt: skip
    err = capsys.readouterr().err
    assert "drop --connect" in err and "--cell-m" in err and "--instance" in err
    assert "--sims 5: give 1..4 processes" in err
    assert "cannot read plan" in err and "pick another --instance" in err
    assert not (tmp_path / "runs").exists() or not any((tmp_path / "runs").iterdir())


@pytest.mark.slow
def test_flight_out_of_time_aborts_with_exit_1_and_frees_every_port_walltime(tmp_path):
    """Wall time: --timeout is a wall-clock limit. 2 s of wall time, at speed-up 1 (the flight
    needs 37 s of simulation time, so at least 37 s of wall time on any machine)."""
    plan = [[[1, 5], [2, 5]], [[1, 2], [2, 2]], [[2, 1], [3, 1]], [[5, 1], [6, 1]]]
    f = tmp_path / "p.json"
    f.write_text(json.dumps(plan))
    inst = BASE + 30
    code = main(["fly", "--mission", "formation", "--agents", "4", "--policy-file", str(f),
                 "--speedup", "1", "--timeout", "2", "--instance", str(inst), "--runs-dir", str(tmp_path / "r")])  # fmt: skip
    assert code == 1
    (run,) = (tmp_path / "r").iterdir()
    summary = (run / "summary.md").read_text()
    assert "ABORTED" in summary and "--timeout 2 s" in summary
    for port in [p + inst + k for p in (14580, 18570, 14540) for k in range(4)]:
        with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
            s.bind(("127.0.0.1", port))  # closed: nothing of the flight is left running


def test_stop_all_signals_every_child_at_once_and_reasons_prefer_the_supervisor_walltime():
    """Wall time: four children that each take 1 s to end after SIGINT end in about 1 s, not 4."""
    import subprocess
    import sys
    import time

    from skyherd.runio import launch

    code = "import signal, time\nsignal.signal(signal.SIGINT, lambda *a: (time.sleep(1.0), exit(3)))\nprint('up', flush=True)\ntime.sleep(60)\n"  # fmt: skip
    kids = [launch.Child(f"k{i}", subprocess.Popen([sys.executable, "-c", code],
                                                   stdout=subprocess.PIPE), None) for i in range(4)]  # fmt: skip
    for k in kids:
        assert k.proc.stdout.readline() == b"up\n"
    t0 = time.monotonic()
    assert launch.stop_all(kids, grace_s=30.0) == [3, 3, 3, 3]
    assert time.monotonic() - t0 < 3.5  # sequential stops would take >= 4 s
    from skyherd.report.reason import COMPANION_EXITED, flight_reason

    assert flight_reason("landed", "") == "landed"
    assert flight_reason("x", f"{COMPANION_EXITED} 2") == "x"
    assert flight_reason("interrupted", "the flight took longer than --timeout 2 s") == (
        "the flight took longer than --timeout 2 s"
    )
