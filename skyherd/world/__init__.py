"""The simulated world of `skyherd sim`: one vehicle (built-in autopilot and physics), the UGV
team and the downward camera, stepped on one simulation clock; the lockstep barrier that keeps
the companion's decisions on that clock."""
