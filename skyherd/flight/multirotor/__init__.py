"""Multirotor autopilot: cascaded control, mixer, modes; `MultirotorAutopilot`.

The autopilot (and the numba quadrotor model under it) loads on first use, so that reading the
parameter table (flight.multirotor.params, e.g. from the companion) does not compile physics."""


def __getattr__(name: str):
    if name == "MultirotorAutopilot":
        from skyherd.flight.multirotor.autopilot import MultirotorAutopilot

        return MultirotorAutopilot
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


__all__ = ["MultirotorAutopilot"]
