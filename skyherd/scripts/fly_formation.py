"""The formation mission of `skyherd fly --mission formation --agents K`: the learned SQL-SIE
plan (or `--policy-file`, a `plan_K<K>.json` of `skyherd train sql`) on the field
(mission/formation_plan.py), flown by K+1 programs: `skyherd sim --ugvs none` processes sharing
the vehicles (instance N+k, its home on its start cell) and one `skyherd companion --mission
formation` flying all K in lockstep (mission/formation.py). The run folder gets plan.json,
decisions.jsonl, events.jsonl, metrics.csv (field frame), uav<k>/ and the report
(report/formation.py: formation.png, summary.md with landing errors, separations, times).
"""

from __future__ import annotations

import argparse

from skyherd.flight.geo import DEFAULT_HOME
from skyherd.mission.formation_plan import (
    FormationParams,
    obtain_plan,
    plan_text,
    vehicle_homes,
    vehicle_instances,
)
from skyherd.report.formation import formation_report
from skyherd.runio import ports
from skyherd.runio.constants import GCS_REMOTE_PORT
from skyherd.runio.run import Interrupted
from skyherd.runio.runfolder import args_dict, atomic_write_text
from skyherd.runio.signals import KeptSignals
from skyherd.scripts.cli import UsageError, usage
from skyherd.world.fleet import FleetVehicle, sim_groups, write_fleet


def _params(args) -> FormationParams:
    try:
        return FormationParams(cell_m=args.cell_m)
    except ValueError as e:
        raise UsageError(f"{e}; pick --cell-m in [1, 20]") from None


def _check(args) -> None:
    if getattr(args, "connect", None) is not None:
        raise UsageError("--mission formation flies the built-in vehicles only; drop --connect")
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


def run_formation(args: argparse.Namespace, kept: KeptSignals) -> int:
    """Fly the formation as K simulators + one companion; 0 if every vehicle landed on its
    target. `kept`: fly's KeptSignals (keeping); the plan (seconds to minutes when it is
    learned) is the one part a signal stops at once."""
    from tqdm import tqdm

    from skyherd.runio import launch
    from skyherd.scripts.cli import skyherd_cmd
    from skyherd.scripts.fly import after_report, nothing_recorded
    from skyherd.scripts.fly_options import flight_signing

    _check(args)
    _check_children(args)
    key = usage(flight_signing(args).checked_key_file)  # None: a per-run key, or unsigned
    params = _params(args)
    K = args.agents
    try:
        kept.raising()  # one kept so far raises now
        plan, plan_info = usage(obtain_plan, args.policy_file, K, args.sql_seed, tqdm)
    except Interrupted as e:
        return nothing_recorded(e.signum)
    finally:
        kept.keeping()
    instances = vehicle_instances(args.instance, K)
    usage(ports.check_ports_free, instances)  # before anything starts
    homes = vehicle_homes(DEFAULT_HOME, [p[0] for p in plan], params.cell_m)
    from skyherd.report import ending
    from skyherd.runio import signals
    from skyherd.runio.run import open_run_folder

    if kept.signum is not None:  # nothing made, nothing started
        return nothing_recorded(kept.signum)
    folder = open_run_folder("fly", args.runs_dir)  # UsageError: not writable, full
    run_dir = folder.path
    key = key or flight_signing(args).per_run_key(run_dir)  # one key for every vehicle's two links
    signing = ["--signing-key", str(key)] if key is not None else []
    folder.write_config(
        {"args": args_dict(args), "mission": "formation", "formation": params,
         "plan": plan_info, "field_origin": DEFAULT_HOME, "homes": homes, "instances": instances,
         "frame": "field NED about field_origin; cell (x, y) centre at north (y-1)*cell_m, "
                  "east (x-1)*cell_m",
         "signing": flight_signing(args).mode()}
    )  # fmt: skip
    atomic_write_text(run_dir / "plan.json", plan_text(plan))
    ending.write_running(run_dir)
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
    kids = launch.Launch(kept)
    try:
        with kids:  # stopped on every way out, the companion first
            for g, group in enumerate(groups):
                fleet = [FleetVehicle(f"uav{k}", instances[k], args.seed + k,
                                      (homes[k].lat_deg, homes[k].lon_deg, homes[k].alt_m)) for k in group]  # fmt: skip
                fleet_file = run_dir / f"sim{g}.json"
                write_fleet(fleet_file, fleet)
                kids.start_sim(f"sim{g}", skyherd_cmd(
                    "sim", "--fleet", str(fleet_file), "--ugvs", "none", "--speedup", repr(args.speedup),
                    "--latency", repr(args.latency), "--run-dir", str(run_dir), *signing), run_dir / f"sim{g}.log")  # fmt: skip
            kids.start_companion(skyherd_cmd(
                "companion", "--mission", "formation", "--plan", str(run_dir / "plan.json"), "--cell-m",
                repr(params.cell_m), "--instance", str(args.instance), "--run-dir", str(run_dir),
                *signing))  # fmt: skip
            rc, why = kids.supervise(args.timeout)
    except KeyboardInterrupt as e:  # SIGINT, SIGTERM, SIGHUP (runio.launch): 128 + signum
        rc, why = signals.interrupted(e)
    vehicles = [f"uav{k}" for k in range(K)]
    ok = ending.end_run(
        run_dir, formation_report, rc, why, why=why, sims=kids.sims, vehicles=vehicles
    )
    return after_report(ok, rc, kept)


def _check_children(args) -> None:
    """The children's own checks on the options passed on to them (fly_options.check_child;
    the fleet and plan files are made later): UsageError."""
    from skyherd.scripts.fly_options import check_child

    check_child("sim", ["--ugvs", "none", "--speedup", repr(args.speedup), "--latency",
                        repr(args.latency), "--instance", str(args.instance)])  # fmt: skip
    check_child("companion", ["--mission", "formation", "--plan", "plan.json", "--cell-m",
                              repr(args.cell_m), "--instance", str(args.instance)])  # fmt: skip
