"""skyherd: one UAV keeps a group of UGVs in its camera's view, flown by a policy learned from
demonstrations, behind a runtime safety net.

The packages are the layers of docs/architecture.md, imported as `skyherd.<package>`:
runio (0); flight, groundsim, perception, policy, safety (1); hil, record (2); world
(`skyherd sim`), mission (`skyherd companion`) (3); scripts, the command line (4).
Importing `skyherd` imports none of them.
"""


def __getattr__(name: str):
    """`skyherd.__version__`, looked up when asked (PEP 562): importing `skyherd` stays free of
    importlib.metadata (email, datetime, ...), so `python -m skyherd.scripts.cli` reaches the
    line that keeps an early Ctrl-C sooner (scripts/cli.py; a SIGINT in that import was a
    child's KeyboardInterrupt traceback, tests/e2e/test_fly_waysout.py)."""
    if name != "__version__":
        raise AttributeError(f"module 'skyherd' has no attribute {name!r}")
    from importlib import metadata

    try:
        return metadata.version("skyherd")
    except metadata.PackageNotFoundError:  # a source tree that was never installed
        return "0+unknown"
