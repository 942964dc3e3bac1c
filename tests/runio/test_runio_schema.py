"""runio.schema: a table of plain values is checked without pydantic, and takes exactly the values
pydantic's strict check takes, as pydantic gives them; anything else goes to pydantic, whose
one-line errors stay as they were. `skyherd fly`'s and the companion's default tables need no
pydantic at all (issue 31: its import and first model were ~0.07 CPU s of each)."""

from __future__ import annotations

import math
import subprocess
import sys

import pytest

from skyherd.runio.schema import STRICT, ConfigError, _plain, validate_mapping

TYPES = [float, int, str, bool, float | None, int | None, str | None]
VALUES = [0, 1, -5, 2**53, 2**53 + 1, 2**70, 1.5, -0.0, 1e308, math.nan, math.inf, -math.inf,
          True, False, "x", "1.5", "", None, [1.0], {"a": 1}]  # fmt: skip


@pytest.mark.parametrize("typ", TYPES, ids=str)
def test_plain_values_are_taken_as_pydantics_strict_check_takes_them(typ):
    import json

    from pydantic import ValidationError, create_model

    model = create_model("T", __config__=STRICT, v=(typ, None))
    for value in VALUES:
        ok, got = _plain(typ, value)
        try:
            want = model.model_validate_json(json.dumps({"v": value}, allow_nan=True)).v
        except ValidationError:
            assert not ok, (typ, value)  # what pydantic refuses never passes without it
            continue
        if ok:
            assert type(got) is type(want) and (got == want or got != got), (typ, value, got)
            assert math.copysign(1, got) == math.copysign(1, want) if type(got) is float else True


def test_a_bad_table_still_gets_pydantics_one_line_error():
    with pytest.raises(ConfigError, match=r"\[params\] unknown key 'typo'"):
        validate_mapping({"typo": 1.0}, float, ["MPC_XY_VEL_MAX"], "params")
    with pytest.raises(ConfigError, match=r"\[params\] MPC_XY_VEL_MAX must be a finite number"):
        validate_mapping({"MPC_XY_VEL_MAX": "fast"}, float, ["MPC_XY_VEL_MAX"], "params")
    assert validate_mapping({"MPC_XY_VEL_MAX": 4}, float, ["MPC_XY_VEL_MAX"], "params") == {
        "MPC_XY_VEL_MAX": 4.0
    }


DEFAULT_TABLES = """
import sys
from skyherd.safety.config import default_envelope_path, fill_dataclass, load_envelope
from skyherd.safety.supervisor import SupervisorParams
for airframe in ("quadrotor", "fixedwing"):
    load_envelope(default_envelope_path(airframe))
fill_dataclass(SupervisorParams, {}, "supervisor")
print("pydantic" in sys.modules)
"""


def test_the_default_envelopes_load_without_pydantic():
    out = subprocess.run([sys.executable, "-c", DEFAULT_TABLES], capture_output=True, text=True,
                         timeout=120, check=True).stdout.split()  # fmt: skip
    assert out == ["False"]
