"""world/scene.py's world.csv rows: written cell by cell in the header's order, the same bytes as
the dict rows they were written from before (every column through runio's to_jsonable)."""

import math

import numpy as np
import pytest

from skyherd.flight.state import VehicleState
from skyherd.groundsim.ugv import UGVStates
from skyherd.runio import CsvWriter
from skyherd.task.params import TaskParams
from skyherd.world.params import WorldParams
from skyherd.world.scene import Scene
from skyherd.world.team import team_states


def dict_row(t, state, mode, armed, team_t, ugvs) -> dict:
    """A world.csv row as the dict it was written from before."""
    v = state.vel_ned if state.vel_ned is not None else np.full(3, np.nan)
    p = state.pos_ned
    row = {"t": t, "north": p[0], "east": p[1], "down": p[2], "vn": v[0], "ve": v[1], "vd": v[2],
           "mode": mode, "armed": "" if armed is None else int(armed),
           "team_t": "" if team_t is None else round(team_t, 6)}  # fmt: skip
    for i in range(0 if ugvs is None else ugvs.n):
        row[f"ugv{i}_n"], row[f"ugv{i}_e"] = ugvs.pos_ne[i, 0], ugvs.pos_ne[i, 1]
    return row


@pytest.mark.parametrize("scenario", ["composite", "none"])
def test_truth_rows_are_the_dict_rows_they_were(tmp_path, scenario):
    rng = np.random.default_rng(7)
    (tmp_path / "new").mkdir()
    scene = Scene(WorldParams(scenario=scenario), TaskParams(), run_dir=tmp_path / "new")
    old = CsvWriter(tmp_path / "old.csv", scene.truth.columns)
    awkward = [0.0, -0.0, 1e-300, 1e22, 0.1 + 0.2, math.nan, math.inf, -math.inf]
    for k in range(1500):
        pos = rng.uniform(-50, 50, 3)
        pos[rng.random(3) < 0.1] = rng.choice(awkward)
        vel = None if k % 7 == 0 else rng.normal(size=3)
        state = VehicleState(
            0.0, pos, vel, np.array([1.0, 0, 0, 0]), np.zeros(3), np.zeros(3), False
        )
        t = [k / 10, np.float64(k / 10 + 1e-9), k][k % 3]
        scene.team_t = [None, 0.1 * k + 1e-8, np.float64(k / 3)][k % 3]
        n = [3, 3, 2, 4][k % 4]  # a team the header counts, or one UGV fewer or more
        ugvs = UGVStates(rng.uniform(-40, 40, (n, 2)), np.zeros(n), np.zeros(n))
        ugvs = None if k % 11 == 0 or scene.team is None else ugvs
        mode, armed = ["OFFBOARD", "", "HOLD"][k % 3], [True, False, None][k % 3]
        scene.write_truth(t, state, mode, armed, ugvs)
        team = team_states(scene.team) if ugvs is None and scene.team else ugvs  # as it is
        old.write(dict_row(t, state, mode, armed, scene.team_t, team))
    scene.close()
    old.close()
    assert (tmp_path / "new" / "world.csv").read_bytes() == (tmp_path / "old.csv").read_bytes()
