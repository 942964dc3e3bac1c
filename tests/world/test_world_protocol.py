"""world.protocol.SimWorld: what `skyherd sim` runs, one interface for its three worlds, and
hil.bridge_select.Bridge, what both bridges are to the bridged world (issue 28 item 5).
world.serve acts on SIGUSR1 through the interface alone (it used to ask each world what it
had: hasattr), so a world that lacks a method fails here, not in a flight."""

from __future__ import annotations

import pytest

from skyherd.hil.bridge_select import AUTOPILOTS, Bridge, make_bridge
from skyherd.world.bridged import BridgedWorld
from skyherd.world.follow import FollowWorld
from skyherd.world.protocol import SimWorld
from skyherd.world.serve import COMPANION_GONE, FLY_DIED, companion_signal
from skyherd.world.sim import World, WorldParams

MEMBERS = [n for n in vars(SimWorld) if not n.startswith("_")]


@pytest.mark.parametrize("cls", [World, FollowWorld, BridgedWorld])
def test_every_world_has_the_whole_interface(cls):
    assert set(MEMBERS) == {"run", "stop", "companion_gone", "parent_died", "close"}
    for name in MEMBERS:
        assert callable(getattr(cls, name, None)), (cls.__name__, name)


@pytest.mark.parametrize("autopilot", AUTOPILOTS)
def test_both_bridges_are_bridges(autopilot):
    bridge = make_bridge(autopilot, instance=77)  # not opened: nothing bound yet
    try:
        assert isinstance(bridge, Bridge) and bridge.t == 0.0
    finally:
        bridge.close()


@pytest.mark.parametrize("died", [False, True])
def test_a_bridged_world_stops_on_sigusr1_through_the_interface(tmp_path, died):
    """Nothing flies alone on a bridge: the companion gone or fly dead, the world stops."""
    bridge = make_bridge("ardupilot", instance=77)
    world = BridgedWorld(bridge, WorldParams(instance=77, scenario="none"), run_dir=tmp_path)
    try:
        assert isinstance(world, SimWorld) and not world._stop.is_set()
        companion_signal([world], died)
        assert world._stop.is_set()
    finally:
        world.close()


def test_the_built_in_world_steps_on_alone_and_says_why(tmp_path):
    world = World(WorldParams(instance=78, scenario="none", lockstep=False), run_dir=tmp_path)
    try:
        companion_signal([world], died=False)
        assert world._alone.is_set() and world.alone_why == COMPANION_GONE
    finally:
        world.close()
    world = World(WorldParams(instance=78, scenario="none", lockstep=False), run_dir=tmp_path)
    try:
        companion_signal([world], died=True)  # before the flight: alone at once
        assert world._alone.is_set() and world.alone_why == FLY_DIED
    finally:
        world.close()
