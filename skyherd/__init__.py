"""skyherd: one UAV keeps a group of UGVs in its camera's view, flown by a policy learned from
demonstrations, behind a runtime safety net.

The packages are the layers of docs/architecture.md, imported as `skyherd.<package>`:
runio (0); flight, groundsim, perception, policy, safety (1); hil, record (2); world
(`skyherd sim`), mission (`skyherd companion`) (3); scripts, the command line (4).
Importing `skyherd` imports none of them.
"""

from importlib import metadata as _metadata

try:
    __version__ = _metadata.version("skyherd")
except _metadata.PackageNotFoundError:  # a source tree that was never installed
    __version__ = "0+unknown"
