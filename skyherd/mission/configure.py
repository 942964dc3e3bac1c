"""`--configure-autopilot`: set the autopilot's parameters the safety envelope requires, read
each back, record every change — before the take-off, and only when the operator asks.

Without it the companion refuses to take off on a mismatch (safety.consistency's rule and the
value to set, e.g. "GUID_TIMEOUT = 3 s ... set GUID_TIMEOUT <= 0.53 s"). With it, each value
`safety.consistency.required_values` gives is sent (PARAM_SET), its echo awaited (PARAM_VALUE,
mission.steps.set_param_checked), and the change written as {name, before, after, reason} to
the mission's `configured` list (companion.json, summary.md, and a line on stderr). Nothing is
restored afterwards: the autopilot keeps the values the envelope needs, and the records say
what they were before. What cannot be set this way (a value that is not a number, an INT32
parameter) still refuses the take-off with its reason.
"""

from __future__ import annotations

from dataclasses import dataclass

from skyherd.mission.steps import Phase, set_param_checked
from skyherd.mission.vehicle import VehicleLink
from skyherd.safety.consistency import check_params, required_values
from skyherd.safety.net import SafetyNet


@dataclass(frozen=True)
class Change:
    name: str
    before: float
    after: float
    reason: str  # the rule the old value broke (safety.consistency.check_params)

    def record(self) -> dict:
        return {"name": self.name, "before": self.before, "after": self.after,
                "reason": self.reason}  # fmt: skip


def configure(v: VehicleLink, net: SafetyNet, changes: list[Change], say=None) -> Phase:
    """Set every parameter the envelope requires (after read_params), appending each change to
    `changes`; the guard then sees the echoes (the caller reloads it)."""
    pos_max = net.p.pos_speed_max_mps
    spec = net.spec
    why = check_params(spec, v.params, pos_max)
    for name, value in required_values(spec, v.params, pos_max).items():
        before = float(v.params[name])
        yield from set_param_checked(v, name, value)
        changes.append(Change(name, before, value, why[name]))
        if say is not None:
            say(f"--configure-autopilot: {name} {before:g} -> {value:g} ({why[name]})")
