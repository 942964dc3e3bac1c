"""Why a flight ended, in words: the supervisor's reason (runio.launch) or the companion's own
(companion.json). No heavy import: `skyherd fly` reads COMPANION_EXITED on its way to the launch."""

from __future__ import annotations

COMPANION_EXITED = "the companion exited with code"  # how supervise() begins that reason


def flight_reason(companion_reason: str | None, why: str) -> str:
    """Why the flight ended: the supervisor's reason when it stopped the companion (the time
    limit, a simulator that died), else the companion's own (it ended the flight)."""
    if why and not why.startswith(COMPANION_EXITED):
        return why
    return companion_reason or why
