"""`skyherd sim`'s setup without its command line (world.setup, world.build): the checks name
the option and what to do, and the defaults are filled in as the command fills them."""

from __future__ import annotations

import pytest

from skyherd.runio import ports
from skyherd.world.build import WorldError, parse_home, parse_windows
from skyherd.world.setup import SimSetup


def test_checked_fills_the_instances_port_and_the_speedup():
    s = SimSetup(instance=3).checked()
    assert s.zenoh_port == ports.zenoh_port(3) == 7450
    assert s.speedup == 0.0  # lockstep: as fast as possible
    assert SimSetup(free_run=True).checked().speedup == 10.0  # free-running needs a pacer
    params, endpoint = s.world_params()
    assert params.instance == endpoint.instance == 3 and params.lockstep


@pytest.mark.parametrize(
    "setup, said",
    [
        (SimSetup(ugvs="none", cut_camera=("1:1",)), "--ugvs none is the built-in vehicle alone"),
        (SimSetup(ugvs="flock", follow="udpin:127.0.0.1:14550"), "--ugvs flock flees"),
        (SimSetup(speedup=0.5), "--speedup must be 0"),
        (SimSetup(latency=float("nan")), "--latency nan: must be a finite number >= 0"),
        (SimSetup(cut_link=("30",)), "--cut-link '30': expected T:D"),
        (SimSetup(fault=("bogus@1",)), "bogus"),
        (SimSetup(param=("COM_OF_LOS_T=3",)), "did you mean COM_OF_LOSS_T"),
        (
            SimSetup(ugvs="none", fleet="fleet.json", param=("COM_OF_LOSS_T=3",)),
            "--fleet: built-in",
        ),
    ],
)
def test_checked_refuses_with_the_options_name(setup, said):
    with pytest.raises(ValueError) as e:
        setup.checked()
    assert said in str(e.value)


def test_text_forms_of_home_and_windows():
    assert parse_home(None) is None
    assert parse_home("47.397742,8.545594,488") == (47.397742, 8.545594, 488.0)
    with pytest.raises(WorldError, match="out of range"):
        parse_home("95,0,0")
    assert parse_windows(["30:3", "40.5:0.5"], "--cut-camera") == ((30.0, 3.0), (40.5, 0.5))
    with pytest.raises(WorldError, match=r"--cut-camera '5:0': T must be >= 0 and D > 0"):
        parse_windows(["5:0"], "--cut-camera")
