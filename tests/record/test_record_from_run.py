"""flight.mcap from a run folder's files (record.from_run, `skyherd record`): poses, UGVs,
decisions with their setpoints drawn from the pose of their time, events, the fence; bad lines
skipped and counted."""

from __future__ import annotations

import json
import re

from google.protobuf import descriptor_pb2, descriptor_pool, message_factory
from mcap.reader import make_reader

from skyherd.record import read_messages
from skyherd.scripts.cli import main


def _folder(tmp_path):
    from skyherd.safety.config import default_envelope_path

    run = tmp_path / "runs" / "20261201T000000Z-companion"
    sim = tmp_path / "runs" / "20261201T000000Z-sim"
    run.mkdir(parents=True)
    sim.mkdir()
    rows = ["t,north,east,down,vn,ve,vd,mode,armed,phase"]
    rows += [f"{0.5 * k},{k},0.0,-20.0,2,0,0,OFFBOARD,1,policy" for k in range(10)]
    rows += ["oops,1,2,3,,,,,,"]
    (run / "metrics.csv").write_text("\n".join(rows) + "\n")
    world = ["t,north,east,down,ugv0_n,ugv0_e,ugv1_n,ugv1_e"]
    world += [f"{0.5 * k},{k},0,-20,{k},5,{k},-5" for k in range(10)]
    (sim / "world.csv").write_text("\n".join(world) + "\n")
    dec = [json.dumps({"t": 0.5 * k, "vehicle": "uav0", "phi": [0.5] * 8, "verdict": "projected",
                       "proposed": {"vel_ned": [4, 0, 0]}, "certified": {"vel_ned": [2, 0, 0]},
                       "reason": "accel", "mode": "ai"}) for k in range(10)]  # fmt: skip
    (run / "decisions.jsonl").write_text("\n".join(dec) + '\n{"t": 5.0, "verd')
    ev = {"t": 2.0, "event": "switch", "from": "ai", "to": "fallback", "reason": "fence"}
    (run / "events.jsonl").write_text(
        json.dumps(ev) + "\n" + json.dumps({"event": "no time"}) + "\n"
    )
    env = default_envelope_path("quadrotor")
    (run / "config.json").write_text(json.dumps({"envelope": {"file": {"path": str(env)}}}))
    return run, sim


def test_skyherd_record_builds_flight_mcap_from_a_run_folder(tmp_path, capsys):
    run, sim = _folder(tmp_path)
    assert main(["record", str(run), "--also", str(sim)]) == 0
    got = read_messages(run / "flight.mcap")
    c = got.counts()
    assert got.complete and c["/uav0/pose"] == 20 and c["/ugvs"] == 10  # metrics + world rows
    assert c["/uav0/decision"] == 10 and c["/uav0/phi"] == 10 and c["/uav0/setpoint"] == 10
    assert c["/uav0/safety/event"] == 1 and c["/geometry"] >= 1
    out = capsys.readouterr().out
    assert re.search(r"skipped in metrics.csv +\| 1 ", out)
    assert re.search(r"skipped in decisions.jsonl +\| 1 ", out)
    # the arrow of the decision at t = 2.0 s starts at the pose of t = 2.0 s (north 4 m)
    with open(run / "flight.mcap", "rb") as f:
        for schema, _channel, msg in make_reader(f).iter_messages(topics=["/uav0/setpoint"]):
            if msg.log_time == 2_000_000_000:
                fds = descriptor_pb2.FileDescriptorSet.FromString(schema.data)
                pool = descriptor_pool.DescriptorPool()
                for fd in fds.file:
                    pool.Add(fd)
                cls = message_factory.GetMessageClass(pool.FindMessageTypeByName(schema.name))
                arrows = cls.FromString(msg.data).entities[0].arrows
                assert [a.pose.position.x for a in arrows] == [4.0, 4.0]


def test_skyherd_record_bad_usage_and_empty_folder(tmp_path):
    assert main(["record", str(tmp_path / "none")]) == 2
    (tmp_path / "empty").mkdir()
    assert main(["record", str(tmp_path / "empty")]) == 1
