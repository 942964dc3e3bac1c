"""Test support: run the companion's own code (mission.companion.run free-running, a VehicleLink,
the phases of mission.steps) over a real MAVLink link, as `skyherd companion --free-run` runs
a mission, with a mission given as a generator."""

from __future__ import annotations

import numpy as np

from skyherd.flight.autopilot_api import Setpoint
from skyherd.hil.link import MavlinkLink
from skyherd.mission.authority import ModeAuthority
from skyherd.mission.companion import CompanionParams, run
from skyherd.mission.steps import recipe, wait_ready, wait_until
from skyherd.mission.vehicle import VehicleLink
from skyherd.runio.constants import COMPANION_COMPONENT


class Steps:
    """A mission for mission.companion.run that is only its generator (no camera)."""

    name = "steps"

    def on_frame(self, t, frame, status) -> None:
        pass


def fly(link: MavlinkLink | str, mission, gen=None, patience_s: float = 30.0) -> VehicleLink:
    """Run `gen(v)` (or `mission.run(v)`) on a VehicleLink over `link` (an open link, or an
    address opened as component 191 and closed after), ticked on the autopilot's clock until
    it returns; what it raises, raises here."""
    own = isinstance(link, str)
    if own:
        link = MavlinkLink.open(link, source_component=COMPANION_COMPONENT)
    v = VehicleLink(link)
    try:
        run(v, mission, (gen or mission.run)(v), None,
            CompanionParams(lockstep=False, link_patience_s=patience_s))  # fmt: skip
    finally:
        if own:
            link.close()
    return v


def watched(v: VehicleLink, auth: ModeAuthority, predicate, what: str, timeout_s: float = 5.0):
    """Wait as a mission's AI phase does: the authority sees every tick's mode; ends early if
    the autopilot took the vehicle (then `auth.yielded` says why)."""
    t0 = v.t
    while auth.update(v) == "fly" and not predicate():
        assert v.t - t0 <= timeout_s, f"timed out after {timeout_s:.0f} s waiting for {what}"
        yield


def missions(altitude: float, target_ned, reach_m: float, n: int, out: dict):
    """The mission generator: `n` times take-off (the profile's recipe), hand-over to a target,
    the net's fallback and back (ModeAuthority, as the missions map it), landing (or, for a
    plane, its return); what each showed goes to `out`."""

    def gen(v):
        yield from wait_ready(v)
        prof, target = v.profile, Setpoint(pos_ned=np.asarray(target_ned, float))
        for k in range(n):
            auth = ModeAuthority()
            yield from recipe(v, prof.takeoff_steps(altitude, v.home_amsl_m))
            yield from recipe(v, prof.handover_steps(), hold=lambda: target)
            auth.adopt(v, prof.ai_mode)
            yield from watched(v, auth, lambda: np.linalg.norm(v.tel.pos_ned[:2] - target.pos_ned[:2])
                               < reach_m, "the target", timeout_s=120.0)  # fmt: skip
            auth.want(v, prof.fallback_mode)
            yield from watched(v, auth, lambda: v.tel.mode is prof.fallback_mode, "the fallback")
            auth.want(v, prof.ai_mode)
            yield from watched(v, auth, lambda: v.tel.mode is prof.ai_mode, "the AI's mode")
            out[f"yielded_{k}"] = auth.yielded
            yield from recipe(v, prof.land_steps() + prof.end_steps())
            if prof.vehicle == "multirotor":
                yield from wait_until(v, lambda: not v.tel.armed, 60.0, "disarmed")
            out[f"armed_{k}"] = v.tel.armed

    return gen


def judge_checks(summary: str) -> dict[str, tuple[str, str]]:
    """The judge's table in a `skyherd fly` run's summary.md: check → (pass | FAIL, figure)."""
    out, inside = {}, False
    for line in summary.splitlines():
        if line.startswith("## "):
            inside = line.startswith("## The judge")
            continue
        cells = [c.strip() for c in line.strip().strip("|").split("|")]
        if inside and len(cells) >= 3 and cells[1] in ("pass", "FAIL"):
            out[cells[0]] = (cells[1], cells[2])
    return out
