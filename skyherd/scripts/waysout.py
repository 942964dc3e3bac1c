"""The names `fly`, `sim` and `launch` take from here; every way out of `skyherd fly` lives in
report.ending (its summary), runio.run.open_run_folder and runio.signals."""

from skyherd.report.ending import (  # noqa: F401  # noqa: F401
    append_ending,
    ending_lines,
    parent_died,
    recording_cut,
    report_safely,
    write_running,
)
from skyherd.runio.run import open_run_folder  # noqa: F401
from skyherd.runio.signals import INTERRUPTS, KeptSignals, interrupted  # noqa: F401
