"""The mission layer: what the UAV does, tick by tick, for 1..K vehicles (phases, pilots, the
companion's loop, the mapping of the safety net's decisions onto autopilot modes)."""
