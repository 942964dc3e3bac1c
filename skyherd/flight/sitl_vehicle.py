"""One simulated vehicle on its own (`skyherd sitl`): its MAVLink endpoints in the PX4 SITL
layout (CONVENTIONS.md; every number in runio/constants.py), the parameters an earlier run set
over MAVLink loaded again from the state folder, the links it announces, and what it did when
it stops (flight.sitl.Sitl steps it)."""

from __future__ import annotations

import json
import os
import signal
import sys
from pathlib import Path
from typing import TYPE_CHECKING

from skyherd.runio import markdown_table

if TYPE_CHECKING:  # `skyherd sitl --help` imports this module: no MAVLink stack for it
    from skyherd.flight.mavlink import EndpointConfig
    from skyherd.flight.sitl import RunStats, Sitl


def default_state_dir() -> Path:
    """Where parameters persist: $XDG_STATE_HOME/skyherd/sitl (or ~/.local/state/...)."""
    base = os.environ.get("XDG_STATE_HOME") or str(Path.home() / ".local" / "state")
    return Path(base) / "skyherd" / "sitl"


def saved_params(config: EndpointConfig, airframe: str) -> dict:
    """The parameter values a previous run saved in the state folder (set over MAVLink) that
    this run loads: {"file": path or None, "values": {name: value}} for config.json and the
    start-up line."""
    from skyherd.flight.mavlink.params import ParamFile

    path = config.param_file(airframe)
    values = ParamFile(path).load() if path is not None and path.exists() else {}
    return {"file": str(path) if path is not None else None, "values": values}


def saved_params_line(saved: dict) -> str | None:
    """The start-up line that says which saved parameters were loaded again (never silently);
    None when none were."""
    if not saved["values"]:
        return None
    names = ", ".join(f"{k}={v:g}" for k, v in list(saved["values"].items())[:6])
    more = len(saved["values"]) - 6
    n = len(saved["values"])
    return (f"skyherd sitl: {n} parameter{'s' if n != 1 else ''} saved in {saved['file']} "
            f"loaded again ({names}{f', +{more} more' if more > 0 else ''}); delete that file or "
            "give another --state-dir to start from the defaults")  # fmt: skip


def links_table(config: EndpointConfig) -> str:
    """The vehicle's two MAVLink links: where each is bound and where it sends."""
    rows = [
        ["api / offboard", f"udp {config.api_bind[0]}:{config.api_bind[1]}", f"{config.api_remote[0]}:{config.api_remote[1]}"],
        ["ground station", f"udp {config.gcs_bind[0]}:{config.gcs_bind[1]}", f"{config.gcs_remote[0]}:{config.gcs_remote[1]}"],
    ]  # fmt: skip
    return markdown_table(["link", "bound to", "sends to"], rows)


def run_until_stopped(sitl: Sitl, duration_s: float | None) -> RunStats:
    """Run until SIGTERM or SIGINT (even when a shell started the process in the background)
    end it cleanly, or until `duration_s` of simulation time; a bounded run shows its progress
    in simulated seconds on a terminal."""
    for sig in (signal.SIGTERM, signal.SIGINT):
        signal.signal(sig, lambda *_: sitl.request_stop())
    if duration_s is None:
        return sitl.run(duration_s=None, on_step=None)
    from tqdm import tqdm

    with tqdm(total=round(duration_s), unit="sim s", disable=not sys.stderr.isatty()) as bar:

        def progress(s: Sitl) -> None:
            if s.clock.t - bar.n >= 1.0:
                bar.update(int(s.clock.t - bar.n))

        return sitl.run(duration_s=duration_s, on_step=progress)


def run_summary(sitl: Sitl, stats: RunStats | None) -> str:
    """What the vehicle did, as a table: simulated time, steps, the endpoint's counts, the
    messages and commands received, the real-time factor."""
    ep = sitl.endpoint
    summary = {
        "sim_s": sitl.clock.t,
        "steps": sitl.steps,
        "stats": dict(ep.stats),
        "received": dict(ep.rx_types),
        "commands": {str(k): v for k, v in ep.rx_commands.items()},
    }
    if stats is not None:
        summary["real_time_factor"] = stats.real_time_factor
    return markdown_table(["quantity", "value"], [[k, json.dumps(v)] for k, v in summary.items()])
