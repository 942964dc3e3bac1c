"""`skyherd explain RUN`: a readable timeline from decisions.jsonl in the companion's record format
(built by hand here, as the companion writes it: LAYOUT's per-decision record)."""

import json

from skyherd.policy.education.timeline import describe_velocity, read_decisions, timeline
from skyherd.scripts.cli import main


def _rec(t, vel, verdict="accepted", certified=None, explanation=None, pilot="policy", reason="ok"):
    sp = {"pos_ned": None, "vel_ned": vel, "yaw": 0.0}
    r = {"t": t, "vehicle": "uav0", "pilot": pilot, "phi": [0.81, 0.5, 0.3, 0.4, 1, 1, 0.3, 1],
         "proposed": sp, "certified": {**sp, "vel_ned": certified or vel}, "verdict": verdict,
         "reason": reason, "mode": "ai", "autopilot_mode": "OFFBOARD"}  # fmt: skip
    if explanation is not None:
        r["explanation"] = explanation
    return r


LAT = {"module": "lateral", "reason": "team 0.31 right of centre",
       "concepts": {"offset_east": 0.31, "offset_south": -0.02}}  # fmt: skip
UP = {"module": "climb", "reason": "a UGV is out of view", "concepts": {"in_view": 0.0}}


def _run(tmp_path, records, torn=True):
    d = tmp_path / "run"
    d.mkdir()
    lines = [json.dumps(r) for r in records]
    text = "\n".join(lines) + "\n" + ('{"t": 99, "vehic' if torn else "")  # a kill mid-write
    (d / "decisions.jsonl").write_text(text)
    return d


def test_timeline_reads_the_record_format_and_folds_repeats(tmp_path, capsys):
    recs = [_rec(12.0, [0, 4, 0], explanation=LAT), _rec(12.5, [0, 4, 0], explanation=LAT),
            _rec(13.0, [0, 4, 0], "projected", [0, 2.1, 0], LAT, reason="acceleration limit"),
            _rec(13.5, [0, 0, -2], explanation=UP),
            _rec(14.0, [0, 0, 0], "pid", [1.0, 0, 0], pilot="pid", reason="recovery")]  # fmt: skip
    run = _run(tmp_path, recs)
    decisions, bad = read_decisions(run / "decisions.jsonl")
    assert len(decisions) == 5 and bad == 1
    lines = timeline(decisions)
    assert lines[0] == (
        "t = 12.0 s lateral: team 0.31 right of centre → east 4 m/s; net: accepted  (×2 until t = 12.5 s)"
    )
    assert lines[1].startswith("t = 13.0 s lateral: team 0.31 right of centre → east 4 m/s; "
                               "net: projected → east 2.1 m/s (acceleration limit)")  # fmt: skip
    assert lines[2] == "t = 13.5 s climb: a UGV is out of view → climb 2 m/s; net: accepted"
    assert lines[3].startswith(
        "t = 14.0 s pid: no explanation recorded → hover; net: pid → north 1 m/s"
    )
    assert main(["explain", str(run)]) == 0
    out = capsys.readouterr().out.splitlines()
    assert out[:4] == lines and out[-1] == "5 decisions, 4 explained, 1 unreadable lines skipped"


def test_explain_at_a_time_shows_the_concepts(tmp_path, capsys):
    run = _run(
        tmp_path, [_rec(12.0, [0, 4, 0], explanation=LAT), _rec(13.5, [0, 0, -2], explanation=UP)]
    )
    assert main(["explain", str(run), "--t", "13.2"]) == 0
    out = capsys.readouterr().out
    assert out.startswith("t = 12.0 s lateral: team 0.31 right of centre")
    assert "offset_east = 0.31" in out and "autopilot OFFBOARD" in out
    assert main(["explain", str(run / "decisions.jsonl"), "--t", "20"]) == 0
    assert capsys.readouterr().out.startswith("t = 13.5 s climb")


def test_explain_bad_usage(tmp_path, capsys):
    assert main(["explain", str(tmp_path / "nowhere")]) == 2
    assert "no decisions.jsonl" in capsys.readouterr().err
    (tmp_path / "decisions.jsonl").write_text("garbage\n[1, 2]\n")
    assert main(["explain", str(tmp_path)]) == 2
    assert "no readable decision records (2 unreadable lines)" in capsys.readouterr().err


def test_describe_velocity():
    assert describe_velocity([0, -4, 0]) == "west 4 m/s"
    assert describe_velocity([0, 0, 1.5]) == "descend 1.5 m/s"
    assert describe_velocity([0.01, 0, 0]) == "hover"
    assert describe_velocity(None) == "-" and describe_velocity([1, "x", 0]) == "-"
    # the whole command, largest component first; only components below 5 mm/s are left out
    assert describe_velocity([0, 2.1, -0.58]) == "east 2.1 m/s, climb 0.58 m/s"
    assert (
        describe_velocity([-0.34, 0.69, 0.09]) == "east 0.69 m/s, south 0.34 m/s, descend 0.09 m/s"
    )
    assert describe_velocity([0.004, -3, 0]) == "west 3 m/s"


def test_a_projected_decision_states_the_certified_command_in_full(tmp_path, capsys):
    """The net added a 0.58 m/s climb to a 4 m/s east proposal: the timeline and the detail
    both say so (issue 29: only the largest component was named)."""
    rec = _rec(13.0, [0, 4, 0], "projected", [0, 2.1, -0.58], LAT, reason="acceleration limit")
    run = _run(tmp_path, [rec], torn=False)
    assert main(["explain", str(run)]) == 0
    assert capsys.readouterr().out.splitlines()[0] == (
        "t = 13.0 s lateral: team 0.31 right of centre → east 4 m/s; "
        "net: projected → east 2.1 m/s, climb 0.58 m/s (acceleration limit)"
    )
    assert main(["explain", str(run), "--t", "13"]) == 0
    out = capsys.readouterr().out
    assert "    proposed (+0.00, +4.00, +0.00) m/s NED" in out
    assert "    certified (+0.00, +2.10, -0.58) m/s NED" in out
