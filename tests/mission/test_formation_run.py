"""A formation run folder read back (mission.formation_run) without the command line: the tracks
of metrics.csv, every vehicle judged from its own world.csv in the field frame, and plan.json's
text (mission.formation_plan.plan_text)."""

from __future__ import annotations

import json

import numpy as np

from skyherd.mission.formation_plan import TRACK_COLUMNS, FormationParams, load_plan, plan_text
from skyherd.mission.formation_run import judge_vehicles, read_tracks
from skyherd.safety.judge import first_failed

PLAN = [[(1, 1), (2, 1), (3, 1)], [(1, 3), (1, 4), (1, 5)]]


def test_tracks_are_per_vehicle_and_a_torn_line_or_a_stranger_is_left_out(tmp_path):
    assert [t.shape for t in read_tracks(tmp_path, 2)] == [(0, 4), (0, 4)]  # no metrics.csv
    row = dict.fromkeys(TRACK_COLUMNS, "0")
    lines = [",".join(TRACK_COLUMNS)]
    for t, k, n in ((0.0, 0, 1.0), (0.0, 1, 4.0), (0.1, 0, 1.5), (0.1, 7, 9.0)):
        lines.append(",".join(str(v) for v in (row | {"t": t, "vehicle": k, "north": n}).values()))
    lines.append("0.2,1,4.")  # cut by a kill
    (tmp_path / "metrics.csv").write_text("\n".join(lines))
    tracks = read_tracks(tmp_path, 2)
    assert np.allclose(tracks[0], [[0.0, 1.0, 0.0, 0.0], [0.1, 1.5, 0.0, 0.0]])
    assert np.allclose(tracks[1], [[0.0, 4.0, 0.0, 0.0]])


def _world(path, north: float) -> None:
    path.mkdir()
    rows = [f"{t / 10:.1f},{north},0.0,-8.0,OFFBOARD,1" for t in range(200)]
    (path / "world.csv").write_text("t,north,east,down,mode,armed\n" + "\n".join(rows) + "\n")


def test_each_vehicle_is_judged_on_its_own_truth_moved_into_the_field(tmp_path):
    """Both vehicles hover 8 m over their homes; vehicle 1's world.csv says 300 m north of it:
    outside the formation's fence. Only vehicle 1 fails, on the fence."""
    _world(tmp_path / "uav0", 0.0)
    _world(tmp_path / "uav1", 300.0)
    events = [{"vehicle": f"uav{k}", "event": "handover", "t": 1.0} for k in (0, 1)]
    (tmp_path / "events.jsonl").write_text(
        "\n".join(json.dumps(e) for e in events) + '\n{"vehicle": "uav'  # a line cut by a kill
    )
    comp = {"outcome": "completed", "times": {"all_over_targets": 15.0}}
    judged = judge_vehicles(tmp_path, PLAN, FormationParams(), comp)
    fence = [{c.name: c.ok for c in checks}["fence"] for checks in judged]
    assert fence == [True, False]
    assert first_failed(judged[1]).name == "fence"


def test_plan_json_is_what_load_plan_reads(tmp_path):
    path = tmp_path / "plan.json"
    path.write_text(plan_text(PLAN))
    assert path.read_text().splitlines()[1] == "  [[1,1],[2,1],[3,1]],"
    assert load_plan(path, 2) == PLAN
