"""`skyherd drill`'s named and random drills of one airframe: the plan (its constraint set, the
supervisor's parameters, the drill parameters, the scripted and random drills) and flying it
drill by drill in the in-process drill loop (safety.drills.run_drill), every supervisor event
tagged with its drill and airframe, one metrics.csv row per drill. The randomized campaign is
safety.campaign_run's and mission.campaign's."""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Callable, Iterator
from dataclasses import dataclass

import numpy as np

from skyherd.flight.autopilot_api import Autopilot
from skyherd.safety.drills import (
    DrillParams,
    DrillResult,
    Script,
    random_drill,
    run_drill,
    scripted_drills,
)
from skyherd.safety.envelope import EnvelopeSpec
from skyherd.safety.supervisor import SupervisorParams

COLUMNS = [
    "drill",
    "airframe",
    "passed",
    "excursion_m",
    "fallback_s",
    "pid_s",
    "recover_s",
    "rejected",
    "projected",
    "switches",
    "first_reason",
    "why",
    "constraint_set_version",
]  # metrics.csv of `skyherd drill` (the campaign's: safety.campaign_run.COLUMNS)


def metrics_row(r, version: str) -> dict:
    """One drill's metrics.csv row (safety.drills.DrillResult `r`, its constraint set's version)."""
    return {
        "drill": r.name,
        "airframe": r.airframe,
        "passed": r.passed,
        "excursion_m": round(r.excursion_m, 3),
        "fallback_s": round(r.fallback_s, 3),
        "pid_s": round(r.pid_s, 3),
        "recover_s": "" if math.isnan(r.recover_s) else round(r.recover_s, 3),
        "rejected": r.rejected,
        "projected": r.projected,
        "switches": r.switches,
        "first_reason": r.reasons[0] if r.reasons else "",
        "why": r.why,
        "constraint_set_version": version,
    }


@dataclass(frozen=True)
class DrillPlan:
    """The drills of one airframe and what they fly with."""

    airframe: str
    spec: EnvelopeSpec
    sp: SupervisorParams
    p: DrillParams
    make: Callable[[int], Autopilot]  # seed → a fresh autopilot
    scripts: list[Script]

    def describe(self) -> dict:
        """The plan as config.json records it."""
        return {
            "airframe": self.airframe,
            "constraint_set": self.spec.describe(),
            "constraint_set_version": self.spec.version,
            "supervisor": self.sp,
            "drill": self.p,
            "drills": [s.name for s in self.scripts],
        }


def autopilot_factory(airframe: str) -> Callable[[int], Autopilot]:
    """A function of the seed that returns a fresh autopilot (on the ground, or ready to start
    in the air); AirframeUnavailable at once if the airframe's autopilot is not available."""
    from skyherd.flight.airframes_registry import make_autopilot

    make_autopilot(airframe)  # fail early if unavailable
    return lambda seed: make_autopilot(airframe, seed=seed)


def drill_plan(
    airframe: str,
    spec: EnvelopeSpec,
    sp: SupervisorParams,
    intervention: str | None = None,
    duration_s: float | None = None,
    only: str | None = None,
    n_random: int = 0,
    seed: int = 0,
) -> DrillPlan:
    """The scripted drills of `airframe` (those whose name contains one of the comma-separated
    `only`, if given) and `n_random` random ones drawn with `seed`; `intervention` (switch,
    project) and `duration_s` (AI time per drill [s]) replace the defaults. ValueError when
    `only` matches no drill and no random drill is asked for; AirframeUnavailable when the
    airframe's autopilot is not available."""
    if intervention:
        sp = dataclasses.replace(sp, intervention=intervention)
    make = autopilot_factory(airframe)
    p = (
        DrillParams()
        if duration_s is None
        else DrillParams(duration_s=duration_s, duration_fixedwing_s=duration_s)
    )
    scripts = scripted_drills(spec, p)
    if only:
        keys = [k.strip() for k in only.split(",") if k.strip()]
        scripts = [s for s in scripts if any(k in s.name for k in keys)]
        if not scripts and not n_random:
            names = [s.name for s in scripted_drills(spec, p)]
            raise ValueError(f"{only!r} matches no drill; names: {names}")
    rng = np.random.default_rng(seed)
    scripts += [random_drill(k, rng, spec, p) for k in range(n_random)]
    return DrillPlan(airframe, spec, sp, p, make, scripts)


def fly_plan(plan: DrillPlan, seed: int, events) -> Iterator[DrillResult]:
    """Each drill of `plan` flown on a fresh autopilot (`seed`), its result as it ends; its
    supervisor events to `events` (anything with write(dict)), tagged with the drill."""
    for script in plan.scripts:
        tagged = Tagged(events, script.name, plan.airframe)
        yield run_drill(script, plan.make(seed), plan.spec, plan.sp, plan.p, tagged)


def fly_plans(
    plans: list[DrillPlan],
    seed: int,
    events,
    metrics,
    on_result: Callable[[DrillPlan, DrillResult], None] | None = None,
) -> list[tuple[DrillResult, EnvelopeSpec]]:
    """Every drill of `plans` (`fly_plan`), each one's row to `metrics` (COLUMNS) as it ends,
    then `on_result(plan, result)`; the (result, constraint set) pairs in order."""
    results = []
    for plan in plans:
        for r in fly_plan(plan, seed, events):
            results.append((r, plan.spec))
            metrics.write(metrics_row(r, plan.spec.version))
            if on_result is not None:
                on_result(plan, r)
    return results


class Tagged:
    """Adds the drill and airframe to every supervisor event."""

    def __init__(self, sink, drill: str, airframe: str):
        self.sink, self.drill, self.airframe = sink, drill, airframe

    def write(self, record: dict) -> None:
        self.sink.write({"drill": self.drill, "airframe": self.airframe, **record})
