"""The companion's missions built from what the command line chose (`MissionChoice`): the
pilot, the safety net, the plan and the mission object `skyherd companion` flies
(`build_mission`), without argparse; ValueError with a one-line reason on bad input.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from skyherd.runio import JsonlWriter


@dataclass(frozen=True)
class MissionChoice:
    """What the companion flies (`skyherd companion`'s options, their help each field's comment
    or docstring: scripts.options; saved with its arguments)."""

    mission: str = "groundair"  # groundair | square | shepherd | orbit
    altitude_m: float | None = None
    """take-off altitude above home [m] (default: 20; `fly` frames the team)"""
    duration_s: float = 60.0  # flight behind the safety net [s]
    side_m: float = 40.0  # square side [m]
    envelope: str | None = None  # constraint-set TOML of the safety net
    pilot: str = "policy"
    """groundair pilot: policy (the learned one), pid (the classic follower on φ(s)), or
    drill:NAME, a named drill's adversarial AI flown by the same mission, e.g. drill:lateral-fence
    with --envelope safety/envelopes/quadrotor_field.toml"""
    policy: str | None = None
    """policy file: discrete (skyherd train ab / irl / educate) or the deep continuous ABS-DL
    policy (skyherd train abs-dl, e.g. policy/models/groundair_absdl.npz) (default: the discrete
    AB policy the repository keeps)"""
    lost_ugv_search: bool = False
    """groundair: when a UGV leaves the view, search for it (dead reckoning from its last
    sighting, climbing toward the ceiling, expanding square: mission/search.py) instead of
    leaving it to the pilot"""
    configure_autopilot: bool = False
    """before the take-off, set the autopilot's parameters the safety envelope requires (e.g.
    PX4 COM_OF_LOSS_T, ArduCopter GUID_TIMEOUT), read each back and record the change
    (companion.json, summary.md); nothing is restored afterwards. Default: refuse to take off on
    a mismatch, naming the parameter and the value to set"""
    shepherd_selector: str = "learned"
    """--mission shepherd: the high-level selector between collect and drive: learned
    (policy/shepherd/selector.json, fitted to Strömbom's demonstrations) or strombom (the
    hand-written rule)"""
    orbit_team: str = "lateral"
    """--mission orbit: the UGV team's scenario the companion is briefed with (its start, speed,
    spread)"""
    orbit_seed: int = 0  # --mission orbit: the team's seed (the briefing)
    orbit_no_land: bool = False  # --mission orbit: end in the orbit, no landing
    groundair_altitude_m: float = 20.0  # the ground-air and square missions' default [m]
    shepherd_altitude_m: float = 12.0  # --mission shepherd's default [m]: the flock feels the
    # UAV's horizontal position only; low enough for the camera to show the flock's part under it

    def checked(self) -> MissionChoice:
        """This choice, once its numbers are in range; ValueError (one line, naming the
        option) otherwise."""
        if not 0 < self.duration_s <= 36000:  # NaN fails too
            raise ValueError("--duration must be in (0, 36000] s")
        if self.altitude_m is not None and not 0 < self.altitude_m <= 120:
            raise ValueError(f"--altitude {self.altitude_m:g}: must be in (0, 120] m above home")
        if not 0 < self.side_m <= 500:
            raise ValueError(f"--side {self.side_m:g}: must be in (0, 500] m")
        return self


def mission_choice(options) -> MissionChoice:
    """The mission `options` chose (a namespace with `skyherd companion`'s option names); an
    option another command's parser lacks keeps its default."""
    d = MissionChoice()
    return MissionChoice(
        mission=options.mission, altitude_m=options.altitude, duration_s=options.duration,
        side_m=options.side, envelope=options.envelope, pilot=options.pilot, policy=options.policy,
        lost_ugv_search=getattr(options, "lost_ugv_search", d.lost_ugv_search),
        configure_autopilot=getattr(options, "configure_autopilot", d.configure_autopilot),
        shepherd_selector=getattr(options, "shepherd_selector", d.shepherd_selector),
        orbit_team=getattr(options, "orbit_team", d.orbit_team),
        orbit_seed=getattr(options, "orbit_seed", d.orbit_seed),
        orbit_no_land=getattr(options, "orbit_no_land", d.orbit_no_land),
    )  # fmt: skip


def _say_nothing(text: str) -> None:
    pass


def _record(run_dir: Path | None):
    """decisions.jsonl and metrics.csv (TRACK_COLUMNS) in `run_dir`, or no records."""
    from skyherd.mission.flight import TRACK_COLUMNS, Record
    from skyherd.runio import CsvWriter

    return Record(
        decisions=JsonlWriter(run_dir / "decisions.jsonl") if run_dir else None,
        track=CsvWriter(run_dir / "metrics.csv", TRACK_COLUMNS) if run_dir else None,
    )


def build_mission(c: MissionChoice, run_dir: Path | None, say=_say_nothing):
    """Policy, safety net, pilot and the mission generator's owner, and its plan (ValueError,
    one line, on bad input). With `run_dir`, the records go there; `say(line)` tells progress."""
    from skyherd.mission.flight import FlightPlan, SingleVehicleMission
    from skyherd.mission.perception import Perception
    from skyherd.mission.pilots import PerceptionFollower, PolicyPilot, WaypointPilot
    from skyherd.task.params import TaskParams

    task = TaskParams()
    altitude = c.groundair_altitude_m if c.altitude_m is None else c.altitude_m
    if c.mission == "orbit":
        return _orbit_mission(c, run_dir)
    if c.mission == "shepherd":
        return _shepherd_mission(c, run_dir)
    if c.mission == "square":
        if not (0 < altitude <= 120 and 0 < c.side_m <= 500):
            raise ValueError("--altitude must be in (0, 120] m and --side in (0, 500] m")
        s, z = c.side_m, -altitude
        wps = [np.array(w, dtype=float) for w in ([s, 0, z], [s, s, z], [0, s, z], [0, 0, z])]
        pilot, net, perception = WaypointPilot(wps), None, None
        plan = FlightPlan(altitude_m=altitude, duration_s=600.0)
    else:
        plan = FlightPlan(altitude_m=altitude, duration_s=c.duration_s, decision_s=task.dt_s)
        net = load_groundair_net(c.envelope, run_dir)
        if c.pilot == "policy":
            pilot = PolicyPilot(load_pilot_policy(c.policy), task)
        elif c.pilot == "pid":
            pilot = PerceptionFollower(task)
        else:  # a drill's adversarial AI, deciding every tick as the drills' AI does
            pilot = drill_pilot(c.pilot, net.spec)
            plan = FlightPlan(altitude_m=altitude, duration_s=c.duration_s, decision_s=0.1)
        perception = Perception(task)
        if c.lost_ugv_search and not c.pilot.startswith("drill:"):
            from skyherd.mission.search import SearchPilot
            from skyherd.policy.search.lost import LostSearch

            pilot = SearchPilot(pilot, perception, LostSearch(None, task), net.spec.limits,
                                net.spec.dynamics.tau_s)  # fmt: skip
    record = _record(run_dir)
    return SingleVehicleMission(pilot, net, plan, record, perception,
                                c.configure_autopilot, say), plan  # fmt: skip


def _shepherd_mission(c: MissionChoice, run_dir: Path | None):
    """The shepherd (mission/shepherd.py) behind the ground-air envelope's net; its flock reader
    is attached once the Zenoh session is open (`attach_flock`)."""
    from skyherd.mission.flight import FlightPlan, SingleVehicleMission
    from skyherd.mission.shepherd import ShepherdPilot
    from skyherd.policy.shepherd.rules import ShepherdParams
    from skyherd.policy.shepherd.selector import make_selector

    altitude = c.shepherd_altitude_m if c.altitude_m is None else c.altitude_m
    plan = FlightPlan(altitude_m=altitude, duration_s=c.duration_s,
                      decision_s=ShepherdParams().decision_s)  # fmt: skip
    net = load_groundair_net(c.envelope, run_dir)
    spec = net.spec
    pilot = ShepherdPilot(make_selector(c.shepherd_selector), lambda t: None, altitude, spec.limits,
                          spec.dynamics.tau_s)  # fmt: skip
    record = _record(run_dir)
    return SingleVehicleMission(pilot, net, plan, record, None), plan


def attach_flock(session, mission, key: bytes | None = None) -> object:
    """The shepherd reads the flock's reports (skyherd/ugv/<id>/state) on `session` (with the
    flight's key only authentic ones); returns the subscriber (closed with the session), kept
    as `mission.flock_sub` for companion.json."""
    from skyherd.groundsim.flock import FlockParams
    from skyherd.groundsim.transport import UGVStateSubscriber
    from skyherd.mission.shepherd import flock_reader

    sub = mission.flock_sub = UGVStateSubscriber(session, key=key)
    mission.pilot.flock = flock_reader(sub, FlockParams().n)
    return sub


INPUT_FAULT_DRILLS = ("camera loss", "link loss")
"""Named drills whose fault is an input, not the AI's action: in a flight those are the
simulator's --cut-camera / --cut-link, not a pilot."""


def drill_pilot(choice: str, spec):
    """The adversarial pilot of `--pilot drill:NAME` for the flight's envelope (ValueError
    naming the drills there are)."""
    from skyherd.mission.pilots import DrillPilot
    from skyherd.safety.drills import DrillParams, scripted_drills

    p = DrillParams()
    name = choice.split(":", 1)[1].replace("-", " ").strip()
    scripts = {s.name: s for s in scripted_drills(spec, p) if s.name not in INPUT_FAULT_DRILLS}
    if name not in scripts:
        names = ", ".join("drill:" + n.replace(" ", "-") for n in scripts)
        raise ValueError(f"--pilot {choice}: no such drill for {spec.name}; use one of {names}")
    return DrillPilot(scripts[name], p, p.duration(spec.airframe), name=f"drill:{name}")


def _orbit_mission(c: MissionChoice, run_dir: Path | None):
    """The fixed-wing orbit (mission/orbit.py) behind the fixed-wing envelope's net."""
    from skyherd.mission.orbit import OrbitFlight, OrbitMission, briefing_for
    from skyherd.mission.orbit_plan import fence_reserve
    from skyherd.safety.config import ENVELOPE_DIR, EnvelopeFileError
    from skyherd.safety.net import SafetyNet, warm_up

    events = JsonlWriter(run_dir / "events.jsonl") if run_dir else None
    try:
        flight = OrbitFlight(duration_s=c.duration_s, land=not c.orbit_no_land)
        net = SafetyNet.load(
            "fixedwing", c.envelope or ENVELOPE_DIR / "fixedwing_field.toml", events=events
        )
    except (EnvelopeFileError, ValueError) as e:
        raise ValueError(f"{e}; fix the envelope file or the duration") from None
    warm_up(net.envelope, net.p)
    lim = net.envelope.spec.limits
    brief = briefing_for(c.orbit_team, c.orbit_seed, flight.duration_s, flight.establish_s)
    record = _record(run_dir)
    alt_band = (lim.floor_m + lim.margin_m, lim.ceiling_m - lim.margin_m - 15.0)
    mission = OrbitMission(net, flight, brief, record, fence_reserve(net.envelope.spec), alt_band)
    return mission, flight


def load_pilot_policy(path: str | None):
    """The ground-air policy file (the kept one without `path`), checked against the task's
    observation and actions (ValueError, one line)."""
    from skyherd.policy.dqn import PolicyFileError, load_policy
    from skyherd.policy.models import DEFAULT_POLICY
    from skyherd.task.observation import OBS_DIM
    from skyherd.task.params import N_ACTIONS

    try:
        policy = load_policy(path or DEFAULT_POLICY)
    except PolicyFileError as e:
        raise ValueError(f"{e}; train one with `skyherd train ab` or pass --policy") from None
    if getattr(policy, "continuous", False):  # a deep velocity policy (skyherd train abs-dl)
        shape = (getattr(policy, "obs_dim", None), getattr(policy, "act_dim", None))
        if shape != (OBS_DIM, 3):
            raise ValueError(f"{path}: the deep policy takes {shape[0]} inputs and gives {shape[1]} "
                             f"velocity components; the ground-air task has {OBS_DIM} inputs and a "
                             "3-component NED velocity: pass a policy from `skyherd train abs-dl`")  # fmt: skip
        return policy
    shape = (getattr(policy, "obs_dim", None), getattr(policy, "n_actions", None))
    if shape != (OBS_DIM, N_ACTIONS):
        raise ValueError(f"{path or DEFAULT_POLICY}: the policy takes {shape[0]} inputs and gives "
                         f"{shape[1]} actions; the ground-air task has {OBS_DIM} inputs and {N_ACTIONS} "
                         "actions: pass a policy trained for it (`skyherd train ab`) or drop --policy")  # fmt: skip
    return policy


def load_groundair_net(envelope: str | None, run_dir: Path | None):
    """The ground-air mission's SafetyNet (the camera is one of its inputs), warmed up."""
    from skyherd.safety.config import ENVELOPE_DIR, EnvelopeFileError
    from skyherd.safety.net import SafetyNet, warm_up

    path = envelope or ENVELOPE_DIR / "quadrotor_groundair.toml"
    events = JsonlWriter(run_dir / "events.jsonl") if run_dir else None
    try:
        net = SafetyNet.load("quadrotor", path, events=events, camera=True)
    except (EnvelopeFileError, ValueError) as e:
        raise ValueError(f"{e}; fix the file or pass another --envelope") from None
    warm_up(net.envelope, net.p)  # now, not at the first switch in flight
    return net
