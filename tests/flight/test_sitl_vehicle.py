"""`skyherd sitl`'s vehicle without the command line (flight.sitl_vehicle): the parameters an
earlier run saved are found and said, the links announced are the PX4 SITL layout's."""

import json

from skyherd.flight.mavlink import EndpointConfig
from skyherd.flight.sitl_vehicle import links_table, saved_params, saved_params_line


def test_saved_parameters_are_found_and_said_never_silently(tmp_path):
    config = EndpointConfig(instance=3, state_dir=tmp_path)
    assert saved_params(config, "quadrotor")["values"] == {}
    assert saved_params_line(saved_params(config, "quadrotor")) is None
    values = {f"P{k}": float(k) for k in range(8)}
    path = tmp_path / "quadrotor-3" / "params.json"
    path.parent.mkdir()
    path.write_text(json.dumps({"version": 1, "params": values}))
    saved = saved_params(config, "quadrotor")
    assert saved == {"file": str(path), "values": values}
    line = saved_params_line(saved)
    assert line.startswith(f"skyherd sitl: 8 parameters saved in {path} loaded again (P0=0, ")
    assert "P5=5, +2 more); delete that file" in line
    assert saved_params(EndpointConfig(instance=3), "quadrotor") == {"file": None, "values": {}}


def test_the_links_are_the_px4_sitl_layout_of_the_instance():
    table = links_table(EndpointConfig(instance=3))
    assert "| api / offboard | udp 127.0.0.1:14583 | 127.0.0.1:14543 |" in table
    assert "| ground station | udp 127.0.0.1:18573 | 127.0.0.1:14550 |" in table
