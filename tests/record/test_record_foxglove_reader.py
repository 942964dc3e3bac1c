"""Opt-in: a flight's MCAP read by Foxglove's own TypeScript reader (@mcap/core, as the Foxglove
app reads files: summary, chunk index, zstd chunks) and every message decoded from the schema in
the file (protobufjs from the FileDescriptorSet; JSON), i.e. it opens without conversion.

    npm install --prefix tests/js          # once (the registry's @mcap/core, protobufjs, fzstd)
    SKYHERD_MCAP_NODE=1 .venv/bin/python -m pytest -q tests/record/test_record_foxglove_reader.py
"""

from __future__ import annotations

import json
import os
import shutil
import subprocess
from pathlib import Path

import pytest

from skyherd.record import FlightRecorder

JS = Path(__file__).resolve().parents[1] / "js"
pytestmark = pytest.mark.skipif(
    not os.environ.get("SKYHERD_MCAP_NODE"),
    reason="opt-in: set SKYHERD_MCAP_NODE=1 (needs node and `npm install --prefix tests/js`)",
)


def test_foxglove_reader_decodes_every_channel(tmp_path):
    from test_record_mcap import EXPECTED, _fly

    node = shutil.which("node")
    modules = Path(os.environ.get("SKYHERD_MCAP_NODE_MODULES", JS / "node_modules"))
    if node is None or not (modules / "@mcap" / "core").is_dir():
        pytest.fail(f"needs node and {modules}/@mcap/core: run `npm install --prefix {JS}`")
    path = tmp_path / "flight.mcap"
    with FlightRecorder(path) as rec:
        _fly(rec)
    r = subprocess.run([node, str(JS / "read_mcap.cjs"), str(path)], capture_output=True, text=True,
                       timeout=120, env={**os.environ, "NODE_PATH": str(modules)})  # fmt: skip
    assert r.returncode == 0, r.stderr
    got = json.loads(r.stdout)
    assert {k: (v["schema"], v["count"]) for k, v in got.items() if k != "/geometry"} == EXPECTED
    assert got["/uav0/camera/image"]["first"]["format"] == "jpeg"
    assert got["/uav0/pose"]["first"]["frameId"] == "ned"
    assert got["/uav0/pose"]["log_time_ns"] == [0, 100_000_000, 200_000_000]
    assert got["/uav0/log"]["first"]["message"] == "switch ai → fallback: fence"
    assert got["/uav0/decision"]["first"]["verdict"] == "accepted"


def test_foxglove_stream_reader_reads_a_cut_file_up_to_its_last_chunk(tmp_path):
    """Foxglove reads a file without a summary (a killed flight) as a stream: @mcap/core's
    stream reader gets every message of the complete chunks, as record.read_messages does."""
    from skyherd.record import read_messages

    node = shutil.which("node")
    modules = Path(os.environ.get("SKYHERD_MCAP_NODE_MODULES", JS / "node_modules"))
    path = tmp_path / "flight.mcap"
    rec = FlightRecorder(path, chunk_s=0.5)
    for k in range(40):
        rec.pose(0.1 * k, [k, 0, -10])
        rec.event(0.1 * k, {"t": 0.1 * k, "event": "tick", "reason": str(k)})
    data = path.read_bytes()
    rec.close()
    cut = tmp_path / "cut.mcap"
    cut.write_bytes(data[: len(data) - 7])  # inside the last chunk's message index
    want = len(read_messages(cut).messages)
    r = subprocess.run([node, str(JS / "read_mcap.cjs"), "--stream", str(cut)], capture_output=True,
                       text=True, timeout=120, env={**os.environ, "NODE_PATH": str(modules)})  # fmt: skip
    assert r.returncode == 0, r.stderr
    got = json.loads(r.stdout)
    assert got == {"messages": want, "complete": False} and want >= 100
