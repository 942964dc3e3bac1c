"""Run-folder I/O: atomic whole-file writes, append-and-flush streams (CSV, JSON lines, the
per-decision record), markdown tables, the run folder and its lifecycle, provenance for
config.json, the one address syntax and schema-checked configuration tables. The lowest layer:
every other layer may import it, it imports none of them."""

from skyherd.runio.address import (
    Address,
    AddressError,
    mavlink_address,
    parse_address,
    zenoh_endpoint,
)
from skyherd.runio.decisions import DecisionLog, read_decisions
from skyherd.runio.provenance import code_version, command_line, envelope_facts, file_facts
from skyherd.runio.run import Interrupted, Run, RunAborted, UsageError, open_run
from skyherd.runio.runfolder import (
    MISSING,
    CsvWriter,
    JsonlWriter,
    RunFolder,
    args_dict,
    atomic_write_bytes,
    atomic_write_text,
    is_missing,
    markdown_table,
    strict_json,
    to_jsonable,
    try_write_text,
    versions,
)
from skyherd.runio.schema import ConfigError, fill_dataclass, validate_mapping
from skyherd.runio.space import cut_records

__all__ = [
    "MISSING",
    "Address",
    "AddressError",
    "ConfigError",
    "CsvWriter",
    "DecisionLog",
    "Interrupted",
    "JsonlWriter",
    "Run",
    "RunAborted",
    "RunFolder",
    "UsageError",
    "args_dict",
    "atomic_write_bytes",
    "atomic_write_text",
    "code_version",
    "command_line",
    "envelope_facts",
    "file_facts",
    "fill_dataclass",
    "is_missing",
    "markdown_table",
    "mavlink_address",
    "open_run",
    "parse_address",
    "read_decisions",
    "strict_json",
    "to_jsonable",
    "try_write_text",
    "cut_records",
    "validate_mapping",
    "versions",
    "zenoh_endpoint",
]
