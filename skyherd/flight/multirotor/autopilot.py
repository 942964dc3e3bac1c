"""`MultirotorAutopilot`: the quadrotor and its onboard autopilot (implements `Autopilot`).

Per `step()` (one control period, default 4 ms = 250 Hz):
  1. commander: failsafes (offboard / manual loss), land detector, auto-disarm;
  2. navigator: the current mode writes a setpoint (position, velocity, attitude, thrust);
  3. one compiled call runs the position/velocity loops once and, per 1 ms physics substep,
     attitude, rate, mixer and physics (flight/multirotor/control.py);
  4. the clock advances by control_dt and one VehicleState is built.
Time comes only from the SimClock. Randomness only from faults (flight/faults.py): a
`FaultPlan` with a Generator seeded from `seed`. The autopilot flies on its estimate
(`state`: truth + the GPS error of the fault plan, what LOCAL_POSITION_NED reports);
`true_state` is the physics. Without GPS or baro faults or noise both are the same object.

Geofence (flight/geofence.py): an uploaded fence (`set_fence`) and GF_MAX_HOR_DIST /
GF_MAX_VER_DIST. Targets outside are refused (reposition, offboard positions, mission items
at upload and at start, takeoff height), arming outside is refused; a breach (GF_COUNT
samples at 20 Hz) takes GF_ACTION: 1 warn, 2 hold, 3 return, 4/5 land.

Brake rule (HOLD and LAND entered while moving): zero-velocity setpoint until the ground
speed is below BRAKE_SPEED, or it has made no new minimum (by BRAKE_MIN_GAIN) for
BRAKE_STALL_S (a wind stronger than the velocity loop's integrator can hold never lets it get
slower), or BRAKE_MAX_S have passed; then the position there is captured and held.

Trajectory shaping (SH_POS_SMOOTH 1: auto modes; 2: and offboard position-only setpoints;
0, the default: targets go straight to the position loop): a reference r moves toward the
target with speed min(v_max, √(2 a d), K d) (d the distance from where the reference would
stop, r + ṙ·a/j, to the target; a = MPC_ACC_HOR,
K = MPC_XY_TRAJ_P; vertically MPC_ACC_UP_MAX / MPC_ACC_DOWN_MAX and K = MPC_Z_P), its
velocity following it (below); the position loop tracks r with ṙ as
feed-forward. Its acceleration follows k (v_des − ṙ), k = j/a, at most a, and changes by at
most j·dt per step (j = MPC_JERK_AUTO): a jerk-limited reference, simpler than PX4's
time-optimal one.

GPS loss: the estimate dead-reckons (flight/faults.py); after EKF2_NOAID_TOUT s without a fix
the position is invalid and the vehicle lands where it is (LAND, a PX4-like "descend"),
unless it is in a mode that needs no position (MANUAL, STABILIZED, ALTCTL).
"""

from __future__ import annotations

import math
from pathlib import Path

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
from skyherd.flight.frames import wrap_pi
from skyherd.flight.geo import DEFAULT_HOME, Home
from skyherd.flight.geofence import ACTION_HOLD, ACTION_NAMES, ACTION_NONE, ACTION_RTL, FenceMonitor
from skyherd.flight.multirotor import layout as ctl  # the compiled step's arrays, by index
from skyherd.flight.multirotor.compiled import kernels
from skyherd.flight.multirotor.mixer import allocation_inverse
from skyherd.flight.multirotor.params import MULTIROTOR_PARAMS
from skyherd.flight.params import ParamStore
from skyherd.flight.quadrotor import (
    A_ENERGY,
    A_ON_GROUND,
    A_WIND,
    DEFAULT_AIRFRAME,
    X_MOTOR,
    QuadrotorParams,
    WindField,
    WindModel,
)
from skyherd.flight.state import VehicleState

_MANUAL_MODES = (FlightMode.MANUAL, FlightMode.STABILIZED, FlightMode.ALTCTL, FlightMode.POSCTL)
_MAX_ABS_POS = 1.0e5  # [m] setpoints farther than this are refused
_MAX_ABS_VEL = 50.0  # [m/s]
_GROUND_Z = -0.3  # [m] a target below this height (down > −0.3) keeps a landed vehicle idle
_NO_POSITION_MODES = (FlightMode.MANUAL, FlightMode.STABILIZED, FlightMode.ALTCTL)
BRAKE_SPEED = 0.3  # [m/s] braking ends below this ground speed (PX4's hold capture)
BRAKE_MIN_GAIN = 0.05  # [m/s] a new speed minimum must be this much lower ...
BRAKE_STALL_S = 0.5  # [s] ... within this long, or the brake has done what it can
BRAKE_MAX_S = 4.0  # [s] braking never lasts longer
WIND_TAU_S = 1.0  # [s] the wind estimate's low-pass time constant (control.estimate_wind)
WIND_FF_MIN_MPS = 1.0  # [m/s] the wind estimate is fed forward only beyond this (control.py)


def _vec3(v, limit: float) -> np.ndarray | None:
    """A private float copy of a (3,) vector; ValueError if not finite or |v_i| > limit."""
    if v is None:
        return None
    a = np.array(v, dtype=float)
    if a.shape != (3,):
        raise ValueError("vectors need 3 components")
    if not (abs(a).max() <= limit):  # also false for NaN
        raise ValueError(f"not finite or beyond {limit:g}")
    return a


class MultirotorAutopilot(AutopilotBase):
    """A quadrotor with a PX4-like autopilot on the simulation clock.

    params_file: TOML with a `[params]` table of overrides; airframe: airframe file;
    home: geodetic home; clock: the shared SimClock (a new one if None); control_dt [s]:
    autopilot period (a multiple of the physics step); seed: recorded, unused (no noise);
    start_pos_ned [m], start_yaw [rad]: where it starts (on the ground if down >= 0);
    battery_start: charge at start [0, 1] (for battery drills); wind: mean wind and seeded
    gusts acting on the airframe's drag (None: calm air); faults: a FaultPlan (its wind
    replaces `wind`); rng: the Generator the faults draw from (default seeded from `seed`).
    """

    airframe = "quadrotor"

    def __init__(
        self,
        params_file: Path | str | None = None,
        home: Home = DEFAULT_HOME,
        clock: SimClock | None = None,
        seed: int = 0,
        control_dt: float = 0.004,
        airframe_file: Path | str = DEFAULT_AIRFRAME,
        start_pos_ned: tuple[float, float, float] = (0.0, 0.0, 0.0),
        start_yaw: float = 0.0,
        battery_start: float = 1.0,
        wind: WindModel | None = None,
        faults: FaultPlan | None = None,
        rng: np.random.Generator | None = None,
    ):
        self.home = home
        self.clock = clock if clock is not None else SimClock()
        self.seed = int(seed)
        if not (0.0 <= battery_start <= 1.0):
            raise ValueError(f"battery_start must be in [0, 1], got {battery_start}")
        self._battery_start = float(battery_start)
        self.vehicle = QuadrotorParams.from_toml(airframe_file)
        n = round(control_dt / self.vehicle.physics_dt)
        if n < 1 or abs(n * self.vehicle.physics_dt - control_dt) > 1e-9:
            raise ValueError(
                f"control_dt {control_dt} s must be a multiple of physics_dt "
                f"{self.vehicle.physics_dt} s"
            )
        self.control_dt = float(control_dt)
        self._n_sub = int(n)
        self._dt_sub = self.vehicle.physics_dt
        self._dt_us = round(control_dt * 1e6)
        self.params = ParamStore(MULTIROTOR_PARAMS)
        if params_file is not None:
            self.params.load_toml(params_file)
        # the compiled step (ahead of time, else numba's: multirotor.compiled) over one work
        # array and one constant array; named views into them
        compiled = kernels()
        self._control_step, self._level_with_yaw = (
            compiled.control_step_packed,
            compiled.level_with_yaw,
        )
        self._w = np.zeros(ctl.N_W)
        self._k = np.zeros(ctl.N_K)
        self._p = self._k[ctl.K_P : ctl.K_C]
        self._p[:] = self.vehicle.to_array()
        self._c = self._k[ctl.K_C : ctl.N_K]
        self._x = self._w[ctl.W_X : ctl.W_AUX]
        self._aux = self._w[ctl.W_AUX : ctl.W_CS]
        self._cs = self._w[ctl.W_CS : ctl.W_SP]
        self._sp = self._w[ctl.W_SP : ctl.W_U]
        self._u = self._w[ctl.W_U : ctl.N_W]
        self._c_rev = -1
        self._mix = allocation_inverse(
            self.vehicle.rotor_xy,
            np.asarray(self.vehicle.spin),
            self.vehicle.k_thrust,
            self.vehicle.k_torque,
        ).ravel()
        self._weight = self.vehicle.mass * self.vehicle.gravity
        self._t_max = 4.0 * self.vehicle.max_thrust
        # commander / navigator state
        self._armed = False
        self._mode = FlightMode.HOLD
        self._mode_before_rtl = FlightMode.HOLD  # the rtl fault's way back (flight.faults)
        self._ground_since: float | None = 0.0
        self._armed_at = 0.0
        self._flown = False  # took off since arming
        self._hold_pos = np.zeros(3)
        self._braking = False
        self._yaw_sp = 0.0
        self._target = np.zeros(3)
        self._takeoff_target = np.zeros(3)
        self._land_xy = np.zeros(2)
        self._landing = False
        self._rtl_phase = "climb"
        self._rtl_alt = 0.0
        self._rtl_xy = np.zeros(2)
        self._climb_xy = np.zeros(2)
        self._offboard: Setpoint | None = None
        self._offboard_t = -math.inf
        self._manual = (0.0, 0.0, 0.0, 0.0)
        self._manual_t = -math.inf
        self._man_hold_xy: np.ndarray | None = None
        self._man_hold_z: float | None = None
        self._items: list[MissionItem] = []
        self._progress = MissionProgress()
        self._item_started = False
        self._item_reached_at: float | None = None
        self._climb_first = False
        self._status: list[str] = []
        self._next_battery_check = 0.0
        self._ref = np.zeros(3)  # shaped target reference [m] and its velocity [m/s]
        self._ref_v = np.zeros(3)
        self._ref_a = np.zeros(3)
        self._ref_t = -math.inf
        self._brake_t0 = 0.0
        self._brake_vmin = math.inf
        self._brake_vmin_t = 0.0
        self._battery_drop = 0.0  # [0, 1] charge lost to battery faults
        self._extra_j = 0.0  # [J] energy drawn by drain faults
        self.fence = FenceMonitor()
        self._fence_on = False
        self._refused = 0  # offboard setpoints refused by the fence (STATUSTEXT rate limit)
        self.faults = faults if faults is not None and not faults.empty else None
        self._inj: FaultInjector | None = None
        if self.faults is not None:
            gen = rng if rng is not None else np.random.default_rng(self.seed)
            self._inj = FaultInjector(self.faults, gen)
            self.wind = self._inj.wind
        else:
            self.wind = WindField(wind if wind is not None else WindModel(seed=self.seed))
        # the navigator's view of the state: the truth itself unless faults touch the estimate
        self._est_on = self._inj is not None and self._inj.touches_estimate
        self._ex = self._x.copy() if self._est_on else self._x
        self._gps_fix = True
        self._pos_valid = True
        self._reset_vehicle(np.asarray(start_pos_ned, dtype=float), float(start_yaw))
        self._true_state = self._state = self._make_state()
        if self._est_on:
            self._gps_update(self._inj, self.clock.t)
            self._state = self._make_state(self._ex)

    # ------------------------------------------------------------------ properties

    @property
    def landed_state(self) -> LandedState:
        if self._aux[A_ON_GROUND] > 0.5:
            return LandedState.ON_GROUND
        if self._mode == FlightMode.TAKEOFF:
            return LandedState.TAKEOFF
        if self._landing:
            return LandedState.LANDING
        return LandedState.IN_AIR

    @property
    def battery_remaining(self) -> float:
        """Remaining charge [0, 1]: shaft energy / efficiency + avionics, over capacity."""
        v = self.vehicle
        used = self._aux[A_ENERGY] / v.efficiency + v.avionics_power * self.clock.t + self._extra_j
        rem = self._battery_start - self._battery_drop - used / (v.battery_capacity_wh * 3600.0)
        return float(min(1.0, max(0.0, rem)))

    @property
    def battery_voltage(self) -> float:
        """Pack voltage [V], linear in the remaining charge."""
        v = self.vehicle
        return v.voltage_empty + (v.voltage_full - v.voltage_empty) * self.battery_remaining

    @property
    def wind_ned(self) -> np.ndarray:
        """(3,) wind acting now [m/s], NED."""
        return self._aux[A_WIND : A_WIND + 3].copy()

    @property
    def wind_estimate_ned(self) -> np.ndarray:
        """(3,) the autopilot's own wind estimate [m/s], NED (down 0: not estimated), from its
        accelerometer and drag model (flight/multirotor/control.py); what WIND_COV reports."""
        w = self._cs[ctl.CS_WIND : ctl.CS_WIND + 2]
        return np.array([w[0], w[1], 0.0])

    @property
    def motor_commands(self) -> np.ndarray:
        """(4,) last normalised motor commands."""
        return self._cs[ctl.CS_U : ctl.CS_U + 4].copy()

    @property
    def motor_speed(self) -> np.ndarray:
        return self._x[X_MOTOR:].copy()

    @property
    def on_ground(self) -> bool:
        return bool(self._aux[A_ON_GROUND] > 0.5)

    def drain_status(self) -> list[str]:
        """Human-readable events since the last call (mode changes, failsafes)."""
        if not self._status:
            return []  # the common step: nothing happened
        out, self._status = self._status, []
        return out

    # ------------------------------------------------------------------ stepping
    def step(self) -> None:
        if self._c_rev != self.params.revision:
            self._build_constants()
        t = self.clock.t
        inj = self._inj
        if inj is not None:
            self._apply_faults(inj, t)
        elif not self._calm:
            self._aux[A_WIND : A_WIND + 3] = self.wind.sample(self.control_dt)
        self._commander(t)
        if self._fence_on and self.fence.due(t):
            self._fence_check()
        sp = self._sp
        if self._armed:
            self._navigate(t)
            self._ground_idle_if_landed()
            sp[ctl.SP_ARMED] = 1.0
        else:
            sp[ctl.SP_ARMED] = 0.0
        if self._est_on:
            # fly on the estimate: p_sp − p̂ = (p_sp − e_p) − p, the same for velocity
            e = inj.err.pv
            sp[0:6] -= e
            self._control_step(self._w, self._k, self._dt_sub, self._n_sub)
            sp[0:6] += e
        else:
            self._control_step(self._w, self._k, self._dt_sub, self._n_sub)
        self.clock.advance(self._dt_us)
        if self._est_on:
            self._gps_update(inj, self.clock.t)
        # both built when first asked for: most steps nobody reads them (telemetry at 10-50 Hz,
        # the camera at 10 Hz), and a VehicleState costs as much as a third of the physics
        self._true_state = self._state = None

    @property
    def state(self) -> VehicleState:
        """What the autopilot believes and reports now (the truth unless faults touch the
        estimate)."""
        if self._state is None:
            self._state = self._make_state(self._ex) if self._est_on else self.true_state
        return self._state

    @property
    def true_state(self) -> VehicleState:
        """The physics (ground truth) now; `state` is what the autopilot believes and reports."""
        if self._true_state is None:
            self._true_state = self._make_state()
        return self._true_state

    def _update_estimate(self) -> None:
        """The estimate: truth + the injector's current error (position and velocity)."""
        ex = self._ex
        ex[:] = self._x
        ex[0:6] += self._inj.err.pv

    def _apply_faults(self, inj: FaultInjector, t: float) -> None:
        """Wind, GPS error and battery faults for the step that starts at t."""
        dt = self.control_dt
        if not inj.calm:
            self._aux[A_WIND : A_WIND + 3] = inj.wind_ned(t, dt)
        if inj._battery_events:
            drop, watts = inj.battery(t)
            if drop is not None and drop < self.battery_remaining:
                self._battery_drop += self.battery_remaining - drop
                self._event(f"battery fault: charge {drop:.0%}")
            self._extra_j += watts * dt
        if inj._switch_events:
            apply_switches(self, inj.switches(t))

    def _gps_update(self, inj: FaultInjector, t: float) -> None:
        """The estimate at t (after the physics step) and the GPS-loss rule."""
        e = inj.update(t, self.control_dt)
        self._update_estimate()
        if e.fix != self._gps_fix:
            self._gps_fix = e.fix
            self._event("gps fix regained" if e.fix else "gps fix lost: dead reckoning")
            if e.fix and not self._pos_valid:
                self._pos_valid = True
                self._event("position estimate valid again")
        if not e.fix and self._pos_valid and e.lost_s > self.params["EKF2_NOAID_TOUT"]:
            self._pos_valid = False
            self._event(f"no position for {e.lost_s:.1f} s: position estimate invalid")
            if self._armed and self._mode not in _NO_POSITION_MODES + (FlightMode.LAND,):
                self._event("failsafe: position lost -> land")
                self._switch(FlightMode.LAND)
                self._failsafe_action("position lost: land")

    def _make_state(self, src: np.ndarray | None = None) -> VehicleState:
        """One copy of the state vector; the state's arrays are views into it (hot path)."""
        x = (self._x if src is None else src).copy()
        return VehicleState(
            self.clock.t,
            x[0:3],
            x[3:6],
            x[6:10],
            x[10:13],
            self._aux[0:3].copy(),
            bool(self._aux[A_ON_GROUND] > 0.5),
        )

    def _reset_vehicle(self, pos: np.ndarray, yaw: float) -> None:
        self._x[:] = 0.0
        self._x[0:3] = pos
        self._x[6] = math.cos(0.5 * yaw)
        self._x[9] = math.sin(0.5 * yaw)
        self._aux[:] = 0.0
        if pos[2] >= 0.0:
            self._x[2] = 0.0
            self._aux[A_ON_GROUND] = 1.0
            self._level_with_yaw(self._x)
        self._aux[2] = -self.vehicle.gravity
        self._calm = self.wind.calm
        self._aux[A_WIND : A_WIND + 3] = self.wind.sample(self.control_dt)
        self._yaw_sp = yaw
        self._hold_pos = self._x[0:3].copy()
        if self._ex is not self._x:
            self._ex[:] = self._x

    def _build_constants(self) -> None:
        """Parameters → the compiled controller's constant array (degrees → rad here)."""
        P = self.params
        c = self._c
        d = math.radians
        c[ctl.C_KP_XY] = P["MPC_XY_P"]
        c[ctl.C_KP_Z] = P["MPC_Z_P"]
        c[ctl.C_KV_XY] = P["MPC_XY_VEL_P_ACC"]
        c[ctl.C_KI_XY] = P["MPC_XY_VEL_I_ACC"]
        c[ctl.C_KV_Z] = P["MPC_Z_VEL_P_ACC"]
        c[ctl.C_KI_Z] = P["MPC_Z_VEL_I_ACC"]
        c[ctl.C_TILT_MAX] = d(P["MPC_TILTMAX_AIR"])
        c[ctl.C_VINT_MAX] = P["MPC_VEL_I_LIM"]
        c[ctl.C_VINT_ERR] = P["MPC_VEL_I_ERR"]
        ff, v = P["MPC_DRAG_FF"], self.vehicle
        c[ctl.C_DRAG_LIN : ctl.C_DRAG_LIN + 2] = ff * v.drag_linear[0], ff * v.drag_linear[2]
        c[ctl.C_DRAG_QUAD : ctl.C_DRAG_QUAD + 2] = (
            ff * v.drag_quadratic[0],
            ff * v.drag_quadratic[2],
        )
        # the wind estimator inverts the airframe's body x / y drag (PX4: EKF2_BCOEF_X/Y, MCOEF)
        c[ctl.C_WDRAG_LIN : ctl.C_WDRAG_LIN + 2] = v.drag_linear[0], v.drag_linear[1]
        c[ctl.C_WDRAG_QUAD : ctl.C_WDRAG_QUAD + 2] = v.drag_quadratic[0], v.drag_quadratic[1]
        c[ctl.C_WIND_TAU] = WIND_TAU_S
        c[ctl.C_WIND_FF_MIN] = WIND_FF_MIN_MPS
        c[ctl.C_KATT : ctl.C_KATT + 3] = (P["MC_ROLL_P"], P["MC_PITCH_P"], P["MC_YAW_P"])
        c[ctl.C_RATE_MAX : ctl.C_RATE_MAX + 3] = (
            d(P["MC_ROLLRATE_MAX"]),
            d(P["MC_PITCHRATE_MAX"]),
            d(P["MC_YAWRATE_MAX"]),
        )
        c[ctl.C_KRP : ctl.C_KRP + 3] = (P["MC_ROLLRATE_P"], P["MC_PITCHRATE_P"], P["MC_YAWRATE_P"])
        c[ctl.C_KRI : ctl.C_KRI + 3] = (P["MC_ROLLRATE_I"], P["MC_PITCHRATE_I"], P["MC_YAWRATE_I"])
        c[ctl.C_KRD : ctl.C_KRD + 3] = (P["MC_ROLLRATE_D"], P["MC_PITCHRATE_D"], P["MC_YAWRATE_D"])
        c[ctl.C_RINT_MAX] = P["MC_RATE_I_LIM"]
        c[ctl.C_T_MIN] = P["MPC_THR_MIN"] * self._t_max
        c[ctl.C_T_MAX] = P["MPC_THR_MAX"] * self._t_max
        c[ctl.C_T_IDLE] = self.vehicle.max_thrust * P["MOT_SPIN_ARM"] ** 2
        c[ctl.C_T_ROTOR_MAX] = self.vehicle.max_thrust
        c[ctl.C_MASS] = self.vehicle.mass
        c[ctl.C_MIX : ctl.C_MIX + 16] = self._mix
        # navigation limits, cached as plain floats
        self._vxy_max = P["MPC_XY_VEL_MAX"]
        self._vxy_cruise = P["MPC_XY_CRUISE"]
        self._vz_up = P["MPC_Z_VEL_MAX_UP"]
        self._vz_dn = P["MPC_Z_VEL_MAX_DN"]
        self._of_loss_t = P["COM_OF_LOSS_T"]
        self._rc_loss_t = P["COM_RC_LOSS_T"]
        self._disarm_land = P["COM_DISARM_LAND"]
        self._disarm_prflt = P["COM_DISARM_PRFLT"]
        self._land_trig = P["LNDMC_TRIG_TIME"]
        self._bat_crit = P["BAT_CRIT_THR"]
        self._bat_emergency = P["BAT_EMERGEN_THR"]
        self._smooth = int(P["SH_POS_SMOOTH"])
        self._acc_hor, self._traj_p = P["MPC_ACC_HOR"], P["MPC_XY_TRAJ_P"]
        self._acc_up, self._acc_dn = P["MPC_ACC_UP_MAX"], P["MPC_ACC_DOWN_MAX"]
        self._traj_pz = P["MPC_Z_P"]
        self._jerk = P["MPC_JERK_AUTO"]
        self.fence.configure(None, P["GF_MAX_HOR_DIST"], P["GF_MAX_VER_DIST"])
        self._fence_on = self.fence.fence.active
        self._c_rev = self.params.revision

    # ------------------------------------------------------------------ commander
    def _event(self, text: str) -> None:
        self._status.append(f"{self.clock.t:.3f} {text}")

    def _switch(self, mode: FlightMode) -> None:
        """Enter a mode (no checks)."""
        prev = self._mode
        self._mode = mode
        self._landing = False
        pos = self._ex[0:3]
        if mode in (FlightMode.HOLD, FlightMode.OFFBOARD) or mode in _MANUAL_MODES:
            self._hold_pos = pos.copy()
            self._man_hold_xy = None
            self._man_hold_z = None
        self._braking = mode in (FlightMode.HOLD, FlightMode.LAND)
        if self._braking:
            self._brake_t0 = self._brake_vmin_t = self.clock.t
            self._brake_vmin = math.inf
        if mode == FlightMode.LAND:
            self._land_xy = pos[0:2].copy()
            self._landing = True
        if mode == FlightMode.RTL:
            self._rtl_phase = "climb"
            self._rtl_xy = pos[0:2].copy()
            self._rtl_alt = max(-float(pos[2]), self.params["RTL_RETURN_ALT"])
            ceiling = self.fence.fence.max_ver
            if ceiling > 0.0:  # as PX4: the return never climbs through GF_MAX_VER_DIST
                self._rtl_alt = max(min(self._rtl_alt, ceiling - 2.0), min(2.0, ceiling))
        if mode == FlightMode.MISSION:
            self._item_started = False
        self._yaw_sp = self._yaw()
        if prev != mode:
            self._event(f"mode {prev.value} -> {mode.value}")

    def _yaw(self) -> float:
        w, x, y, z = self._x[6:10]
        return math.atan2(2.0 * (w * z + x * y), 1.0 - 2.0 * (y * y + z * z))

    def _commander(self, t: float) -> None:
        on_ground = self._aux[A_ON_GROUND] > 0.5
        if on_ground:
            if self._ground_since is None:
                self._ground_since = t
        else:
            self._ground_since = None
            if self._armed:
                self._flown = True
        if not self._armed:
            return
        # auto-disarm on the ground
        if on_ground:
            wait = self._disarm_land if self._flown else self._disarm_prflt
            since = max(self._ground_since, self._armed_at)
            if wait >= 0 and t - since >= wait + (self._land_trig if self._flown else 0.0):
                self._armed = False
                self._event("auto-disarmed on the ground")
                return
        # failsafes
        mode = self._mode
        if t >= self._next_battery_check:  # 1 Hz is plenty for a battery
            self._next_battery_check = t + 1.0
            self._battery_failsafe(mode, on_ground)
            mode = self._mode
        if mode == FlightMode.OFFBOARD and t - self._offboard_t > self._of_loss_t:
            self._event(offboard_lost_text(t - self._offboard_t, self._of_loss_t))
            self._switch(FlightMode.HOLD)
        elif mode in _MANUAL_MODES and t - self._manual_t > self._rc_loss_t:
            self._event("manual control lost -> hold")
            self._switch(FlightMode.HOLD)

    def _battery_failsafe(self, mode: FlightMode, on_ground: bool) -> None:
        """PX4 COM_LOW_BAT_ACT 3: critical → return, emergency → land where it is."""
        if on_ground:
            return
        rem = self.battery_remaining
        if rem <= self._bat_emergency and mode != FlightMode.LAND:
            self._event(f"battery {rem:.0%}: emergency -> land")
            self._switch(FlightMode.LAND)
            self._failsafe_action(f"battery {rem:.0%}: emergency land")
        elif rem <= self._bat_crit and mode not in (FlightMode.RTL, FlightMode.LAND):
            self._event(f"battery {rem:.0%}: critical -> return")
            self._switch(FlightMode.RTL)
            self._failsafe_action(f"battery {rem:.0%}: critical return")

    # ------------------------------------------------------------------ geofence
    def set_fence(self, shapes) -> None:
        """The fence uploaded over MAVLink (FenceShape list, [] clears it): enforced from now."""
        self.fence.configure(list(shapes or ()), self.params["GF_MAX_HOR_DIST"],
                             self.params["GF_MAX_VER_DIST"])  # fmt: skip
        self._fence_on = self.fence.fence.active
        n = len(self.fence.fence.areas)
        self._event(f"geofence: {n} area(s)" if n else "geofence: no areas")

    def fence_violation(self, pos_ned) -> str | None:
        """Why a target (3,) NED [m] is outside the vehicle's fence, or None."""
        return self.fence.fence.violation(pos_ned) if self._fence_on else None

    def _fence_check(self) -> None:
        """One breach sample on the estimated position; the GF_ACTION when a breach completes."""
        if not self._armed or self._aux[A_ON_GROUND] > 0.5:
            return
        why = self.fence.sample(self._ex[0:3], int(self.params["GF_COUNT"]))
        if why is None:
            return
        act = int(self.params["GF_ACTION"])
        self._event(f"geofence breach: {why} -> {ACTION_NAMES.get(act, act)}")
        mode = self._mode
        if act <= ACTION_NONE + 1 or mode == FlightMode.LAND:
            return  # none / warning only; a landing is never undone
        if act == ACTION_HOLD:
            if mode != FlightMode.RTL:
                self._switch(FlightMode.HOLD)
        elif act == ACTION_RTL:
            if mode != FlightMode.RTL:
                self._switch(FlightMode.RTL)
        else:  # 4 terminate (not simulated) and 5 land
            self._switch(FlightMode.LAND)
        self._failsafe_action(f"geofence breach: {why}")

    def _target_refusal(self, pos: np.ndarray) -> str | None:
        """Why the autopilot refuses to fly to pos (3,) NED, or None."""
        if not self._pos_valid:
            return "no position estimate"
        why = self.fence_violation(pos)
        return None if why is None else f"target outside geofence: {why}"

    def _mission_refusal(self, items: list[MissionItem]) -> str | None:
        """Why a mission cannot be flown inside the fence (TAKEOFF: its height, here)."""
        if not self._fence_on:
            return None
        for i, it in enumerate(items):
            if it.command == MissionCommand.RETURN_TO_LAUNCH:
                continue
            p = it.pos_ned
            if it.command == MissionCommand.TAKEOFF:
                p = (self._ex[0], self._ex[1], p[2])
            why = self.fence_violation(p)
            if why is not None:
                return f"item {i} outside geofence: {why}"
        return None

    def _landed_for(self, t: float) -> bool:
        return self._ground_since is not None and t - self._ground_since >= self._land_trig

    # ------------------------------------------------------------------ navigator
    def _navigate(self, t: float) -> None:
        mode = self._mode
        if mode == FlightMode.HOLD:
            if self._braking and not self._brake():
                self._hold_pos = self._ex[0:3].copy()
            if not self._braking:
                self._goto(self._hold_pos, self._vxy_cruise)
        elif mode == FlightMode.TAKEOFF:
            self._goto(self._takeoff_target, self._vxy_cruise, vz_up=self.params["MPC_TKO_SPEED"])
            if (
                abs(self._ex[2] - self._takeoff_target[2])
                < 0.1 * max(1.0, -self._takeoff_target[2])
                and abs(self._ex[5]) < 0.3
            ):
                self._switch(FlightMode.HOLD)
                self._hold_pos = self._takeoff_target.copy()
                self._braking = False
        elif mode == FlightMode.LAND:
            if self._braking and not self._brake(z=False):
                self._land_xy = self._ex[0:2].copy()
            self._descend(None if self._braking else self._land_xy)
        elif mode == FlightMode.RTL:
            self._rtl(t)
        elif mode == FlightMode.MISSION:
            self._mission(t)
        elif mode == FlightMode.OFFBOARD:
            self._offboard_nav()
        else:
            self._manual_nav(mode)

    def _shape(self, target, vxy: float, vz_up: float, vz_dn: float) -> None:
        """Move the reference one step toward target (module docstring) → sp position and
        velocity feed-forward. Restarts from the estimate when it was not used last step."""
        dt = self.control_dt
        t = self.clock.t
        r, rv, ra = self._ref, self._ref_v, self._ref_a
        if abs(t - self._ref_t - dt) > 1e-9:
            r[:] = self._ex[0:3]
            rv[:] = self._ex[3:6]
            ra[:] = 0.0
        self._ref_t = t
        a, j = self._acc_hor, self._jerk
        lag = a / j  # [s] the time the jerk limit needs to unwind a full acceleration
        dx, dy = target[0] - r[0] - rv[0] * lag, target[1] - r[1] - rv[1] * lag
        d = math.hypot(dx, dy)
        v = min(vxy, math.sqrt(2.0 * a * d), self._traj_p * d)
        wx, wy = (v * dx / d, v * dy / d) if d > 1e-9 else (0.0, 0.0)
        # acceleration toward the desired velocity (gain j/a: the jerk limit's own time
        # constant), at most a; the acceleration itself changes by at most j·dt
        k = j / a
        ax, ay = k * (wx - rv[0]), k * (wy - rv[1])
        n = math.hypot(ax, ay)
        if n > a:
            ax, ay = ax * a / n, ay * a / n
        jx, jy = ax - ra[0], ay - ra[1]
        n = math.hypot(jx, jy)
        if n > j * dt:
            jx, jy = jx * j * dt / n, jy * j * dt / n
        ra[0] += jx
        ra[1] += jy
        dz = target[2] - r[2]
        up = dz < 0.0
        az = self._acc_up if up else self._acc_dn
        dz -= rv[2] * az / j
        up = dz < 0.0
        vz = min(vz_up if up else vz_dn, math.sqrt(2.0 * az * abs(dz)), self._traj_pz * abs(dz))
        a_z = max(-az, min(az, (j / az) * ((-vz if up else vz) - rv[2])))
        ra[2] += max(-j * dt, min(j * dt, a_z - ra[2]))
        rv += ra * dt
        r += rv * dt
        sp = self._sp
        sp[0:3] = r
        # velocity feed-forward ṙ + r̈/K_v: the velocity loop's P term then gives r̈ itself
        c = self._c
        sp[3] = rv[0] + ra[0] / c[ctl.C_KV_XY]
        sp[4] = rv[1] + ra[1] / c[ctl.C_KV_XY]
        sp[5] = rv[2] + ra[2] / c[ctl.C_KV_Z]

    def _goto(self, pos: np.ndarray, vxy: float, vz_up: float | None = None) -> None:
        sp = self._sp
        if self._smooth:
            self._shape(pos, vxy, self._vz_up if vz_up is None else vz_up, self._vz_dn)
        else:
            sp[0:3] = pos
            sp[3:6] = 0.0
        sp[ctl.SP_XY_MODE] = ctl.XY_POS
        sp[ctl.SP_Z_MODE] = ctl.Z_POS
        sp[ctl.SP_YAW] = self._yaw_sp
        sp[ctl.SP_YAWRATE] = 0.0
        sp[ctl.SP_VXY_MAX] = vxy
        sp[ctl.SP_VZ_UP] = self._vz_up if vz_up is None else vz_up
        sp[ctl.SP_VZ_DN] = self._vz_dn

    def _brake(self, z: bool = True) -> bool:
        """PX4 brakes before it holds: zero velocity setpoint (horizontal, and vertical if z).
        Ends (False; the caller captures its position) on the brake rule of the module
        docstring: slower than BRAKE_SPEED, or no new speed minimum for BRAKE_STALL_S, or
        BRAKE_MAX_S of braking."""
        v = self._ex[3:6]
        vz = v[2] if z else 0.0
        speed = math.sqrt(v[0] * v[0] + v[1] * v[1] + vz * vz)
        t = self.clock.t
        if speed < self._brake_vmin - BRAKE_MIN_GAIN:
            self._brake_vmin, self._brake_vmin_t = speed, t
        self._braking = (
            speed > BRAKE_SPEED
            and t - self._brake_vmin_t < BRAKE_STALL_S
            and t - self._brake_t0 < BRAKE_MAX_S
        )
        if self._braking:
            sp = self._sp
            sp[0:3] = self._ex[0:3]
            sp[3:6] = 0.0
            sp[ctl.SP_XY_MODE] = ctl.XY_VEL
            sp[ctl.SP_Z_MODE] = ctl.Z_VEL if z else ctl.Z_POS
            sp[ctl.SP_YAW] = self._yaw_sp
            sp[ctl.SP_YAWRATE] = 0.0
            sp[ctl.SP_VXY_MAX] = self._vxy_max
            sp[ctl.SP_VZ_UP] = self._vz_up
            sp[ctl.SP_VZ_DN] = self._vz_dn
        return self._braking

    def _descend(self, xy: np.ndarray | None) -> None:
        """Hold xy (None: stop horizontally), sink at the land speed (faster high up)."""
        sp = self._sp
        self._landing = True
        if xy is None:
            sp[0:2] = self._ex[0:2]
        else:
            sp[0:2] = xy
        sp[2] = self._ex[2]
        sp[3:6] = 0.0
        h = -self._ex[2]
        v = self.params["MPC_LAND_SPEED"] if h < self.params["MPC_LAND_ALT1"] else self._vz_dn
        sp[5] = v
        sp[ctl.SP_XY_MODE] = ctl.XY_POS if xy is not None else ctl.XY_VEL
        sp[ctl.SP_Z_MODE] = ctl.Z_VEL
        sp[ctl.SP_YAW] = self._yaw_sp
        sp[ctl.SP_YAWRATE] = 0.0
        sp[ctl.SP_VXY_MAX] = self._vxy_cruise
        sp[ctl.SP_VZ_UP] = self._vz_up
        sp[ctl.SP_VZ_DN] = max(v, self._vz_dn)

    def _ground_idle_if_landed(self) -> None:
        """A landed vehicle whose setpoint does not ask to climb idles with level attitude."""
        if self._aux[A_ON_GROUND] < 0.5:
            return
        sp = self._sp
        zm = sp[ctl.SP_Z_MODE]
        wants_air = (
            (zm == ctl.Z_POS and sp[2] < _GROUND_Z)
            or (zm == ctl.Z_VEL and sp[5] < -0.1)
            or (zm == ctl.Z_THRUST and sp[ctl.SP_THRUST] > 0.0)
        )
        if not wants_air:
            sp[ctl.SP_XY_MODE] = ctl.XY_ATT
            sp[ctl.SP_Z_MODE] = ctl.Z_THRUST
            sp[ctl.SP_ROLL] = 0.0
            sp[ctl.SP_PITCH] = 0.0
            sp[ctl.SP_THRUST] = 0.0
            sp[ctl.SP_YAW] = self._yaw()
            sp[ctl.SP_YAWRATE] = 0.0
            self._landing = False

    def _offboard_nav(self) -> None:
        s = self._offboard
        sp = self._sp
        if s is None:
            self._goto(self._hold_pos, self._vxy_cruise)
            return
        if s.yaw is not None:
            self._yaw_sp = s.yaw
            sp[ctl.SP_YAWRATE] = 0.0
        elif s.yaw_rate is not None:
            self._yaw_sp = wrap_pi(self._yaw_sp + s.yaw_rate * self.control_dt)
            sp[ctl.SP_YAWRATE] = s.yaw_rate
        else:
            sp[ctl.SP_YAWRATE] = 0.0
        sp[ctl.SP_YAW] = self._yaw_sp
        sp[ctl.SP_VXY_MAX] = self._vxy_max
        sp[ctl.SP_VZ_UP] = self._vz_up
        sp[ctl.SP_VZ_DN] = self._vz_dn
        if s.pos_ned is not None:
            if self._smooth == 2 and s.vel_ned is None:
                self._shape(s.pos_ned, self._vxy_max, self._vz_up, self._vz_dn)
            else:
                sp[0:3] = s.pos_ned
                sp[3:6] = s.vel_ned if s.vel_ned is not None else 0.0
            sp[ctl.SP_XY_MODE] = ctl.XY_POS
            sp[ctl.SP_Z_MODE] = ctl.Z_POS
        else:
            sp[0:3] = self._ex[0:3]
            sp[3:6] = s.vel_ned
            sp[ctl.SP_XY_MODE] = ctl.XY_VEL
            sp[ctl.SP_Z_MODE] = ctl.Z_VEL

    def _rtl(self, t: float) -> None:
        pos = self._ex[0:3]
        if self._rtl_phase == "climb":
            self._goto(np.array([self._rtl_xy[0], self._rtl_xy[1], -self._rtl_alt]), 1.0)
            if -pos[2] >= self._rtl_alt - 1.0:
                self._rtl_phase = "return"
                self._event("rtl: return leg")
        elif self._rtl_phase == "return":
            self._goto(np.array([0.0, 0.0, -self._rtl_alt]), self._vxy_cruise)
            if math.hypot(pos[0], pos[1]) < 1.0 and math.hypot(self._ex[3], self._ex[4]) < 0.5:
                self._rtl_phase = "land"
                self._event("rtl: landing")
        else:
            self._descend(np.zeros(2))

    def _manual_nav(self, mode: FlightMode) -> None:
        x_st, y_st, z_st, r_st = self._manual
        P = self.params
        sp = self._sp
        dt = self.control_dt
        yaw_rate = r_st * math.radians(P["MPC_MAN_Y_MAX"])
        self._yaw_sp = wrap_pi(self._yaw_sp + yaw_rate * dt)
        sp[ctl.SP_YAW] = self._yaw_sp
        sp[ctl.SP_YAWRATE] = yaw_rate
        sp[ctl.SP_VXY_MAX] = P["MPC_VEL_MANUAL"]
        sp[ctl.SP_VZ_UP] = self._vz_up
        sp[ctl.SP_VZ_DN] = self._vz_dn
        sp[3:6] = 0.0
        pos = self._ex[0:3]
        tilt = math.radians(P["MPC_MAN_TILT_MAX"])
        # horizontal
        if mode == FlightMode.POSCTL:
            if abs(x_st) < 0.05 and abs(y_st) < 0.05:
                if self._man_hold_xy is None and math.hypot(self._ex[3], self._ex[4]) < 0.3:
                    self._man_hold_xy = pos[0:2].copy()  # stopped: hold here
                if self._man_hold_xy is None:
                    sp[ctl.SP_XY_MODE] = ctl.XY_VEL  # centred sticks: brake first
                else:
                    sp[0:2] = self._man_hold_xy
                    sp[ctl.SP_XY_MODE] = ctl.XY_POS
            else:
                self._man_hold_xy = None
                v = P["MPC_VEL_MANUAL"]
                c, s = math.cos(self._yaw_sp), math.sin(self._yaw_sp)
                sp[3] = v * (x_st * c - y_st * s)
                sp[4] = v * (x_st * s + y_st * c)
                sp[ctl.SP_XY_MODE] = ctl.XY_VEL
        else:
            sp[ctl.SP_ROLL] = y_st * tilt
            sp[ctl.SP_PITCH] = -x_st * tilt
            sp[ctl.SP_XY_MODE] = ctl.XY_ATT
        # vertical
        if mode in (FlightMode.POSCTL, FlightMode.ALTCTL):
            dz = z_st - 0.5
            if abs(dz) < 0.05:
                if self._man_hold_z is None and abs(self._ex[5]) < 0.2:
                    self._man_hold_z = float(pos[2])
                if self._man_hold_z is None:
                    sp[ctl.SP_Z_MODE] = ctl.Z_VEL
                else:
                    sp[2] = self._man_hold_z
                    sp[ctl.SP_Z_MODE] = ctl.Z_POS
            else:
                self._man_hold_z = None
                sp[5] = -2.0 * dz * (self._vz_up if dz > 0 else self._vz_dn)
                sp[ctl.SP_Z_MODE] = ctl.Z_VEL
        else:
            w, tmax = self._weight, P["MPC_THR_MAX"] * self._t_max
            thrust = 2.0 * z_st * w if z_st <= 0.5 else w + (z_st - 0.5) * 2.0 * (tmax - w)
            sp[ctl.SP_THRUST] = thrust
            sp[ctl.SP_Z_MODE] = ctl.Z_THRUST

    # ------------------------------------------------------------------ mission
    def _mission(self, t: float) -> None:
        pr = self._progress
        items = self._items
        pos = self._ex[0:3]
        if pr.finished or not items:
            self._goto(self._hold_pos, self._vxy_cruise)
            return
        item = items[pr.current]
        cmd = item.command
        if not self._item_started:
            self._item_started = True
            self._item_reached_at = None
            self._climb_first = False
            if cmd == MissionCommand.TAKEOFF:  # no height given (< 0.5 m): MIS_TAKEOFF_ALT
                z = item.pos_ned[2] if item.pos_ned[2] < -0.5 else -self.params["MIS_TAKEOFF_ALT"]
                self._target = np.array([pos[0], pos[1], z])
            elif cmd == MissionCommand.RETURN_TO_LAUNCH:
                self._mark_reached(pr.current)
                pr.finished = True
                self._switch(FlightMode.RTL)
                self._navigate(t)
                return
            else:
                self._target = np.asarray(item.pos_ned, dtype=float).copy()
                if cmd == MissionCommand.LAND:
                    self._target[2] = min(pos[2], self._target[2]) if pos[2] < -0.5 else pos[2]
                # from the ground, climb before going anywhere
                self._climb_first = pos[2] > -1.0 and cmd != MissionCommand.LAND
                self._climb_xy = pos[0:2].copy()
            if item.yaw is not None:
                self._yaw_sp = float(item.yaw)
        if self._climb_first:
            alt = min(self._target[2], -self.params["MIS_TAKEOFF_ALT"])
            climb = np.array([self._climb_xy[0], self._climb_xy[1], alt])
            self._goto(climb, self._vxy_cruise)
            if pos[2] - climb[2] < self.params["NAV_MC_ALT_RAD"]:
                self._climb_first = False
            return
        if cmd == MissionCommand.LAND:
            d = math.hypot(pos[0] - self._target[0], pos[1] - self._target[1])
            if self._landing or d < self._accept(item):
                self._descend(self._target[0:2])
                if self._landed_for(t):
                    self._mark_reached(pr.current)
                    pr.finished = True
                    self._hold_pos = pos.copy()
                    self._event("mission: landed, finished")
            else:
                self._goto(self._target, self._vxy_cruise)
            return
        self._goto(self._target, self._vxy_cruise)
        if self._item_reached_at is None:
            d = math.hypot(pos[0] - self._target[0], pos[1] - self._target[1])
            dz = abs(pos[2] - self._target[2])
            if (cmd == MissionCommand.TAKEOFF or d < self._accept(item)) and dz < self.params[
                "NAV_MC_ALT_RAD"
            ]:
                self._item_reached_at = t
                self._mark_reached(pr.current)
        if self._item_reached_at is not None:
            if cmd == MissionCommand.LOITER_UNLIM:
                return
            if t - self._item_reached_at >= item.hold_s:
                self._hold_pos = self._target.copy()
                if pr.current + 1 >= len(items):
                    pr.finished = True
                    self._event("mission finished")
                else:
                    pr.current += 1
                    self._item_started = False

    def _accept(self, item: MissionItem) -> float:
        return item.accept_radius if item.accept_radius > 0 else self.params["NAV_ACC_RAD"]

    def _mark_reached(self, seq: int) -> None:
        self._progress.reached.append(seq)
        self._event(f"mission item {seq} reached")

    # ------------------------------------------------------------------ requests
    def _state_valid(self) -> bool:
        return bool(np.all(np.isfinite(self._x)))

    def arm(self, force: bool = False) -> Result:
        if self._armed:
            return Result.accepted()
        if not self._state_valid():
            return Result.denied("vehicle state invalid")
        if not self.on_ground and not force:
            return Result.denied("not on the ground (use force to arm in the air)")
        if self.battery_remaining <= 0.0:
            return Result.denied("battery empty")
        if not (self._gps_fix and self._pos_valid):
            return Result.denied("no position estimate (GPS): arming refused")
        if not (math.isfinite(self.home.lat_deg) and math.isfinite(self.home.lon_deg)):
            return Result.denied("no home position: arming refused")
        why = self.fence_violation(self._ex[0:3])
        if why is not None and not force:
            return Result.denied(f"outside geofence ({why}): arming refused")
        self.fence.outside_count, self.fence.breached = 0, False
        self._failsafe_action("")
        self._armed = True
        self._armed_at = self.clock.t
        self._flown = not self.on_ground
        self._cs[:] = 0.0
        self._hold_pos = self._ex[0:3].copy()
        self._yaw_sp = self._yaw()
        self._item_started = False
        self._event("armed")
        return Result.accepted()

    def disarm(self, force: bool = False) -> Result:
        if not self._armed:
            return Result.accepted()
        if not self.on_ground and not force:
            return Result.denied("in the air (use force to disarm in flight)")
        self._armed = False
        self._event("disarmed" + (" (forced)" if force else ""))
        return Result.accepted()

    def _enter_mode(self, mode: FlightMode) -> Result:
        t = self.clock.t
        if mode == self._mode:
            return Result.accepted()
        if mode == FlightMode.OFFBOARD and (
            self._offboard is None or t - self._offboard_t > self.params["COM_OF_LOSS_T"]
        ):
            return Result.denied("no offboard setpoint stream: send setpoints first")
        if mode in _MANUAL_MODES and t - self._manual_t > self.params["COM_RC_LOSS_T"]:
            return Result.denied("no manual control input")
        if mode == FlightMode.MISSION and not self._items:
            return Result.denied("no mission uploaded")
        if mode == FlightMode.MISSION:
            why = self._mission_refusal(self._items)
            if why is not None or not self._pos_valid:
                return Result.denied(why or "no position estimate")
        if mode == FlightMode.TAKEOFF:
            return self.takeoff()
        if mode == FlightMode.RTL:
            return self.return_to_launch()
        self._switch(mode)
        return Result.accepted()

    def takeoff(self, altitude: float | None = None) -> Result:
        if altitude is None:
            altitude = self.params["MIS_TAKEOFF_ALT"]
        try:
            altitude = float(altitude)
        except (TypeError, ValueError):
            return Result.denied("takeoff altitude is not a number")
        if not math.isfinite(altitude) or not (0.5 <= altitude <= 1000.0):
            return Result.denied(f"takeoff altitude {altitude} m outside [0.5, 1000]")
        if not self._armed:
            return Result.denied("not armed: arm first")
        pos = self._ex[0:3]
        why = self._target_refusal(np.array([pos[0], pos[1], -altitude]))
        if why is not None:
            return Result.denied(f"takeoff: {why}")
        self._switch(FlightMode.TAKEOFF)
        self._takeoff_target = np.array([pos[0], pos[1], -altitude])
        return Result.accepted()

    def land(self) -> Result:
        self._switch(FlightMode.LAND)
        return Result.accepted()

    def return_to_launch(self) -> Result:
        if not self._armed or self.on_ground:
            return Result.denied("landed: nothing to return from")
        self._switch(FlightMode.RTL)
        return Result.accepted()

    def reposition(self, pos_ned: np.ndarray, yaw: float | None = None) -> Result:
        try:
            p = np.asarray(pos_ned, dtype=float).reshape(3)
        except (TypeError, ValueError):
            return Result.denied("position must be 3 numbers (NED m)")
        if not np.all(np.isfinite(p)) or np.any(np.abs(p) > _MAX_ABS_POS):
            return Result.denied("position not finite or out of range")
        if yaw is not None and not math.isfinite(yaw):
            return Result.denied("yaw not finite")
        if not self._armed:
            return Result.denied("not armed")
        why = self._target_refusal(p)
        if why is not None:
            return Result.denied(why)
        self._switch(FlightMode.HOLD)
        self._hold_pos = p.copy()
        self._braking = False
        if yaw is not None:
            self._yaw_sp = wrap_pi(float(yaw))
        return Result.accepted()

    def set_offboard_setpoint(self, setpoint: Setpoint) -> Result:
        if not isinstance(setpoint, Setpoint):
            return Result.denied("not a Setpoint")
        if setpoint.pos_ned is None and setpoint.vel_ned is None:
            return Result.denied("setpoint has neither position nor velocity")
        try:
            pos = _vec3(setpoint.pos_ned, _MAX_ABS_POS)
            vel = _vec3(setpoint.vel_ned, _MAX_ABS_VEL)
            yaw = None if setpoint.yaw is None else float(setpoint.yaw)
            rate = None if setpoint.yaw_rate is None else float(setpoint.yaw_rate)
        except (TypeError, ValueError) as e:
            return Result.denied(f"setpoint refused: {e}")
        if (yaw is not None and not abs(yaw) <= 100.0) or (
            rate is not None and not abs(rate) <= 100.0
        ):
            return Result.denied("setpoint refused: yaw or yaw rate not finite or out of range")
        if pos is not None and (self._fence_on or not self._pos_valid):
            why = self._target_refusal(pos)
            if why is not None:  # the last accepted setpoint stays; the stream ages
                self._refused += 1
                if self._refused in (1, 10, 100) or self._refused % 1000 == 0:
                    self._event(f"offboard setpoint refused ({self._refused}): {why}")
                return Result.denied(why)
        self._offboard = Setpoint(
            pos_ned=pos, vel_ned=vel, yaw=None if yaw is None else wrap_pi(yaw), yaw_rate=rate
        )
        self._offboard_t = self.clock.t
        return Result.accepted()

    def set_manual_control(self, x: float, y: float, z: float, r: float) -> Result:
        try:
            vals = [float(v) for v in (x, y, z, r)]
        except (TypeError, ValueError):
            return Result.denied("sticks must be numbers")
        if not all(math.isfinite(v) for v in vals):
            return Result.denied("sticks not finite")
        x, y, z, r = vals
        if max(abs(x), abs(y), abs(r)) > 1.0 + 1e-6 or not (-1e-6 <= z <= 1.0 + 1e-6):
            return Result.denied("sticks out of range: x, y, r in [-1, 1], z in [0, 1]")
        self._manual = (x, y, min(max(z, 0.0), 1.0), r)
        self._manual_t = self.clock.t
        return Result.accepted()

    def set_mission(self, items: list[MissionItem]) -> Result:
        try:
            items = list(items)
        except TypeError:
            return Result.denied("mission must be a list of MissionItem")
        for i, it in enumerate(items):
            if not isinstance(it, MissionItem) or not isinstance(it.command, MissionCommand):
                return Result.denied(f"item {i} is not a MissionItem")
            p = np.asarray(it.pos_ned, dtype=float)
            finite = (
                p.shape == (3,)
                and bool(np.all(np.isfinite(p)))
                and math.isfinite(it.hold_s)
                and math.isfinite(it.accept_radius)
                and (it.yaw is None or math.isfinite(it.yaw))
            )
            if not finite or np.any(np.abs(p) > _MAX_ABS_POS) or it.hold_s < 0:
                return Result.denied(f"item {i}: position/hold/radius not finite or out of range")
        why = self._mission_refusal(items)
        if why is not None:
            return Result.denied(why)
        self._items = items
        self._progress = MissionProgress()
        self._item_started = False
        if self._mode == FlightMode.MISSION and not items:
            self._switch(FlightMode.HOLD)
        return Result.accepted()

    def set_mission_current(self, seq: int) -> Result:
        if not (0 <= int(seq) < len(self._items)):
            return Result.denied(f"item {seq} not in mission of {len(self._items)}")
        self._progress.current = int(seq)
        self._progress.finished = False
        self._item_started = False
        return Result.accepted()
