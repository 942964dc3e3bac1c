"""Demonstrations flown by a person, without the command line (hil.teleop): keys through a real
pipe become the scenario's actions, the text view marks the UGVs in view."""

import os

from skyherd.hil.teleop import KEYS, KeyboardPilot, text_view
from skyherd.policy.demos import ALLOWED_ACTIONS
from skyherd.policy.groundair.env import GroundAirEnv


def test_keys_become_the_scenarios_actions_and_q_stops():
    r, w = os.pipe()
    try:
        os.write(w, b"rRwx fq")
        pilot = KeyboardPilot(r, 0.0, ALLOWED_ACTIONS["climb"])  # one key per step
        got = [pilot(None) for _ in range(7)]
    finally:
        os.close(r)
        os.close(w)
    # r, R climb; w (north) and x are not climb's, space hovers, f descends (not climb's), q stops
    assert got == [KEYS["r"], KEYS["r"], 0, 0, 0, 0, -1]


def test_keys_in_real_time_take_the_last_key_of_each_step():
    r, w = os.pipe()
    try:
        os.write(w, b"sw")  # both within the first step: the last one counts
        pilot = KeyboardPilot(r, 0.05, ALLOWED_ACTIONS["lateral"])
        first, second = pilot(None), pilot(None)  # nothing pressed in the second step: hover
    finally:
        os.close(r)
        os.close(w)
    assert (first, second) == (KEYS["w"], 0)


def test_the_text_view_marks_the_image_centre_and_the_ugvs_in_view():
    env = GroundAirEnv("composite")
    env.reset(seed=3)
    view = text_view(env).split("\r\n")
    assert len(view) == 17 and all(len(row) == 42 for row in view)
    assert view[1 + 15 // 2][1 + 40 // 2] == "+"
    _, seen = env.cam.pixels(env.n, env.e, env.alt, env.formation.positions())
    marks = "".join(view).count("o")  # two UGVs in one character cell make one mark
    assert 1 <= marks <= int(sum(seen))
