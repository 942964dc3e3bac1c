"""Run-folder I/O: atomic whole-file writes, append-and-flush streams (CSV, JSON lines),
markdown tables, and the run folder itself. The lowest layer: every other layer may import
it, it imports none of them."""

from runio.runfolder import (
    CsvWriter,
    JsonlWriter,
    RunFolder,
    args_dict,
    atomic_write_bytes,
    atomic_write_text,
    markdown_table,
    to_jsonable,
    versions,
)

__all__ = [
    "CsvWriter",
    "JsonlWriter",
    "RunFolder",
    "args_dict",
    "atomic_write_bytes",
    "atomic_write_text",
    "markdown_table",
    "to_jsonable",
    "versions",
]
