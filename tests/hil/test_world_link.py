"""The link the world follows an outside autopilot on (`skyherd fly --connect` beside the
ground-air mission): --world-link, else a default from the autopilot's own address."""

from __future__ import annotations

import pytest

from skyherd.hil.link import world_link
from skyherd.runio.address import AddressError


def test_world_link_defaults_and_refusals():
    assert world_link("tcp:127.0.0.1:5760") == "tcp:127.0.0.1:5762"  # ArduPilot's SERIAL1
    assert world_link("udpin:127.0.0.1:14540") == "udpin:127.0.0.1:14550"  # its GCS stream
    assert world_link("tcp:127.0.0.1:5760", "udpin:127.0.0.1:14551") == "udpin:127.0.0.1:14551"
    with pytest.raises(AddressError, match="^--world-link: "):
        world_link("tcp:127.0.0.1:5760", "tcpin:127.0.0.1:9")
    with pytest.raises(AddressError, match="serial autopilot needs --world-link"):
        world_link("/dev/ttyACM0,57600")
