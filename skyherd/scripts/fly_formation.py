"""The formation mission of `skyherd fly`: K quadrotors fly the learned SQL-SIE plan.

`skyherd fly --mission formation --agents K` takes the lock-step grid plan (trained in-process
with a fixed seed, a few seconds, or read from `--policy-file`, a `plan_K<K>.json` written by
`skyherd train sql`), maps the 50×50 grid onto the field (cell (x, y) → north (y−1)·cell,
east (x−1)·cell about the field origin), and starts K+1 programs: one `skyherd sim --ugvs none`
per vehicle (instance N+k, its home on its start cell) and one `skyherd companion --mission
formation` flying all K in lockstep (mission/formation.py), every setpoint behind its vehicle's
safety net. The run folder gets plan.json, decisions.jsonl and events.jsonl (every vehicle),
metrics.csv (every position sample, field frame), uav<k>/ (each vehicle's tlog, world.csv,
sim_stats.json, sim.log), formation.png and summary.md with landing errors, separations, times.
"""

from __future__ import annotations

import argparse
import os

from skyherd.flight.geo import DEFAULT_HOME
from skyherd.mission.formation_plan import (
    FormationParams,
    PlanError,
    load_plan,
    plan_text,
    validate_plan,
    vehicle_homes,
    vehicle_instances,
)
from skyherd.report.formation import formation_report
from skyherd.runio import ports
from skyherd.runio.constants import GCS_REMOTE_PORT
from skyherd.runio.runfolder import args_dict, atomic_write_text
from skyherd.scripts.cli import UsageError
from skyherd.scripts.fly_options import AGENT_CHOICES, add_formation_arguments  # noqa: F401 - the options live there
from skyherd.world.fleet import FleetVehicle, write_fleet


def _params(args) -> FormationParams:
    try:
        return FormationParams(cell_m=args.cell_m)
    except ValueError as e:
        raise UsageError(f"{e}; pick --cell-m in [1, 20]") from None


def _check(args) -> None:
    if getattr(args, "connect", None) is not None:
        raise UsageError("--mission formation flies the built-in vehicles only; drop --connect")
    if not (args.speedup == 0 or args.speedup >= 1):
        raise UsageError("--speedup must be 0 (as fast as possible) or >= 1")
    if args.sql_seed < 0:
        raise UsageError("--sql-seed must be >= 0")
    if not 0 <= args.sims <= args.agents:
        raise UsageError(
            f"--sims {args.sims}: give 1..{args.agents} processes (or 0: one per CPU core)"
        )
    if not 0 <= args.instance <= ports.MAX_INSTANCE - args.agents + 1:
        raise UsageError(
            f"--instance {args.instance} + {args.agents} vehicles goes past instance "
            f"{ports.MAX_INSTANCE}; pick a smaller --instance"
        )


def obtain_plan(args) -> tuple[list[list[tuple[int, int]]], dict]:
    """The lock-step plan (--policy-file, or learned: policy.sql.learn_plan) and where it came
    from (for config.json). UsageError if unusable."""
    from skyherd.policy.sql import GridParams, PlanParams, learn_plan
    from skyherd.policy.sql.layout import STARTS

    K = args.agents
    size = GridParams().size
    if args.policy_file:
        try:
            plan = load_plan(args.policy_file, K, size)
        except PlanError as e:
            raise UsageError(f"{e}; pass a plan_K{K}.json from `skyherd train sql`") from None
        return plan, {"source": "file", "path": str(args.policy_file)}
    if K not in STARTS:
        raise UsageError(f"the study's SQL-SIE plans are for K = {', '.join(map(str, STARTS))}: "
                         f"for K = {K} pass --policy-file")  # fmt: skip
    from tqdm import tqdm

    params = PlanParams(GridParams(n_agents=K), seed=args.sql_seed)
    try:
        with tqdm(total=params.hyper.episodes, desc=f"train SQL-SIE K={K}", unit="ep") as bar:
            paths = learn_plan(params, bar.update)
        plan = validate_plan(paths, K, size)
    except ValueError as e:
        raise UsageError(f"{e}; try another --sql-seed or pass --policy-file") from None
    return plan, params.describe()


def run_formation(args: argparse.Namespace) -> int:
    """Fly the formation as K simulators + one companion; 0 if every vehicle landed on its target."""
    from skyherd.scripts import launch
    from skyherd.scripts.fly_options import check_signing, per_run_key, signing_mode

    _check(args)
    _check_children(args)
    key = check_signing(args)
    params = _params(args)
    K = args.agents
    plan, plan_info = obtain_plan(args)
    instances = vehicle_instances(args.instance, K)
    _ports_free(instances)
    homes = vehicle_homes(DEFAULT_HOME, [p[0] for p in plan], params.cell_m)
    from skyherd.scripts import waysout

    folder = waysout.open_run_folder("fly", args.runs_dir)  # UsageError: not writable, full
    run_dir = folder.path
    key = key or per_run_key(args, run_dir)  # one key for every vehicle's two links
    signing = ["--signing-key", str(key)] if key is not None else []
    folder.write_config(
        {"args": args_dict(args), "mission": "formation", "formation": params,
         "plan": plan_info, "field_origin": DEFAULT_HOME, "homes": homes, "instances": instances,
         "frame": "field NED about field_origin; cell (x, y) centre at north (y-1)*cell_m, "
                  "east (x-1)*cell_m",
         "signing": signing_mode(args)}
    )  # fmt: skip
    atomic_write_text(run_dir / "plan.json", plan_text(plan))
    waysout.write_running(run_dir)
    print(f"skyherd fly: run folder {run_dir}", flush=True)
    skipped = (
        f" (10 skipped: its companion port is the ground stations' {GCS_REMOTE_PORT})"
        if 10 in range(instances[0], instances[-1])
        else ""
    )
    print(f"skyherd fly: {K} vehicles (instances {instances[0]}..{instances[-1]}{skipped}), plan of "
          f"{len(plan[0]) - 1} steps, speed-up {args.speedup:g}, lockstep", flush=True)  # fmt: skip
    groups = sim_groups(K, args.sims)
    print(f"skyherd fly: {len(groups)} simulator process{'es' if len(groups) > 1 else ''} "
          f"({', '.join(str(len(g)) for g in groups)} vehicles), logs sim<g>.log", flush=True)  # fmt: skip
    why = "interrupted (Ctrl-C)"
    kids = launch.Launch()
    try:
        with kids:  # stopped on every way out, the companion first
            for g, group in enumerate(groups):
                fleet = [FleetVehicle(f"uav{k}", instances[k], args.seed + k,
                                      (homes[k].lat_deg, homes[k].lon_deg, homes[k].alt_m)) for k in group]  # fmt: skip
                fleet_file = run_dir / f"sim{g}.json"
                write_fleet(fleet_file, fleet)
                kids.start_sim(f"sim{g}", launch.skyherd_cmd(
                    "sim", "--fleet", str(fleet_file), "--ugvs", "none", "--speedup", repr(args.speedup),
                    "--latency", repr(args.latency), "--run-dir", str(run_dir), *signing), run_dir / f"sim{g}.log")  # fmt: skip
            kids.start_companion(launch.skyherd_cmd(
                "companion", "--mission", "formation", "--plan", str(run_dir / "plan.json"), "--cell-m",
                repr(params.cell_m), "--instance", str(args.instance), "--run-dir", str(run_dir),
                *signing))  # fmt: skip
            rc, why = kids.supervise(args.timeout)
    except KeyboardInterrupt as e:  # SIGINT, SIGTERM, SIGHUP (scripts.launch): 128 + signum
        rc, why = waysout.interrupted(e)
    ok = waysout.report_safely(formation_report, run_dir, rc, why, why=why)  # never raises
    output = [ln for c in kids.sims for ln in (c.lines or ())]  # kept in memory
    waysout.append_ending(
        run_dir, waysout.ending_lines(run_dir, [f"uav{k}" for k in range(K)], output)
    )
    return 0 if ok and rc == 0 else (rc if rc > 128 else 1)


def _check_children(args) -> None:
    """The children's own checks on the options passed on to them (scripts.sim and
    scripts.companion `check_args`; the fleet and plan files are made later): UsageError."""
    from skyherd.scripts import companion, sim

    why = sim.check_args(["--ugvs", "none", "--speedup", repr(args.speedup), "--latency",
                          repr(args.latency), "--instance", str(args.instance)])  # fmt: skip
    why = why or companion.check_args(["--mission", "formation", "--plan", "plan.json",
                                       "--cell-m", repr(args.cell_m), "--instance", str(args.instance)])  # fmt: skip
    if why:
        raise UsageError(why)


def sim_groups(K: int, sims: int) -> list[list[int]]:
    """Vehicles 0..K-1 shared among `sims` processes (0: one per CPU core, at most K), in
    contiguous groups whose sizes differ by at most one."""
    n = sims if sims > 0 else max(1, min(K, os.cpu_count() or 1))
    base, extra = divmod(K, n)
    groups, k = [], 0
    for g in range(n):
        size = base + (1 if g < extra else 0)
        groups.append(list(range(k, k + size)))
        k += size
    return groups


def _ports_free(instances: list[int]) -> None:
    """UsageError before anything starts if a vehicle's or the companion's UDP port is taken."""
    taken = ports.taken_udp_port(instances)
    if taken is not None:
        inst, port, why = taken
        raise UsageError(f"UDP port {port} of instance {inst} is taken ({why}); "
                         "pick another --instance")  # fmt: skip
