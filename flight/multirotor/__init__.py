"""Multirotor autopilot: cascaded control, mixer, modes; `MultirotorAutopilot`."""

from flight.multirotor.autopilot import MultirotorAutopilot

__all__ = ["MultirotorAutopilot"]
