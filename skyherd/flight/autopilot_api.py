"""What an onboard autopilot offers to its MAVLink endpoint, the safety net and the tools.

Airframe-neutral: the multirotor and the fixed-wing autopilots both implement `Autopilot`.
The MAVLink endpoint translates messages into these calls and never touches dynamics.
All positions NED about home [m], angles [rad], times simulation seconds.
"""

from __future__ import annotations

import enum
from dataclasses import dataclass, field
from typing import Protocol

import numpy as np

from skyherd.flight.clock import SimClock
from skyherd.flight.geo import Home
from skyherd.flight.state import VehicleState


class FlightMode(enum.Enum):
    """Flight modes, named the PX4 way. HOLD is hover (multirotor) or loiter (fixed-wing)."""

    MANUAL = "manual"
    STABILIZED = "stabilized"
    ALTCTL = "altctl"
    POSCTL = "posctl"
    HOLD = "hold"
    TAKEOFF = "takeoff"
    LAND = "land"
    RTL = "rtl"
    MISSION = "mission"
    OFFBOARD = "offboard"


class LandedState(enum.IntEnum):
    """MAV_LANDED_STATE values."""

    UNDEFINED = 0
    ON_GROUND = 1
    IN_AIR = 2
    TAKEOFF = 3
    LANDING = 4


class ModeSource(enum.Enum):
    """Who asks for a mode change. A user (a ground station, an RC pilot) may take the vehicle
    out of the autopilot's own failsafe, as PX4 lets a user take over; a companion (an onboard
    computer, MAV_COMP_ID_ONBOARD_COMPUTER*) may not while that failsafe is in force."""

    USER = "user"
    COMPANION = "companion"


@dataclass(frozen=True)
class Result:
    """Outcome of a request. `ok` False carries a reason a person can act on; `temporary`:
    refused for now (MAV_RESULT_TEMPORARILY_REJECTED), not for what was asked."""

    ok: bool
    reason: str = ""
    in_progress: bool = False
    temporary: bool = False

    @staticmethod
    def accepted() -> Result:
        return Result(True)

    @staticmethod
    def denied(reason: str) -> Result:
        return Result(False, reason)

    @staticmethod
    def rejected_for_now(reason: str) -> Result:
        return Result(False, reason, temporary=True)


@dataclass(frozen=True)
class Setpoint:
    """An offboard / guidance setpoint. None = that field is not commanded.

    pos_ned  (3,) [m]      target position, NED about home
    vel_ned  (3,) [m/s]    target velocity (feed-forward when pos_ned is given)
    yaw      [rad]         heading from north, clockwise
    yaw_rate [rad/s]
    """

    pos_ned: np.ndarray | None = None
    vel_ned: np.ndarray | None = None
    yaw: float | None = None
    yaw_rate: float | None = None

    def is_finite(self) -> bool:
        for v in (self.pos_ned, self.vel_ned):
            if v is not None and not np.all(np.isfinite(v)):
                return False
        for v in (self.yaw, self.yaw_rate):
            if v is not None and not np.isfinite(v):
                return False
        return True


class MissionCommand(enum.IntEnum):
    """The mission item commands the autopilots fly (MAV_CMD values)."""

    WAYPOINT = 16
    LOITER_UNLIM = 17
    LOITER_TIME = 19
    RETURN_TO_LAUNCH = 20
    LAND = 21
    TAKEOFF = 22


@dataclass(frozen=True)
class MissionItem:
    """A mission item in the vehicle's own terms.

    pos_ned: target (3,) [m]; hold_s: time to wait at it [s]; accept_radius: [m] (0 = default);
    yaw: heading at the item [rad] or None; loiter_radius: [m] for loiter items (fixed-wing).
    """

    command: MissionCommand
    pos_ned: np.ndarray
    hold_s: float = 0.0
    accept_radius: float = 0.0
    yaw: float | None = None
    loiter_radius: float = 0.0


@dataclass
class MissionProgress:
    """Mission state the endpoint reports (MISSION_CURRENT, MISSION_ITEM_REACHED)."""

    current: int = 0
    reached: list[int] = field(default_factory=list)  # seqs reached since last drained
    finished: bool = False


class Autopilot(Protocol):
    """An airframe with its onboard autopilot, stepping on the simulation clock."""

    airframe: str  # "quadrotor" | "fixedwing"
    clock: SimClock
    home: Home
    control_dt: float  # [s] period of one `step`

    @property
    def state(self) -> VehicleState: ...
    @property
    def armed(self) -> bool: ...
    @property
    def mode(self) -> FlightMode: ...
    @property
    def landed_state(self) -> LandedState: ...
    @property
    def battery_remaining(self) -> float: ...  # [0, 1]
    @property
    def mission_progress(self) -> MissionProgress: ...

    def step(self) -> None:
        """Advance the clock by `control_dt`: autopilot once, physics as many substeps as needed;
        read `state` (and `true_state`) after it."""
        ...

    def arm(self, force: bool = False) -> Result: ...
    def disarm(self, force: bool = False) -> Result: ...
    def set_mode(self, mode: FlightMode, source: ModeSource = ModeSource.USER) -> Result:
        """Switch modes; refused for now to a companion while the autopilot's own failsafe is
        in force (AutopilotBase.set_mode)."""
        ...

    def takeoff(self, altitude: float | None = None) -> Result: ...
    def land(self) -> Result: ...
    def return_to_launch(self) -> Result: ...
    def reposition(self, pos_ned: np.ndarray, yaw: float | None = None) -> Result: ...
    def set_offboard_setpoint(self, setpoint: Setpoint) -> Result:
        """Stream a setpoint; the time it arrived is the clock's. 0.5 s without one in OFFBOARD → HOLD."""
        ...

    def set_manual_control(self, x: float, y: float, z: float, r: float) -> Result:
        """MANUAL_CONTROL sticks normalised: x pitch/forward, y roll/right, z thrust [0, 1], r yaw."""
        ...

    def set_mission(self, items: list[MissionItem]) -> Result: ...
    def set_mission_current(self, seq: int) -> Result: ...
    def get_param(self, name: str) -> float | None: ...
    def set_param(self, name: str, value: float) -> Result: ...
    def param_names(self) -> list[str]: ...


def offboard_lost_text(gap_s: float, loss_t_s: float) -> str:
    """The offboard-loss failsafe's line (STATUSTEXT): how long no setpoint arrived [s]."""
    return f"offboard setpoints lost: none for {gap_s:.2f} s (COM_OF_LOSS_T {loss_t_s:g} s) -> hold"


class AutopilotBase:
    """The read-outs, parameter calls and mode-change rule every skyherd autopilot shares.

    A subclass keeps `_state` (VehicleState), `_armed`, `_mode` (FlightMode), `_progress`
    (MissionProgress), `_gps_fix`, `_pos_valid` and `params` (a flight.params store) up to date,
    switches modes in `_enter_mode`, and calls `_failsafe_action(why)` whenever one of its own
    failsafes (battery, position loss, geofence) switches the mode, and `_failsafe_action("")`
    when it arms.

    The failsafe rule (`set_mode`): while the autopilot's own failsafe action is in force (armed,
    and no user has changed the mode since), a companion's request for another mode is refused
    for now (MAV_RESULT_TEMPORARILY_REJECTED, the reason in STATUSTEXT), as PX4's failsafe state
    machine keeps its action against a request it does not take as the user's. A companion
    decides on telemetry that is at least its latency old: a request it decided just before the
    failsafe's heartbeat could reach it would otherwise arrive after the switch and undo it
    (docs/safety.md, Run 7 and Run 8). The loss of the companion's own setpoint stream (its HOLD)
    is not held: that failsafe clears when the stream comes back, as PX4's offboard loss does.
    """

    _failsafe_why = ""  # why the autopilot's own failsafe switched the mode; "" none in force

    @property
    def failsafe_in_force(self) -> str:
        """Why the autopilot's own failsafe action holds the vehicle now ("" if none)."""
        return self._failsafe_why if self._armed else ""

    def _failsafe_action(self, why: str) -> None:
        self._failsafe_why = why

    def set_mode(self, mode: FlightMode, source: ModeSource = ModeSource.USER) -> Result:
        if not isinstance(mode, FlightMode):
            return Result.denied(f"unknown mode {mode!r}")
        why = self.failsafe_in_force
        if why and source is ModeSource.COMPANION and mode is not self._mode:
            return Result.rejected_for_now(
                f"{mode.name} refused to the companion: failsafe in force ({why})"
            )
        before = self._mode
        res = self._enter_mode(mode)
        if res.ok and self._mode is not before:
            self._failsafe_why = ""  # a user took over from the failsafe
        return res

    def _enter_mode(self, mode: FlightMode) -> Result:
        raise NotImplementedError

    _state: VehicleState
    _armed: bool
    _mode: FlightMode
    _progress: MissionProgress
    _gps_fix: bool
    _pos_valid: bool

    @property
    def state(self) -> VehicleState:
        return self._state

    @property
    def gps_fix(self) -> bool:
        return self._gps_fix

    @property
    def position_valid(self) -> bool:
        """False once GPS has been lost for longer than the estimator's dead-reckoning limit."""
        return self._pos_valid

    @property
    def armed(self) -> bool:
        return self._armed

    @property
    def mode(self) -> FlightMode:
        return self._mode

    @property
    def mission_progress(self) -> MissionProgress:
        return self._progress

    def get_param(self, name: str) -> float | None:
        return self.params.get(name)

    def set_param(self, name: str, value: float) -> Result:
        return self.params.set(name, value)

    def param_names(self) -> list[str]:
        return self.params.names()
