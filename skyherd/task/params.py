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

from skyherd.perception.camera import CameraParams

ACTION_NAMES: tuple[str, ...] = ("hover", "north", "south", "east", "west", "climb", "descend")
N_ACTIONS = len(ACTION_NAMES)
LATERAL_ACTIONS = (0, 1, 2, 3, 4)
CLIMB_ACTIONS = (0, 5)
DESCEND_ACTIONS = (0, 6)
ALL_ACTIONS = tuple(range(N_ACTIONS))


def autopilot_velocity_limits() -> dict[str, float]:
    """The quadrotor autopilot's velocity limits [m/s]: xy, up, down (flight.multirotor.params)."""
    from skyherd.flight.multirotor.params import MULTIROTOR_PARAMS

    d = {p.name: p.default for p in MULTIROTOR_PARAMS}
    return {"xy": d["MPC_XY_VEL_MAX"], "up": d["MPC_Z_VEL_MAX_UP"], "down": d["MPC_Z_VEL_MAX_DN"]}


@dataclass(frozen=True)
class UAVParams:
    """First-order point model of the quadrotor under offboard velocity control.

    The commanded speeds must lie inside the quadrotor autopilot's limits, read from its one
    source (flight.multirotor.params: MPC_XY_VEL_MAX 12 m/s, MPC_Z_VEL_MAX_UP 3 m/s,
    MPC_Z_VEL_MAX_DN 1.5 m/s); construction fails otherwise. The velocity follows the command
    with time constant `tau_s`: v(t+dt) = v_cmd + (v − v_cmd)·exp(−dt/τ), integrated exactly.
    τ = 0.6 s (both axes, the training default) is slower than skyherd's SITL quadrotor: its
    measured 63 % rise times to offboard velocity steps are 0.46 s lateral (4 m/s) and 0.23 s
    vertical (docs/learning.md); SITL_MEASURED gives those values for robustness tests.
    """

    v_xy_mps: float = 4.0  # lateral speed command [m/s]
    v_up_mps: float = 2.0  # climb speed command [m/s]
    v_down_mps: float = 1.5  # descent speed command [m/s]
    tau_s: float = 0.6  # lateral velocity response time constant [s]
    tau_z_s: float = 0.6  # vertical velocity response time constant [s]
    alt_min_m: float = 5.0  # altitude floor (geofence) [m]
    alt_max_m: float = 60.0  # altitude ceiling (geofence) [m]

    def __post_init__(self) -> None:
        lim = autopilot_velocity_limits()
        if not (
            0 < self.v_xy_mps <= lim["xy"]
            and 0 < self.v_up_mps <= lim["up"]
            and 0 < self.v_down_mps <= lim["down"]
        ):
            raise ValueError(f"UAV speed commands must be > 0 and within the autopilot's {lim}")
        if not (self.tau_s > 0 and self.tau_z_s > 0 and 0 < self.alt_min_m < self.alt_max_m):
            raise ValueError("need tau_s, tau_z_s > 0 and 0 < alt_min_m < alt_max_m")


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


# 63 % rise times of skyherd's SITL quadrotor (flight.multirotor) to offboard velocity steps
# from hover at 20 m: 4 m/s north 0.46 s, 2 m/s climb 0.23 s, 1.5 m/s descent 0.22 s.
SITL_MEASURED = UAVParams(tau_s=0.46, tau_z_s=0.23)
