"""Parameters of the GroundAir task: the UAV point model, the action set, episode limits.

The action set (Discrete(7)), velocity commands in NED [m/s]:

====  ==========  ==========================================
a     name        commanded velocity (north, east, down)
====  ==========  ==========================================
0     hover       (0, 0, 0)
1     north       (+v_xy, 0, 0)
2     south       (−v_xy, 0, 0)
3     east        (0, +v_xy, 0)
4     west        (0, −v_xy, 0)
5     climb       (0, 0, −v_up)
6     descend     (0, 0, +v_down)
====  ==========  ==========================================

In flight the same index maps to the same offboard velocity setpoint (see `action_velocity_ned`).
"""

from __future__ import annotations

from dataclasses import dataclass, field

from perception.camera import CameraParams

ACTION_NAMES: tuple[str, ...] = ("hover", "north", "south", "east", "west", "climb", "descend")
N_ACTIONS = len(ACTION_NAMES)
LATERAL_ACTIONS = (0, 1, 2, 3, 4)
CLIMB_ACTIONS = (0, 5)
DESCEND_ACTIONS = (0, 6)
ALL_ACTIONS = tuple(range(N_ACTIONS))


@dataclass(frozen=True)
class UAVParams:
    """First-order point model of the quadrotor under offboard velocity control.

    Velocity limits are those of the quadrotor's autopilot velocity loop (PX4 defaults are
    MPC_XY_VEL_MAX 12 m/s, MPC_Z_VEL_MAX_UP 3 m/s, MPC_Z_VEL_MAX_DN 1.5 m/s; skyherd commands at
    most these cruise values, well inside them). The velocity follows the command with time
    constant `tau_s`: v(t+dt) = v_cmd + (v − v_cmd)·exp(−dt/τ), integrated exactly.
    """

    v_xy_mps: float = 4.0  # lateral speed command [m/s]
    v_up_mps: float = 2.0  # climb speed command [m/s]
    v_down_mps: float = 1.5  # descent speed command [m/s]
    tau_s: float = 0.6  # velocity response time constant [s]
    alt_min_m: float = 5.0  # altitude floor (geofence) [m]
    alt_max_m: float = 60.0  # altitude ceiling (geofence) [m]


@dataclass(frozen=True)
class TaskParams:
    """Episode and measurement settings of skyherd/GroundAir-v0."""

    dt_s: float = 0.5  # decision period (one env step) [s]
    episode_s: float = 60.0  # time limit → truncation [s]
    lost_s: float = 2.0  # no UGV in view for this long → all lost → termination [s]
    n_ugvs: int = 3  # UGVs in the team
    uav: UAVParams = field(default_factory=UAVParams)
    camera: CameraParams = field(default_factory=CameraParams)
    spread_target: float = 0.35  # the scripted expert's preferred φ spread (radius / half-diag)

    @property
    def max_steps(self) -> int:
        return int(round(self.episode_s / self.dt_s))


def action_velocity_ned(a: int, uav: UAVParams = UAVParams()) -> tuple[float, float, float]:
    """Commanded velocity (north, east, down) [m/s] of action index a."""
    v, up, dn = uav.v_xy_mps, uav.v_up_mps, uav.v_down_mps
    table = (
        (0.0, 0.0, 0.0),
        (v, 0.0, 0.0),
        (-v, 0.0, 0.0),
        (0.0, v, 0.0),
        (0.0, -v, 0.0),
        (0.0, 0.0, -up),
        (0.0, 0.0, dn),
    )
    if not 0 <= int(a) < N_ACTIONS:
        raise ValueError(f"action must be in 0..{N_ACTIONS - 1}, got {a}")
    return table[int(a)]
