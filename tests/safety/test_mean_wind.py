"""`skyherd fly --wind` against the constraint set's wind limit (safety.config.check_mean_wind):
refused above [guards] wind_limit_mps (12 m/s for the quadrotor's ground-air set)."""

from __future__ import annotations

import pytest

from skyherd.flight.faults import wind_from
from skyherd.safety.config import check_mean_wind, fly_envelope


def test_mean_wind_above_the_limit_is_refused(tmp_path):
    assert fly_envelope(None, "quadrotor").guards.wind_limit_mps == 12.0
    check_mean_wind(None, "quadrotor", wind_from(12.0, 270.0), "12,270")
    with pytest.raises(ValueError, match=r"--wind 13,270: 13.0 m/s is above .* limit 12 m/s"):
        check_mean_wind(None, "quadrotor", wind_from(13.0, 270.0), "13,270")
    with pytest.raises(ValueError, match="fix it or pass another --envelope"):
        check_mean_wind(tmp_path / "missing.toml", "quadrotor", (0.0, 0.0, 0.0), "0,0")
