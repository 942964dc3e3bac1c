"""The fixed-wing autopilot: TECS for height and airspeed, L1 for the track, PID attitude.

`FixedWingAutopilot` implements `flight.autopilot_api.Autopilot` over a JSBSim aircraft
(`jsbsim_model.JSBSimPlane`). Modes are PX4's: HOLD is a loiter circle at the present
altitude, RTL returns and loiters over home (and lands if RTL_LAND_DELAY ≥ 0), LAND flies
a descending circle to the approach gate, a straight final on a glide slope, a flare and a
braked roll-out; TAKEOFF is a runway take-off along the present heading.

Frames: NED about home, FRD body; angles [rad] except parameters PX4 keeps in degrees
(converted where read). Positions in the horizontal plane are (north, east) [m].

Faults (flight/faults.py): the plan's wind (mean + gusts + wind events) is set on JSBSim's
atmosphere each control step; GPS faults shift the estimate the guidance flies on (`state`,
what telemetry reports); `true_state` is JSBSim's. GPS lost for longer than EKF2_NOAID_TOUT:
the aircraft loiters where it believes it is (HOLD on dead reckoning).
Geofence (flight/geofence.py): loiter circles (reposition, offboard positions, loiter items)
must lie inside, as must waypoints; a breach takes GF_ACTION (2: loiter on a circle centred
1.5 loiter radii toward home from the breach point; 3: RTL; 4/5: land).
"""

from __future__ import annotations

import enum
import math
from collections.abc import Mapping
from dataclasses import dataclass

import numpy as np

from skyherd.flight.autopilot_api import (
    AutopilotBase,
    FlightMode,
    LandedState,
    MissionCommand,
    MissionItem,
    MissionProgress,
    Result,
    Setpoint,
    offboard_lost_text,
)
from skyherd.flight.clock import SimClock
from skyherd.flight.faults import FaultInjector, FaultPlan, apply_switches
from skyherd.flight.fixedwing import guidance
from skyherd.flight.fixedwing.attitude import AttitudeController, InnerGains
from skyherd.flight.fixedwing.fw_params import FW_PARAM_SPECS
from skyherd.flight.fixedwing.jsbsim_model import JSBSimPlane, ModelParams, Surfaces
from skyherd.flight.fixedwing.tecs import Tecs, TecsGains
from skyherd.flight.frames import wrap_pi
from skyherd.flight.geo import GRAVITY, Home
from skyherd.flight.geofence import ACTION_HOLD, ACTION_NAMES, ACTION_NONE, ACTION_RTL, FenceMonitor
from skyherd.flight.params import ParamStore
from skyherd.flight.state import VehicleState


class Phase(enum.Enum):
    """Sub-state of the autopilot (what the guidance flies right now)."""

    IDLE = "idle"  # on the ground
    TAKEOFF_ROLL = "takeoff_roll"
    TAKEOFF_CLIMB = "takeoff_climb"
    LOITER = "loiter"
    TRACK = "track"  # straight line a → b
    COURSE = "course"  # offboard velocity: course and climb rate
    LAND_DESCEND = "land_descend"
    LAND_FINAL = "land_final"
    FLARE = "flare"
    ROLLOUT = "rollout"
    LANDED = "landed"
    DIRECT = "direct"  # manual / stabilized sticks


@dataclass(frozen=True)
class Runway:
    """A landing or take-off line: touchdown (or start) point (2,) [m] and direction [rad]."""

    point: np.ndarray
    heading: float

    @property
    def dir(self) -> np.ndarray:
        return np.array([math.cos(self.heading), math.sin(self.heading)])


HOLD_FIT_SLACK = 0.1
"""A HOLD circle must fit inside the geofence with this share of its radius to spare."""

LANDING_PHASES = (Phase.LAND_DESCEND, Phase.LAND_FINAL, Phase.FLARE, Phase.ROLLOUT, Phase.LANDED)


def right_of(d: np.ndarray) -> np.ndarray:
    """Unit vector 90° clockwise of (north, east) direction `d`."""
    return np.array([-d[1], d[0]])


class FixedWingAutopilot(AutopilotBase):
    """J3Cub on JSBSim with its own autopilot. See the module docstring."""

    airframe = "fixedwing"

    def __init__(
        self,
        clock: SimClock | None = None,
        home: Home | None = None,
        params: Mapping[str, float] | None = None,
        *,
        gains: InnerGains | None = None,
        tecs_gains: TecsGains | None = None,
        model_params: ModelParams | None = None,
        control_dt: float = 0.02,
        instance: int = 0,
        seed: int = 0,
        faults: FaultPlan | None = None,
        rng: np.random.Generator | None = None,
    ):
        self.clock = clock if clock is not None else SimClock()
        self.home = home if home is not None else Home()
        self.params = ParamStore(FW_PARAM_SPECS, params)
        self._pcache: dict[str, float] = {}
        self._pcache_rev = -1
        self.att = AttitudeController(gains)
        self.gains = self.att.g
        self.tecs = Tecs(tecs_gains)
        self.control_dt = control_dt
        self.instance = instance
        self.seed = seed  # only the fault plan draws random numbers (rng seeded from seed)
        self.faults = faults if faults is not None and not faults.empty else None
        self._inj = None
        if self.faults is not None:
            self._inj = FaultInjector(
                self.faults, rng if rng is not None else np.random.default_rng(seed)
            )
        self.fence = FenceMonitor()
        self._status: list[str] = []
        self._battery_drop = 0.0  # [0, 1] charge lost to battery faults (flight.faults)
        self._next_battery_check = 0.0
        self._gps_fix = True
        self._pos_valid = True
        self.model = JSBSimPlane(self.home, model_params or ModelParams())
        self._dt_us = round(control_dt * 1e6)
        if abs(self._dt_us / 1e6 - control_dt) > 1e-9:
            raise ValueError(f"control_dt {control_dt} s is not a whole number of microseconds")
        self._armed = False
        self._mode = FlightMode.HOLD
        self._mode_before_rtl = FlightMode.HOLD  # the rtl fault's way back (flight.faults)
        self._phase = Phase.IDLE
        self._progress = MissionProgress()
        self._mission: list[MissionItem] = []
        self._offboard: Setpoint | None = None
        self._offboard_t = -math.inf  # arrival of the last accepted setpoint [s, sim clock]
        self._refused_why: str | None = None  # the last refusal said (STATUSTEXT once)
        self._sticks = (0.0, 0.0, 0.0, 0.0)
        self._landed_t: float | None = None
        self._reset_loops()
        self._nav_init()
        self._state = self._true_state = self._stamp(self.model.state())

    # ---- construction helpers ----------------------------------------------------------
    def _reset_loops(self, el_trim: float = 0.0, thr_trim: float = 0.5) -> None:
        self.att.reset(el_trim)
        self.tecs.reset(thr_trim, 0.0)

    def _nav_init(self) -> None:
        self._center = np.zeros(2)
        self._radius = 100.0
        self._loiter_dir = 1
        self._a = np.zeros(2)
        self._b = np.zeros(2)
        self._h_dem = 0.0
        self._v_dem = self.p("FW_AIRSPD_TRIM")
        self._course = 0.0
        self._climb = 0.0
        self._runway: Runway | None = None
        self._after_takeoff: str = "hold"
        self._rtl_loiter_t: float | None = None
        self._loiter_until: float | None = None
        self._reported = -1

    def start_in_air(self, altitude: float, airspeed: float, heading: float = 0.0) -> Surfaces:
        """Put the aircraft trimmed in level flight over home, armed, in HOLD. Returns trim.

        In a fault plan's mean wind the aircraft starts trimmed in the air mass (`airspeed`
        through the air, not over the ground): the wind is there before the start, the gusts
        grow from 0 per their Gauss-Markov model, and the start injects no wind step."""
        mean = None if self.faults is None else self.faults.wind.mean_ned
        trim = self.model.reset_airborne(altitude, airspeed, heading, mean)
        self._failsafe_action("")
        self._armed = True
        self._reset_loops(trim.elevator, trim.throttle)
        self._state = self._true_state = self._stamp(self.model.state())
        self._enter_hold()
        self._v_dem = airspeed
        return trim

    def _stamp(self, s: VehicleState) -> VehicleState:
        """The model's state on the shared clock's time."""
        return VehicleState(
            self.clock.t, s.pos_ned, s.vel_ned, s.quat, s.omega_frd, s.accel_frd, s.on_ground
        )

    @property
    def true_state(self) -> VehicleState:
        """JSBSim's state (ground truth); `state` is the estimate the autopilot flies on."""
        return self._true_state

    def drain_status(self) -> list[str]:
        """Human-readable events since the last call (breaches, failsafes, fence uploads)."""
        if not self._status:
            return []  # the common step: nothing happened
        out, self._status = self._status, []
        return out

    def _event(self, text: str) -> None:
        self._status.append(f"{self.clock.t:.3f} {text}")

    # ---- geofence ----------------------------------------------------------------------
    def set_fence(self, shapes) -> None:
        """The fence uploaded over MAVLink (FenceShape list; [] clears): enforced from now."""
        self.fence.configure(
            list(shapes or ()), self.p("GF_MAX_HOR_DIST"), self.p("GF_MAX_VER_DIST")
        )
        n = len(self.fence.fence.areas)
        self._event(f"geofence: {n} area(s)" if n else "geofence: no areas")

    def _fence_sync(self) -> None:
        f = self.fence.fence
        if (f.max_hor, f.max_ver) != (self.p("GF_MAX_HOR_DIST"), self.p("GF_MAX_VER_DIST")):
            self.fence.configure(None, self.p("GF_MAX_HOR_DIST"), self.p("GF_MAX_VER_DIST"))

    def fence_violation(self, pos_ned, radius: float = 0.0) -> str | None:
        """Why a point (or a loiter circle of `radius` about it) is outside the fence, or None."""
        self._fence_sync()
        f = self.fence.fence
        if not f.active:
            return None
        p = np.asarray(pos_ned, dtype=float)
        return f.circle_violation(p[:2], radius, float(p[2]))

    def _refusal(self, pos_ned, radius: float = 0.0) -> str | None:
        if not self._pos_valid:
            return "no position estimate"
        why = self.fence_violation(pos_ned, radius)
        return None if why is None else f"target outside geofence: {why}"

    def _mission_refusal(self, items) -> str | None:
        for i, it in enumerate(items):
            if it.command in (MissionCommand.RETURN_TO_LAUNCH, MissionCommand.TAKEOFF):
                continue
            r = 0.0
            if it.command in (MissionCommand.LOITER_UNLIM, MissionCommand.LOITER_TIME):
                r = it.loiter_radius if it.loiter_radius > 0 else self.default_loiter_radius()
            p = np.asarray(it.pos_ned, dtype=float)
            if it.command == MissionCommand.LAND:
                p = np.array([p[0], p[1], -1.0])
            why = self.fence_violation(p, r)
            if why is not None:
                return f"item {i} outside geofence: {why}"
        return None

    def _fence_check(self) -> None:
        """One breach sample (20 Hz) on the estimate; GF_ACTION when a breach completes."""
        self._fence_sync()
        if not self.fence.fence.active or not self._flying() or not self.fence.due(self.clock.t):
            return
        why = self.fence.sample(self._state.pos_ned, int(self.p("GF_COUNT")))
        if why is None:
            return
        act = int(self.p("GF_ACTION"))
        self._event(f"geofence breach: {why} -> {ACTION_NAMES.get(act, act)}")
        if act <= ACTION_NONE + 1 or self._mode == FlightMode.LAND:
            return
        if act == ACTION_HOLD:
            pos = self._state.pos_ned[:2]
            r = self.default_loiter_radius()
            d = -pos / max(float(np.hypot(*pos)), 1e-6)  # toward home
            self._mode = FlightMode.HOLD
            # centred 1.5 r toward home: the circle's far side is 0.5 r back inside
            self._set_loiter(pos + 1.5 * r * d, r, 1, max(self._state.altitude, 15.0))
            self._event("mode -> hold (geofence)")
        elif act == ACTION_RTL:
            if self._mode != FlightMode.RTL:
                self._mode = FlightMode.RTL
                self._begin_rtl()
                self._event("mode -> rtl (geofence)")
        else:
            self.land()
            self._event("mode -> land (geofence)")
        self._failsafe_action(f"geofence breach: {why}")

    def _apply_faults(self) -> None:
        """Wind on JSBSim and the estimate's GPS error for the step that starts now."""
        inj, t, dt = self._inj, self.clock.t, self.control_dt
        if not inj.calm:
            self.model.set_wind(inj.wind_ned(t, dt))
        if inj._battery_events:
            drop, _watts = inj.battery(t)  # a drain's watts: the piston engine has no battery
            if drop is not None and drop < self.battery_remaining:
                self._battery_drop += self.battery_remaining - drop
                self._event(f"battery fault: charge {drop:.0%}")
        if inj._switch_events:
            apply_switches(self, inj.switches(t))
        if not inj.touches_estimate:
            return
        e = inj.update(t, dt)
        if e.fix != self._gps_fix:
            self._gps_fix = e.fix
            self._event("gps fix regained" if e.fix else "gps fix lost: dead reckoning")
            if e.fix:
                self._pos_valid = True
        if not e.fix and self._pos_valid and e.lost_s > self.p("EKF2_NOAID_TOUT"):
            self._pos_valid = False
            self._event(f"no position for {e.lost_s:.1f} s: failsafe -> hold (dead reckoning)")
            if self._flying() and self._mode not in (FlightMode.HOLD, FlightMode.LAND):
                self._mode = FlightMode.HOLD
                self._enter_hold()
                self._failsafe_action("position lost: hold")

    def _estimate(self, s: VehicleState) -> VehicleState:
        if self._inj is None or not self._inj.touches_estimate:
            return s
        e = self._inj.err
        return VehicleState(
            s.t, s.pos_ned + e.pos, s.vel_ned + e.vel, s.quat, s.omega_frd, s.accel_frd, s.on_ground
        )

    def p(self, name: str) -> float:
        """Present value of a parameter (a dict snapshot, refreshed when the store changes)."""
        if self._pcache_rev != self.params.revision:
            self._pcache, self._pcache_rev = self.params.as_dict(), self.params.revision
        return self._pcache[name]

    # ---- Autopilot protocol: read-outs ----------------------------------------------------

    @property
    def phase(self) -> Phase:
        return self._phase

    @property
    def airspeed(self) -> float:
        """True airspeed [m/s]."""
        return self.model.airspeed

    @property
    def loiter_center(self) -> np.ndarray:
        return self._center.copy()

    @property
    def loiter_radius(self) -> float:
        return self._radius

    @property
    def landed_state(self) -> LandedState:
        ph = self._phase
        if ph in (Phase.IDLE, Phase.LANDED) or (not self._armed and self._state.on_ground):
            return LandedState.ON_GROUND
        if ph in (Phase.TAKEOFF_ROLL, Phase.TAKEOFF_CLIMB):
            return LandedState.TAKEOFF
        if ph in (Phase.LAND_DESCEND, Phase.LAND_FINAL, Phase.FLARE, Phase.ROLLOUT):
            return LandedState.LANDING
        return LandedState.IN_AIR

    @property
    def battery_remaining(self) -> float:
        """The J3Cub's fuel fraction, less what battery faults took (the failsafes' charge)."""
        return max(0.0, self.model.fuel_fraction - self._battery_drop)

    def _battery_failsafe(self) -> None:
        """PX4 COM_LOW_BAT_ACT 3 (as the multirotor): critical → return, emergency → land."""
        if not self._flying():
            return
        rem, mode = self.battery_remaining, self._mode
        if rem <= self.p("BAT_EMERGEN_THR") and mode != FlightMode.LAND:
            self._event(f"battery {rem:.0%}: emergency -> land")
            self.land()
            self._failsafe_action(f"battery {rem:.0%}: emergency land")
        elif rem <= self.p("BAT_CRIT_THR") and mode not in (FlightMode.RTL, FlightMode.LAND):
            self._event(f"battery {rem:.0%}: critical -> return")
            self.return_to_launch()
            self._failsafe_action(f"battery {rem:.0%}: critical return")

    def default_loiter_radius(self) -> float:
        """NAV_LOITER_RAD, or V_trim^2 / (g tan(0.7 φ_max)) when it is 0 [m]."""
        r = self.p("NAV_LOITER_RAD")
        if r <= 0.0:
            v = self.p("FW_AIRSPD_TRIM")
            r = v * v / (GRAVITY * math.tan(0.7 * math.radians(self.p("FW_R_LIM"))))
        return max(r, self._min_loiter_radius())

    # ---- Autopilot protocol: commands ---------------------------------------------------
    def arm(self, force: bool = False) -> Result:
        if self._armed:
            return Result.accepted()
        if not self._state.on_ground and not force:
            return Result.denied("in the air: arm only on the ground (or force)")
        if not (self._gps_fix and self._pos_valid):
            return Result.denied("no position estimate (GPS): arming refused")
        if not (math.isfinite(self.home.lat_deg) and math.isfinite(self.home.lon_deg)):
            return Result.denied("no home position: arming refused")
        why = self.fence_violation(self._state.pos_ned)
        if why is not None and not force:
            return Result.denied(f"outside geofence ({why}): arming refused")
        self._failsafe_action("")
        self._armed = True
        self.model.set_engine(True)
        self._landed_t = None
        return Result.accepted()

    def disarm(self, force: bool = False) -> Result:
        if not self._armed:
            return Result.accepted()
        if not self._state.on_ground and not force:
            return Result.denied("flying: land first (or force)")
        if self._state.on_ground and self.model.airspeed > 3.0 and not force:
            return Result.denied("still rolling: wait until stopped (or force)")
        self._armed = False
        self.model.set_engine(False)
        if self._state.on_ground:
            self._phase = Phase.IDLE
        return Result.accepted()

    def _enter_mode(self, mode: FlightMode) -> Result:
        if mode == FlightMode.HOLD:
            if self._mode == FlightMode.HOLD and self._phase == Phase.LOITER:
                return Result.accepted()  # already holding: keep the same circle
            if self._flying():
                self._enter_hold()
            else:
                self._abort_takeoff_roll()
            self._mode = FlightMode.HOLD
            return Result.accepted()
        if mode == FlightMode.TAKEOFF:
            return self.takeoff()
        if mode == FlightMode.LAND:
            return self.land()
        if mode == FlightMode.RTL:
            return self.return_to_launch()
        if mode == FlightMode.MISSION:
            if not self._mission:
                return Result.denied("no mission uploaded")
            if not self._flying() and not self._armed:
                return Result.denied("arm first")
            why = self._mission_refusal(self._mission)
            if why is not None:
                return Result.denied(why)
            self._mode = FlightMode.MISSION
            self._progress.finished = False
            self._start_item(min(self._progress.current, len(self._mission) - 1))
            return Result.accepted()
        if mode == FlightMode.OFFBOARD:
            if self._offboard is None or self.clock.t - self._offboard_t > self.p("COM_OF_LOSS_T"):
                return Result.denied("stream offboard setpoints first")
            if not self._flying():
                return Result.denied("offboard needs a flying aircraft: take off first")
            self._mode = FlightMode.OFFBOARD
            self._h_dem = self._state.altitude
            self._apply_offboard()
            return Result.accepted()
        if mode in (FlightMode.MANUAL, FlightMode.STABILIZED, FlightMode.ALTCTL, FlightMode.POSCTL):
            self._mode = mode
            self._h_dem = self._state.altitude
            self._course = self._course_now()
            if self._phase not in (Phase.IDLE, Phase.LANDED):
                self._phase = Phase.DIRECT
            return Result.accepted()
        return Result.denied(f"mode {mode.name} not supported")

    def takeoff(self, altitude: float | None = None) -> Result:
        alt = self.p("MIS_TAKEOFF_ALT") if altitude is None else float(altitude)
        if not (math.isfinite(alt) and 5.0 <= alt <= 1000.0):
            return Result.denied(f"take-off altitude must be 5..1000 m, got {altitude}")
        why = self.fence_violation(np.array([*self._state.pos_ned[:2], -alt]))
        if why is not None and "height" in why:
            return Result.denied(f"take-off: target outside geofence: {why}")
        if self._phase in (Phase.TAKEOFF_ROLL, Phase.TAKEOFF_CLIMB):
            self._h_dem = alt
            return Result.accepted()  # already taking off
        if self._flying():
            self._enter_hold(alt)
            self._mode = FlightMode.HOLD
            return Result.accepted()
        if not self._armed:
            return Result.denied("arm first")
        self._mode = FlightMode.TAKEOFF
        self._begin_takeoff(alt, then="hold")
        return Result.accepted()

    def land(self) -> Result:
        if not self._flying():
            if self._state.on_ground:
                self._mode = FlightMode.LAND
                self._abort_takeoff_roll()
                return Result.accepted()
            return Result.denied("not flying")
        if self._mode == FlightMode.LAND and self._phase in LANDING_PHASES:
            return Result.accepted()  # already landing: a repeated command changes nothing
        self._mode = FlightMode.LAND
        self._begin_landing(self._landing_runway())
        return Result.accepted()

    def return_to_launch(self) -> Result:
        if not self._flying():
            return Result.denied("not flying")
        if self._mode == FlightMode.RTL:
            return Result.accepted()  # already returning
        self._mode = FlightMode.RTL
        self._begin_rtl()
        return Result.accepted()

    def reposition(self, pos_ned: np.ndarray, yaw: float | None = None) -> Result:
        pos = np.asarray(pos_ned, dtype=float)
        if pos.shape != (3,) or not np.all(np.isfinite(pos)):
            return Result.denied("reposition needs 3 finite NED coordinates [m]")
        if not self._flying():
            return Result.denied("not flying")
        alt = -pos[2] if pos[2] < -5.0 else self._state.altitude
        why = self._refusal(np.array([pos[0], pos[1], -alt]), self.default_loiter_radius())
        if why is not None:
            return Result.denied(why)
        self._mode = FlightMode.HOLD
        self._set_loiter(pos[:2], self.default_loiter_radius(), 1, alt)
        return Result.accepted()

    def set_offboard_setpoint(self, setpoint: Setpoint) -> Result:
        if not setpoint.is_finite():
            return Result.denied("setpoint has NaN or infinite fields")
        if setpoint.pos_ned is None and setpoint.vel_ned is None:
            return Result.denied("a fixed-wing needs a position or a velocity setpoint")
        if setpoint.pos_ned is not None:
            why = self._refusal(setpoint.pos_ned, self.default_loiter_radius())
            if why is not None:  # the last accepted setpoint stays; the stream ages
                if why != self._refused_why:  # said once per reason: setpoints have no answer
                    self._event(f"offboard setpoint refused: {why}")
                    self._refused_why = why
                return Result.denied(why)
        self._refused_why = None
        self._offboard = setpoint
        self._offboard_t = self.clock.t
        if self._mode == FlightMode.OFFBOARD:
            self._apply_offboard()
        return Result.accepted()

    def set_manual_control(self, x: float, y: float, z: float, r: float) -> Result:
        vals = (x, y, z, r)
        if not all(math.isfinite(v) for v in vals):
            return Result.denied("manual control has NaN values")
        self._sticks = (
            max(-1.0, min(1.0, x)),
            max(-1.0, min(1.0, y)),
            max(0.0, min(1.0, z)),
            max(-1.0, min(1.0, r)),
        )
        return Result.accepted()

    def set_mission(self, items: list[MissionItem]) -> Result:
        for i, it in enumerate(items):
            if not isinstance(it.command, MissionCommand):
                return Result.denied(f"item {i}: unsupported command {it.command}")
            p = np.asarray(it.pos_ned, dtype=float)
            if p.shape != (3,) or not np.all(np.isfinite(p)):
                return Result.denied(f"item {i}: position must be 3 finite numbers")
        why = self._mission_refusal(items)
        if why is not None:
            return Result.denied(why)
        self._mission = list(items)
        self._progress = MissionProgress()
        if self._mode == FlightMode.MISSION and self._flying():
            if self._mission:  # a new upload mid-mission restarts from its first item
                self._start_item(0)
            else:
                self._mode = FlightMode.HOLD
                self._enter_hold()
        return Result.accepted()

    def set_mission_current(self, seq: int) -> Result:
        if not (0 <= seq < max(1, len(self._mission))):
            return Result.denied(f"mission item {seq} does not exist")
        self._progress.current = seq
        self._progress.finished = False
        if self._mode == FlightMode.MISSION and self._mission:
            self._start_item(seq)
        return Result.accepted()

    # ---- guidance set-up ----------------------------------------------------------------
    def _flying(self) -> bool:
        return (
            self._armed
            and not self._state.on_ground
            and self._phase
            not in (
                Phase.IDLE,
                Phase.LANDED,
                Phase.TAKEOFF_ROLL,
                Phase.ROLLOUT,
            )
        )

    def _abort_takeoff_roll(self) -> None:
        """On the runway at take-off power: idle, brakes and steering, as after a landing."""
        if self._phase == Phase.TAKEOFF_ROLL:
            self._phase = Phase.ROLLOUT

    def _course_now(self) -> float:
        v = self._state.vel_ned
        if math.hypot(v[0], v[1]) < 3.0:
            return self._state.euler[2]
        return math.atan2(v[1], v[0])

    def _set_loiter(self, center: np.ndarray, radius: float, direction: int, alt: float) -> None:
        self._phase = Phase.LOITER
        self._center = np.asarray(center, dtype=float)[:2].copy()
        self._radius = float(radius)
        self._loiter_dir = 1 if direction >= 0 else -1
        self._h_dem = float(alt)
        self._v_dem = self.p("FW_AIRSPD_TRIM")

    def _enter_hold(self, alt: float | None = None) -> None:
        """Loiter on a circle that passes through the present position, tangent to the course,
        at the present altitude; with a geofence, the first circle that fits inside it
        (`hold_circle`)."""
        h = max(self._state.altitude if alt is None else alt, 15.0)
        c, r, direction = self.hold_circle(self._state.pos_ned[:2], self._course_now(), -h)
        self._set_loiter(c, r, direction, h)

    def hold_circle(self, pos_ne, course: float, down: float) -> tuple[np.ndarray, float, int]:
        """HOLD's circle through `pos_ne` tangent to `course` [rad]: (centre (2,), radius [m],
        direction +1 clockwise / −1). Default: NAV_LOITER_RAD on the right (clockwise). With a
        geofence the circle must fit inside it with HOLD_FIT_SLACK of its radius to spare (the
        L1 capture's overshoot): the right side, then the left, each at NAV_LOITER_RAD and then
        shrinking by 15 % a try down to the tightest turn the bank limit flies; none fitting
        (already at or past the fence): the default."""
        r0 = self.default_loiter_radius()
        pos = np.asarray(pos_ne, dtype=float)[:2]
        d = np.array([math.cos(course), math.sin(course)])
        right = right_of(d)
        if self.fence_violation(np.array([pos[0], pos[1], down])) is not None:
            return pos + r0 * right, r0, 1  # outside already: the breach action decides
        if self.fence.fence.active:
            r_min = self._min_loiter_radius()
            r = r0
            while True:
                for side in (1, -1):
                    c = pos + side * r * right
                    if self.fence_violation(np.array([*c, down]), r * (1 + HOLD_FIT_SLACK)) is None:
                        if (side, r) != (1, r0):
                            self._event(f"hold: loiter r {r:.0f} m {'right' if side > 0 else 'left'}"
                                        f" of the course fits the geofence")  # fmt: skip
                        return c, r, side
                if r <= r_min:
                    break
                r = max(r_min, 0.85 * r)
            self._event(f"hold: no loiter circle fits the geofence; r {r0:.0f} m on the right")
        return pos + r0 * right, r0, 1

    def _min_loiter_radius(self) -> float:
        """The tightest circle HOLD flies: V_trim² / (g tan FW_R_LIM) with 10 % in hand [m]."""
        v = self.p("FW_AIRSPD_TRIM")
        return v * v / (GRAVITY * math.tan(math.radians(self.p("FW_R_LIM")))) * 1.1

    def _set_track(self, a: np.ndarray, b: np.ndarray, alt: float) -> None:
        self._phase = Phase.TRACK
        self._a = np.asarray(a, dtype=float)[:2].copy()
        self._b = np.asarray(b, dtype=float)[:2].copy()
        self._h_dem = float(alt)
        self._v_dem = self.p("FW_AIRSPD_TRIM")

    def _begin_takeoff(self, alt: float, then: str) -> None:
        psi = self._state.euler[2]
        self._runway = Runway(self._state.pos_ned[:2].copy(), psi)
        self._h_dem = alt
        self._after_takeoff = then
        self._phase = Phase.TAKEOFF_ROLL
        self._reset_loops(0.0, 1.0)

    def _landing_runway(self) -> Runway:
        """Home's runway when near home, else a touchdown point ahead on the present course."""
        pos = self._state.pos_ned[:2]
        if float(np.hypot(*pos)) < 1500.0:
            return Runway(np.zeros(2), self.home.heading_rad)
        c = self._course_now()
        d = np.array([math.cos(c), math.sin(c)])
        dist = self._final_length() + 2.0 * self.default_loiter_radius()
        return Runway(pos + d * dist, c)

    def _final_length(self) -> float:
        return self.p("FW_LND_APP_ALT") / math.tan(math.radians(self.p("FW_LND_ANG")))

    def _begin_landing(self, rw: Runway) -> None:
        self._runway = rw
        gate = rw.point - rw.dir * self._final_length()
        r = self.default_loiter_radius()
        # Clockwise circle tangent to the final at the gate: the aircraft passes the gate aligned.
        # Circle down at the trim airspeed (full bank authority); slow to FW_LND_AIRSPD on final.
        self._set_loiter(gate + r * right_of(rw.dir), r, 1, self.p("FW_LND_APP_ALT"))
        self._phase = Phase.LAND_DESCEND

    def _begin_rtl(self) -> None:
        alt = max(self.p("RTL_RETURN_ALT"), self._state.altitude)
        ceiling = self.p("GF_MAX_VER_DIST")
        if ceiling > 0.0:  # as PX4: the return never climbs through GF_MAX_VER_DIST
            alt = max(min(alt, ceiling - 5.0), min(15.0, ceiling))
        self._rtl_loiter_t = None
        pos = self._state.pos_ned[:2]
        if float(np.hypot(*pos)) < 1.5 * self.default_loiter_radius():
            self._set_loiter(np.zeros(2), self.default_loiter_radius(), 1, alt)
        else:
            self._set_track(pos, np.zeros(2), alt)

    # ---- missions -------------------------------------------------------------------------
    def _start_item(self, seq: int) -> None:
        self._progress.current = seq
        it = self._mission[seq]
        pos = self._state.pos_ned[:2]
        alt = -float(it.pos_ned[2])
        self._loiter_until = None
        if it.command == MissionCommand.TAKEOFF:
            if self._state.on_ground or self._phase in (Phase.IDLE, Phase.LANDED):
                self._begin_takeoff(max(alt, 10.0), then="mission")
            else:
                self._item_reached()
            return
        if self._phase in (Phase.IDLE, Phase.LANDED, Phase.TAKEOFF_ROLL):
            # On the ground with a mission that has no take-off item: take off first.
            self._begin_takeoff(max(alt, self.p("MIS_TAKEOFF_ALT")), then="mission_item")
            return
        prev = self._a if seq == 0 else np.asarray(self._mission[seq - 1].pos_ned)[:2]
        if seq == 0 or self._mission[seq - 1].command == MissionCommand.TAKEOFF:
            prev = pos
        if it.command == MissionCommand.WAYPOINT:
            self._set_track(prev, it.pos_ned[:2], alt)
        elif it.command in (MissionCommand.LOITER_UNLIM, MissionCommand.LOITER_TIME):
            r = it.loiter_radius if it.loiter_radius > 0 else self.default_loiter_radius()
            self._set_loiter(it.pos_ned[:2], max(r, self.default_loiter_radius() * 0.5), 1, alt)
        elif it.command == MissionCommand.RETURN_TO_LAUNCH:
            self._item_reached()
            self._mode = FlightMode.RTL
            self._progress.finished = True
            self._begin_rtl()
        elif it.command == MissionCommand.LAND:
            b = np.asarray(it.pos_ned, dtype=float)[:2]
            d = b - prev
            hd = math.atan2(d[1], d[0]) if float(np.hypot(*d)) > 1.0 else self._course_now()
            self._begin_landing(Runway(b, hd))

    def _item_reached(self) -> None:
        seq = self._progress.current
        self._progress.reached.append(seq)
        if seq + 1 < len(self._mission):
            self._start_item(seq + 1)
        else:
            self._progress.finished = True
            if self._flying():
                self._enter_hold()  # PX4: loiter at the end of the mission, still in MISSION

    def _mission_tick(self) -> None:
        if self._progress.finished or not self._mission:
            return
        it = self._mission[self._progress.current]
        pos = self._state.pos_ned[:2]
        if it.command == MissionCommand.WAYPOINT and self._phase == Phase.TRACK:
            acc = it.accept_radius if it.accept_radius > 0 else self.p("NAV_ACC_RAD")
            ab = self._b - self._a
            n = float(np.hypot(*ab))
            along = float((pos - self._a) @ ab) / n if n > 1e-3 else math.inf
            if float(np.hypot(*(pos - self._b))) < acc or along >= n:
                self._item_reached()
        elif it.command == MissionCommand.LOITER_TIME and self._phase == Phase.LOITER:
            on_circle = (
                abs(float(np.hypot(*(pos - self._center))) - self._radius) < 0.2 * self._radius
            )
            if self._loiter_until is None and on_circle:
                self._loiter_until = self.clock.t + max(0.0, it.hold_s)
            if self._loiter_until is not None and self.clock.t >= self._loiter_until:
                self._item_reached()
        elif it.command == MissionCommand.LOITER_UNLIM and self._phase == Phase.LOITER:
            d = abs(float(np.hypot(*(pos - self._center))) - self._radius)
            if d < 0.2 * self._radius and self._reported != self._progress.current:
                self._reported = self._progress.current  # reached; it still loiters for ever
                self._progress.reached.append(self._progress.current)

    # ---- offboard -------------------------------------------------------------------------
    def _apply_offboard(self) -> None:
        sp = self._offboard
        if sp is None:
            return
        if sp.pos_ned is not None:
            tgt = np.asarray(sp.pos_ned, dtype=float)
            alt = -tgt[2]
            same = self._phase == Phase.LOITER and float(np.hypot(*(self._center - tgt[:2]))) < 1.0
            if not same:
                self._set_loiter(tgt[:2], self.default_loiter_radius(), 1, alt)
            self._h_dem = alt
        elif sp.vel_ned is not None:
            v = np.asarray(sp.vel_ned, dtype=float)
            if self._phase != Phase.COURSE:
                self._h_dem = self._state.altitude
            self._phase = Phase.COURSE
            vh = math.hypot(v[0], v[1])
            self._course = math.atan2(v[1], v[0]) if vh > 0.5 else self._course_now()
            self._climb = -float(v[2])
            lo, hi = self.p("FW_AIRSPD_MIN"), self.p("FW_AIRSPD_MAX")
            self._v_dem = min(hi, max(lo, vh)) if vh > 0.5 else self.p("FW_AIRSPD_TRIM")

    # ---- the loop -------------------------------------------------------------------------
    def step(self) -> None:
        """Advance the clock by `control_dt`: autopilot once, JSBSim `control_dt/physics_dt` times."""
        if self._inj is not None:
            self._apply_faults()
            self._state = self._estimate(self._true_state)
        self._fence_check()
        cmd = self._control(self._state)
        s = self.model.step(self.control_dt, cmd)
        self.clock.advance(self._dt_us)
        self._true_state = self._stamp(s)
        self._state = self._estimate(self._true_state)

    def _control(self, st: VehicleState) -> Surfaces:
        dt = self.control_dt
        t = self.clock.t
        if not self._armed:
            return Surfaces(brake=1.0)
        if t >= self._next_battery_check:  # 1 Hz, as the multirotor
            self._next_battery_check = t + 1.0
            self._battery_failsafe()
        if self._mode == FlightMode.OFFBOARD and t - self._offboard_t > self.p("COM_OF_LOSS_T"):
            self._event(offboard_lost_text(t - self._offboard_t, self.p("COM_OF_LOSS_T")))
            self._mode = FlightMode.HOLD  # offboard lost (COM_OF_LOSS_T): hold = loiter
            self._enter_hold()
        if self._mode == FlightMode.MISSION:
            self._mission_tick()
        if self._mode == FlightMode.RTL and self._phase == Phase.TRACK:
            if float(np.hypot(*st.pos_ned[:2])) < 1.5 * self.default_loiter_radius():
                self._set_loiter(np.zeros(2), self.default_loiter_radius(), 1, self._h_dem)
        if self._mode == FlightMode.RTL and self._phase == Phase.LOITER:
            delay = self.p("RTL_LAND_DELAY")
            if self._rtl_loiter_t is None:
                self._rtl_loiter_t = t
            if delay >= 0 and t - self._rtl_loiter_t >= delay:
                self._mode = FlightMode.LAND
                self._begin_landing(Runway(np.zeros(2), self.home.heading_rad))

        if self._mode == FlightMode.MANUAL:
            x, y, z, r = self._sticks
            return Surfaces(aileron=y, elevator=-x, rudder=r, throttle=z)
        ph = self._phase
        if ph in (Phase.IDLE, Phase.LANDED):
            return self._on_ground(st)
        if ph == Phase.TAKEOFF_ROLL:
            return self._takeoff_roll(st)
        if ph == Phase.ROLLOUT:
            return self._rollout(st)
        if self._mode in (FlightMode.STABILIZED, FlightMode.ALTCTL, FlightMode.POSCTL):
            return self._sticks_flight(st, dt)
        return self._auto_flight(st, dt)

    # ---- ground phases ----------------------------------------------------------------------
    def _on_ground(self, st: VehicleState) -> Surfaces:
        if self._phase == Phase.LANDED and self._landed_t is not None:
            delay = self.p("COM_DISARM_LAND")
            if delay >= 0 and self.clock.t - self._landed_t >= delay:
                self.disarm()
        return Surfaces(elevator=1.0, brake=1.0, throttle=0.0)

    def _steer(self, st: VehicleState, rw: Runway) -> float:
        """Rudder / tail-wheel command holding the runway centre line."""
        g = self.gains
        xt = guidance.cross2(rw.dir, st.pos_ned[:2] - rw.point)  # > 0 right of the line
        psi_dem = rw.heading - max(-0.3, min(0.3, 0.05 * xt))
        e = wrap_pi(psi_dem - st.euler[2])
        return g.steer_p * e - g.steer_d * st.omega_frd[2]

    def _takeoff_roll(self, st: VehicleState) -> Surfaces:
        rw = self._runway
        assert rw is not None
        v = self.model.airspeed
        roll, pitch, _ = st.euler
        ail = self.att.wings_level_aileron(st)
        rot = self.p("FW_TKO_AIRSPD")
        if v < 8.0:
            el = 0.0
        else:
            rotate = v >= rot
            pitch_dem = math.radians(10.0) if rotate else math.radians(2.0)
            el = (0.4 if rotate else 0.0) + 2.0 * (pitch_dem - pitch) - 0.5 * st.omega_frd[1]
        wheels_h = self.model.agl - self.model.ground_cg_height
        if not self.model.wheels_down() and wheels_h > 1.0:
            self._phase = Phase.TAKEOFF_CLIMB
            self.att.pitch_i = el
            self.tecs.reset(1.0, pitch)
        return Surfaces(ail, el, self._steer(st, rw), self.p("FW_THR_MAX"), 0.0)

    def _rollout(self, st: VehicleState) -> Surfaces:
        rw = self._runway
        assert rw is not None
        gs = float(np.hypot(*st.vel_ned[:2]))
        ail = self.att.wings_level_aileron(st)
        # Taildragger: stick back only once slow (no balloon), gentle brakes (no nose-over).
        el = 1.0 if gs < 14.0 else 0.2
        brake = 0.1 if gs > 14.0 else 0.45
        if gs < 0.3:
            self._phase = Phase.LANDED
            self._landed_t = self.clock.t
            cur = self._progress.current
            if (
                self._mode == FlightMode.MISSION
                and cur < len(self._mission)
                and self._mission[cur].command == MissionCommand.LAND
            ):
                self._item_reached()  # a LAND item is reached once stopped on the ground
        return Surfaces(ail, el, self._steer(st, rw), 0.0, brake)

    # ---- flight -------------------------------------------------------------------------------
    def _bank_limit(self, v: float) -> float:
        """FW_R_LIM, reduced so the load factor keeps 15 % above the stall: cos φ ≥ (1.15 Vs/V)^2."""
        lim = math.radians(self.p("FW_R_LIM"))
        ratio = (1.15 * self.p("FW_AIRSPD_STALL") / max(v, 1.0)) ** 2
        stall_lim = math.acos(ratio) if ratio < 1.0 else 0.0
        return max(math.radians(5.0), min(lim, stall_lim))

    def _auto_flight(self, st: VehicleState, dt: float) -> Surfaces:
        v = self.model.airspeed
        pos, vel = st.pos_ned[:2], st.vel_ned[:2]
        h, hdot = st.altitude, -float(st.vel_ned[2])
        l1p = guidance.L1Params(self.p("NAV_L1_PERIOD"), self.p("NAV_L1_DAMPING"))
        ph = self._phase
        bank_lim = self._bank_limit(v)
        thr_min, thr_max = self.p("FW_THR_MIN"), self.p("FW_THR_MAX")
        pitch_min = math.radians(self.p("FW_P_LIM_MIN"))
        pitch_max = math.radians(self.p("FW_P_LIM_MAX"))
        climb_max, sink_max = self.p("FW_T_CLMB_MAX"), self.p("FW_T_SINK_MAX")
        h_dem, v_dem, weight, hdot_ff = self._h_dem, self._v_dem, 1.0, 0.0
        wheels_h = self.model.agl - self.model.ground_cg_height

        if ph == Phase.TAKEOFF_CLIMB:
            rw = self._runway
            assert rw is not None
            lat = guidance.track(l1p, pos, vel, rw.point, rw.point + rw.dir * 5000.0).lat_acc
            thr_min = thr_max
            weight = 2.0  # pitch holds the climb speed, full throttle climbs
            v_dem = self.p("FW_AIRSPD_MIN")
            if h < 15.0:
                bank_lim = min(bank_lim, math.radians(8.0))
            if h >= self._h_dem - 3.0:
                self._takeoff_done()
        elif ph == Phase.LOITER:
            lat = guidance.loiter(
                l1p, pos, vel, self._center, self._radius, self._loiter_dir
            ).lat_acc
        elif ph == Phase.TRACK:
            lat = guidance.track(l1p, pos, vel, self._a, self._b).lat_acc
        elif ph == Phase.COURSE:
            e = wrap_pi(self._course - self._course_now())
            lat = self.gains.course_k * e * max(v, 1.0)
            self._h_dem += self._climb * dt
            self._h_dem = min(max(self._h_dem, h - 10.0), h + 10.0)
            h_dem, hdot_ff = self._h_dem, self._climb
        elif ph == Phase.LAND_DESCEND:
            lat = guidance.loiter(l1p, pos, vel, self._center, self._radius, 1).lat_acc
            # Halfway to the approach speed: enough bank authority for the circle, and less
            # kinetic energy to lose on the final (the J3Cub cannot dive it off at idle).
            v_dem = 0.5 * (self.p("FW_LND_AIRSPD") + self.p("FW_AIRSPD_TRIM"))
            rw = self._runway
            assert rw is not None
            gate = rw.point - rw.dir * self._final_length()
            course_err = abs(wrap_pi(self._course_now() - rw.heading))
            # At the gate: on the circle's tangent point, aligned with the final, at height.
            ang = guidance.cross2(self._center - gate, pos - self._center)
            ang = math.atan2(ang, float((gate - self._center) @ (pos - self._center)))
            if (
                abs(h - h_dem) < 5.0
                and abs(ang) < math.radians(20)
                and course_err < math.radians(30)
            ):
                self._phase = Phase.LAND_FINAL
        elif ph in (Phase.LAND_FINAL, Phase.FLARE):
            rw = self._runway
            assert rw is not None
            gate = rw.point - rw.dir * self._final_length()
            lat = guidance.track(l1p, pos, vel, gate, rw.point + rw.dir * 2000.0).lat_acc
            to_td = float((rw.point - pos) @ rw.dir)
            gam = math.radians(self.p("FW_LND_ANG"))
            v_dem = self.p("FW_LND_AIRSPD")
            if ph == Phase.LAND_FINAL:
                # The glide path aims short of the touchdown point by twice the flare's
                # geometric length (2·h_flare/tan γ): the flare and float carry it that far.
                aim = to_td - 2.0 * self.p("FW_LND_FLALT") / math.tan(gam)
                h_dem = max(0.0, aim) * math.tan(gam) + self.model.ground_cg_height
                hdot_ff = -v * math.sin(gam)
                if wheels_h < self.p("FW_LND_FLALT"):
                    self._phase = Phase.FLARE
                elif to_td < 0.0 and wheels_h > 10.0:  # overshot: circle down again
                    self._begin_landing(rw)
            if self._phase == Phase.FLARE:
                bank_lim = min(bank_lim, math.radians(5.0))
                thr_min = thr_max = 0.0
                weight = 0.0  # pitch for sink rate only
                pitch_min = 0.0
                h_dem = h
                # Exponential flare to a gentle sink, then hold off while the speed bleeds.
                hdot_ff = -max(0.4, wheels_h / 2.0)
                if self.model.wheels_down():
                    self._phase = Phase.ROLLOUT
        else:  # DIRECT or anything unexpected: wings level, hold height
            lat = 0.0

        # Stall and overspeed protection (all automatic phases but the flare).
        if self._phase != Phase.FLARE:
            v_dem = min(self.p("FW_AIRSPD_MAX"), max(self.p("FW_AIRSPD_MIN"), v_dem))
            if v < self.p("FW_AIRSPD_MIN") - 1.0 and wheels_h > 3.0:
                weight, thr_min = 2.0, thr_max  # underspeed: speed first, full power
                climb_max = 0.5 * climb_max
            if v > self.p("FW_AIRSPD_MAX"):
                weight, thr_max = 2.0, thr_min  # overspeed: idle, pitch up to slow
        out = self.tecs.update(
            dt, h, hdot, v, h_dem, v_dem,
            climb_max=climb_max, sink_max=sink_max, thr_min=thr_min, thr_max=thr_max,
            pitch_min=pitch_min, pitch_max=pitch_max, speed_weight=weight, hdot_ff=hdot_ff,
        )  # fmt: skip
        bank = max(-bank_lim, min(bank_lim, math.atan2(lat, GRAVITY)))
        ail, el, rud = self.att.update(st, bank, out.pitch, v, self.p("FW_AIRSPD_TRIM"), dt)
        return Surfaces(ail, el, rud, out.throttle, 0.0)

    def _takeoff_done(self) -> None:
        then = self._after_takeoff
        if then == "mission" and self._mode == FlightMode.MISSION:
            self._phase = Phase.TRACK
            self._item_reached()
        elif then == "mission_item" and self._mode == FlightMode.MISSION:
            self._phase = Phase.TRACK
            self._start_item(self._progress.current)
        else:
            if self._mode == FlightMode.TAKEOFF:
                self._mode = FlightMode.HOLD
            self._enter_hold(self._h_dem)

    def _sticks_flight(self, st: VehicleState, dt: float) -> Surfaces:
        """STABILIZED: sticks → bank and pitch, throttle direct. ALTCTL/POSCTL: sticks → bank
        and climb rate, TECS holds airspeed."""
        x, y, z, _ = self._sticks
        v = self.model.airspeed
        bank = y * self._bank_limit(v)
        if self._mode == FlightMode.STABILIZED:
            pitch = -x * math.radians(self.p("FW_P_LIM_MAX"))
            ail, el, rud = self.att.update(st, bank, pitch, v, self.p("FW_AIRSPD_TRIM"), dt)
            return Surfaces(ail, el, rud, z, 0.0)
        climb = -x * self.p("FW_T_CLMB_MAX")
        self._h_dem = min(max(self._h_dem + climb * dt, st.altitude - 10.0), st.altitude + 10.0)
        out = self.tecs.update(
            dt, st.altitude, -float(st.vel_ned[2]), v, self._h_dem, self.p("FW_AIRSPD_TRIM"),
            climb_max=self.p("FW_T_CLMB_MAX"), sink_max=self.p("FW_T_SINK_MAX"),
            thr_min=self.p("FW_THR_MIN"), thr_max=self.p("FW_THR_MAX"),
            pitch_min=math.radians(self.p("FW_P_LIM_MIN")),
            pitch_max=math.radians(self.p("FW_P_LIM_MAX")), hdot_ff=climb,
        )  # fmt: skip
        ail, el, rud = self.att.update(st, bank, out.pitch, v, self.p("FW_AIRSPD_TRIM"), dt)
        return Surfaces(ail, el, rud, out.throttle, 0.0)
