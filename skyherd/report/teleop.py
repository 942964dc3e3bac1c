"""`skyherd teleop`'s run folder at its end: the demonstration saved (skyherd-demo format,
policy.demos), config.json and summary.md saying what it holds (steps, episodes, the
all-in-view fraction of each)."""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING

from skyherd.runio import Run, file_facts, markdown_table

if TYPE_CHECKING:  # the learners' stack is imported when a demonstration is recorded
    from skyherd.policy.demos import Demonstration


def save_demo(run: Run, demo: Demonstration, out: Path, scenario: str, source: str) -> int:
    """Save the demonstration of `scenario` from `source` to `out`, say what it holds in
    summary.md and on standard output; nothing recorded = the run failed (1)."""
    if demo.actions.shape[0] == 0:
        print("nothing recorded (quit before the first step)")
        run.fail("nothing recorded (quit before the first step)")
        return 1
    demo.save(out)
    m = demo.meta["episode_metrics"]
    print(f"run folder: {run.path}")
    run.config(demo=file_facts(out), source=source)
    run.describe(out.name, f"the demonstration ({scenario}, {source}), skyherd-demo format")
    rows = [[i, x["all_in_view_frac"]] for i, x in enumerate(m)]
    run.summary(
        f"{demo.actions.shape[0]} steps of {scenario} from the {source} in {len(m)} "
        f"episode(s), saved to `{out}`.\n\n"
        + markdown_table(["episode", "all-in-view fraction"], rows)
    )
    print(f"\nrecorded {demo.actions.shape[0]} steps in {len(m)} episode(s) of {scenario} → {out}")
    print(f"all-in-view fraction per episode: {[round(x['all_in_view_frac'], 3) for x in m]}")
    return 0
