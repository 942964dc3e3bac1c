"""What `skyherd sim` simulates, as one frozen record (`WorldParams`, saved in config.json), apart
from the world that runs it (world.sim, which re-exports it): `skyherd fly`'s checks of the
simulator's arguments (world.setup.SimSetup.world_params) build it without the simulator's stack
(the scene, the renderer, the endpoint).
"""

from __future__ import annotations

from dataclasses import dataclass, field

from skyherd.flight.lockstep import LockstepParams
from skyherd.runio.constants import CAMERA_HZ, PACE_S


@dataclass(frozen=True)
class WorldParams:
    """What `skyherd sim` simulates (saved in config.json)."""

    airframe: str = "quadrotor"
    instance: int = 0  # MAVLink vehicle instance N (ports, system id 1+N)
    seed: int = 0  # one seed for the vehicle, the UGV team and every other random source
    scenario: str = "composite"  # UGV team: a training scenario, groundsim:<behaviour>, "none"
    home: tuple[float, float, float] | None = (
        None  # lat [deg], lon [deg], alt AMSL [m]; None: default
    )
    vehicle: str = "uav0"  # Zenoh key prefix
    camera_hz: float = CAMERA_HZ  # camera frames per simulated second (the companion's tick)
    ugv_start: str = "offboard"  # "offboard" | "0" | seconds: when the team starts to drive
    lockstep: bool = True  # hold the simulation for the companion's decisions
    lockstep_params: LockstepParams = field(default_factory=LockstepParams)
    speedup: float = 10.0  # simulation seconds per wall second; 0 = as fast as possible
    pace_s: float = PACE_S  # the pacer sleeps once per this much simulation time [s]
    gimbal: bool = True  # roll/pitch-stabilised camera (the policy was trained with one)
    camera: str = "down"  # "down": the quadrotor's downward camera; "roi": a zoomed camera on a
    # pan-tilt gimbal pointed at the region of interest a client sets (DO_SET_ROI_LOCATION)
    link_cuts: tuple[
        tuple[float, float], ...
    ] = ()  # (start, duration) [s]: the API link cut both ways
    camera_losses: tuple[
        tuple[float, float], ...
    ] = ()  # (start, duration) [s]: no frames published
    alone_s: float = 30.0  # the companion gone: simulate the autopilot alone at most this long [s]

    def __post_init__(self) -> None:
        if not self.camera_hz > 0:
            raise ValueError(f"camera_hz must be > 0, got {self.camera_hz}")
        if self.lockstep and self.lockstep_params.latency_s >= 1.0 / self.camera_hz:
            raise ValueError(
                f"the companion's latency {self.lockstep_params.latency_s} s must be shorter "
                f"than the camera period {1.0 / self.camera_hz} s"
            )
        if not self.alone_s >= 0.0:
            raise ValueError(f"alone_s must be >= 0, got {self.alone_s}")
        if self.camera not in ("down", "roi"):
            raise ValueError(f"camera must be 'down' or 'roi', not {self.camera!r}")
        if self.ugv_start != "offboard":
            try:
                ok = float(self.ugv_start) >= 0
            except ValueError:
                ok = False
            if not ok:
                raise ValueError(
                    f"ugv_start must be 'offboard' or seconds >= 0, not {self.ugv_start!r}"
                )
