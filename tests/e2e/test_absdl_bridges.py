"""Opt-in: the deep policy (ABS-DL, policy/models/groundair_absdl.npz) flown through the bridges
on real autopilots — PX4 `none_iris` and ArduCopter `--model JSON` on skyherd's physics, flown by
`skyherd fly --connect ADDRESS --policy ABSDL` (`make test-autopilots`). The same record as on the
built-in quadrotor (tests/e2e/test_absdl_fly.py): the judge's verdict and checks, the bridge's
truth (tests/e2e/test_bridge_autopilots.py), and the deep policy deciding — continuous commands,
each explained by the sub-skill network and its weight — with the fraction of decisions the net
changed and the all-in-view fraction printed.

Skipped unless SKYHERD_PX4_BIN / SKYHERD_ARDUCOPTER_BIN name the binaries; run inside a private
network namespace (pytest's). PX4 instance 91 (TCP 4651 to the bridge, onboard link 14549,
Zenoh 7538), its companion 92 (Zenoh 7539); ArduCopter instance 93 (UDP 9932 to the bridge,
SERIAL0 TCP 6690, Zenoh 7540), its companion 94 (Zenoh 7541).
"""

from __future__ import annotations

import pytest

from skyherd.policy.models import ABSDL_POLICY
from tests.e2e.test_absdl_fly import check_deep_policy
from tests.e2e.test_bridge_autopilots import Slots, check_flight, fly_arducopter, fly_px4

pytestmark = pytest.mark.autopilot

MIN_DECISIONS = (
    50  # one every 0.5 s of the autopilot's clock over the 30 s AI phase, less the hand-over
)


def test_px4_flies_the_deep_policy_through_the_bridge(tmp_path):
    flight = fly_px4(tmp_path, Slots(91, 7538, 92, 7539), "--policy", str(ABSDL_POLICY))
    fig = check_deep_policy(flight[2], MIN_DECISIONS)
    check_flight(*flight, "PX4")
    assert fig["in_view"] >= 0.9 and fig["changed_by_net"] < 0.10, fig


def test_arducopter_flies_the_deep_policy_through_the_bridge(tmp_path):
    """GUIDED is both ArduCopter's take-off and its AI mode: the team beside it starts at the
    companion's first decision (world/scene.py), so the policy takes over the same team as on
    PX4 (before that fix: the team started at the take-off, 15 s early, and was never all in
    view)."""
    flight = fly_arducopter(tmp_path, Slots(93, 7540, 94, 7541), "--policy", str(ABSDL_POLICY))
    fig = check_deep_policy(flight[2], MIN_DECISIONS)
    check_flight(*flight, "ArduCopter")
    assert fig["in_view"] >= 0.9 and fig["changed_by_net"] < 0.10, fig
