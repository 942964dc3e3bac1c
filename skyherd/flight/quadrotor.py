"""Quadrotor rigid-body dynamics (6-DOF, X configuration), fixed-step and deterministic.

World NED, body FRD, quaternion (w, x, y, z) body → world. Ground is the plane down = 0
(home altitude). The hot path is a numba kernel over flat float arrays (quadrotor_kernels.py,
imported only by what steps them); `Quadrotor` is the readable wrapper.

Model (per physics step dt, default 1 ms; w = wind, NED):
  motors      ω̇_i = (ω_cmd,i − ω_i)/τ,  ω_cmd,i = u_i·ω_max         (exact discretisation)
  rotors      T_i = k_f ω_i²  along −z_b;   Q_i = s_i k_m ω_i²  about z_b (s_i = +1 CCW rotor)
  moments     M = Σ r_i × (0, 0, −T_i) + (0, 0, Σ Q_i)  → (−Σ y_i T_i, Σ x_i T_i, Σ Q_i)
  drag        F_d,b = −c₁ ⊙ v_b − c₂ ⊙ |v_b| ⊙ v_b,  v_b = Rᵀ (v − w)
  translation m v̇ = R (F_d,b + (0, 0, −ΣT_i)) + m g e_z
  rotation    I ω̇ = M − ω × I ω,   q̇ = ½ q ⊗ (0, ω)
Integration: v, p exact for constant acceleration over the step; ω explicit Euler; q rotated
by the mid-step rate (exact for constant angular acceleration about a fixed axis).
Ground: while resting (on_ground) and the net vertical force points down, the vehicle is
held: no velocity, no rotation, level attitude with its yaw kept. It lifts off as soon as
the thrust exceeds its weight. Touching down never bounces: the down velocity is removed.
"""

from __future__ import annotations

import math
import tomllib
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from skyherd.flight.geo import GRAVITY
from skyherd.flight.state import VehicleState
from skyherd.flight.wind import WindField, WindModel  # noqa: F401 - the wind the vehicle flies in

DEFAULT_AIRFRAME = Path(__file__).parent / "airframes" / "quadrotor_x.toml"

# ---- flat state vector x (17,)
X_POS, X_VEL, X_QUAT, X_OMEGA, X_MOTOR = 0, 3, 6, 10, 13
N_X = 17
# ---- auxiliary outputs aux (8,)
A_SPECIFIC = 0  # (3,) specific force, body FRD [m/s^2]
A_ON_GROUND = 3  # 1.0 while resting on the ground
A_THRUST = 4  # total rotor thrust [N]
A_SHAFT_POWER = 5  # total rotor shaft power [W]
A_ENERGY = 6  # shaft energy since start [J]
A_WIND = 7  # (3,) wind velocity [m/s], NED (input: set by the caller)
N_AUX = 10
# ---- physics parameters p (flat)
P_MASS, P_IXX, P_IYY, P_IZZ, P_KF, P_KM, P_WMAX, P_TAU = 0, 1, 2, 3, 4, 5, 6, 7
P_CLIN = 8  # (3,)
P_CQUAD = 11  # (3,)
P_G = 14
P_RX = 15  # (4,) rotor x [m]
P_RY = 19  # (4,) rotor y [m]
P_SPIN = 23  # (4,)
N_P = 27

_EXPECTED_UNITS = {
    ("body", "mass"): "kg",
    ("body", "inertia"): "kg m^2",
    ("body", "arm_length"): "m",
    ("rotor", "k_thrust"): "N s^2/rad^2",
    ("rotor", "k_torque"): "N m s^2/rad^2",
    ("rotor", "omega_max"): "rad/s",
    ("rotor", "time_constant"): "s",
    ("rotor", "spin"): "1",
    ("drag", "linear"): "N s/m",
    ("drag", "quadratic"): "N s^2/m^2",
    ("battery", "capacity"): "Wh",
    ("battery", "voltage_full"): "V",
    ("battery", "voltage_empty"): "V",
    ("battery", "efficiency"): "1",
    ("battery", "avionics_power"): "W",
    ("sim", "physics_dt"): "s",
}


@dataclass(frozen=True)
class QuadrotorParams:
    """Airframe constants (SI). Rotor order and geometry: PX4 quad X (see the airframe file)."""

    name: str = "quadrotor_x"
    mass: float = 1.5  # [kg]
    inertia: tuple[float, float, float] = (0.029, 0.029, 0.055)  # [kg m^2] Ixx, Iyy, Izz
    arm_length: float = 0.25  # [m]
    k_thrust: float = 6.61e-6  # [N s^2/rad^2]
    k_torque: float = 1.06e-7  # [N m s^2/rad^2]
    omega_max: float = 1100.0  # [rad/s]
    time_constant: float = 0.02  # [s]
    spin: tuple[float, float, float, float] = (1.0, 1.0, -1.0, -1.0)  # +1 CCW from above
    drag_linear: tuple[float, float, float] = (0.10, 0.10, 0.15)  # [N s/m]
    drag_quadratic: tuple[float, float, float] = (0.04, 0.04, 0.06)  # [N s^2/m^2]
    battery_capacity_wh: float = 74.0  # [Wh]
    voltage_full: float = 16.8  # [V]
    voltage_empty: float = 13.2  # [V]
    efficiency: float = 0.7  # [-]
    avionics_power: float = 5.0  # [W]
    physics_dt: float = 0.001  # [s]
    gravity: float = GRAVITY  # [m/s^2]

    @staticmethod
    def from_toml(path: Path | str = DEFAULT_AIRFRAME) -> QuadrotorParams:
        """Read an airframe file; ValueError on a missing key, wrong unit or bad number."""
        try:
            data = tomllib.loads(Path(path).read_text())
        except (OSError, tomllib.TOMLDecodeError) as e:
            raise ValueError(f"cannot read airframe file {path}: {e}") from e

        def get(section: str, key: str):
            try:
                entry = data[section][key]
                value, unit = entry["value"], entry["unit"]
            except (KeyError, TypeError) as e:
                raise ValueError(f"{path}: missing [{section}] {key} = {{value, unit}}") from e
            want = _EXPECTED_UNITS[(section, key)]
            if unit != want:
                raise ValueError(f"{path}: [{section}] {key} in {unit!r}, expected {want!r}")
            arr = np.asarray(value, dtype=float)
            if not np.all(np.isfinite(arr)):
                raise ValueError(f"{path}: [{section}] {key} not finite")
            return tuple(float(v) for v in arr) if arr.ndim else float(arr)

        p = QuadrotorParams(
            name=str(data.get("name", Path(path).stem)),
            mass=get("body", "mass"),
            inertia=get("body", "inertia"),
            arm_length=get("body", "arm_length"),
            k_thrust=get("rotor", "k_thrust"),
            k_torque=get("rotor", "k_torque"),
            omega_max=get("rotor", "omega_max"),
            time_constant=get("rotor", "time_constant"),
            spin=get("rotor", "spin"),
            drag_linear=get("drag", "linear"),
            drag_quadratic=get("drag", "quadratic"),
            battery_capacity_wh=get("battery", "capacity"),
            voltage_full=get("battery", "voltage_full"),
            voltage_empty=get("battery", "voltage_empty"),
            efficiency=get("battery", "efficiency"),
            avionics_power=get("battery", "avionics_power"),
            physics_dt=get("sim", "physics_dt"),
        )
        p.validate()
        return p

    def validate(self) -> None:
        if len(self.inertia) != 3 or len(self.spin) != 4:
            raise ValueError("inertia needs 3 values and spin 4")
        positive = [self.mass, *self.inertia, self.arm_length, self.k_thrust, self.omega_max]
        positive += [self.time_constant, self.battery_capacity_wh, self.efficiency]
        if min(positive) <= 0 or self.k_torque < 0:
            raise ValueError("airframe constants must be positive")
        if not (1e-4 <= self.physics_dt <= 0.002):
            raise ValueError(f"physics_dt {self.physics_dt} s: need 0.1..2 ms (>= 500 Hz)")

    # ---- derived
    @property
    def rotor_xy(self) -> np.ndarray:
        """(4, 2) rotor positions x forward, y right [m], PX4 order."""
        a = self.arm_length / math.sqrt(2.0)
        return np.array([[a, a], [-a, -a], [a, -a], [-a, a]])

    @property
    def max_thrust(self) -> float:
        """Thrust of one rotor at full command [N]."""
        return self.k_thrust * self.omega_max**2

    @property
    def hover_command(self) -> float:
        """Motor command that holds the weight with four equal rotors [-]."""
        return math.sqrt(self.mass * self.gravity / (4.0 * self.k_thrust)) / self.omega_max

    def to_array(self) -> np.ndarray:
        p = np.zeros(N_P)
        p[P_MASS] = self.mass
        p[P_IXX : P_IZZ + 1] = self.inertia
        p[P_KF], p[P_KM], p[P_WMAX], p[P_TAU] = (
            self.k_thrust,
            self.k_torque,
            self.omega_max,
            self.time_constant,
        )
        p[P_CLIN : P_CLIN + 3] = self.drag_linear
        p[P_CQUAD : P_CQUAD + 3] = self.drag_quadratic
        p[P_G] = self.gravity
        xy = self.rotor_xy
        p[P_RX : P_RX + 4] = xy[:, 0]
        p[P_RY : P_RY + 4] = xy[:, 1]
        p[P_SPIN : P_SPIN + 4] = self.spin
        return p


# =====================================================================================
# readable wrapper
# =====================================================================================


@dataclass
class Quadrotor:
    """The vehicle alone: `step(dt, motor_cmd)` → VehicleState. Time is kept here in µs.

    motor_cmd (4,) normalised [0, 1], PX4 quad-X order; NaN (or None) counts as 0, values
    outside [0, 1] are clipped; a wrong shape or non-numbers raise ValueError. `dt` is split into substeps of at most `params.physics_dt`.
    """

    params: QuadrotorParams = field(default_factory=QuadrotorParams)
    time_us: int = 0

    def __post_init__(self) -> None:
        self.params.validate()
        self.p = self.params.to_array()
        self.x = np.zeros(N_X)
        self.aux = np.zeros(N_AUX)
        self._u = np.zeros(4)
        self.reset()

    def reset(
        self,
        pos_ned=(0.0, 0.0, 0.0),
        vel_ned=(0.0, 0.0, 0.0),
        quat=(1.0, 0.0, 0.0, 0.0),
        omega_frd=(0.0, 0.0, 0.0),
        motor_speed=(0.0, 0.0, 0.0, 0.0),
    ) -> None:
        """Put the vehicle somewhere. On the ground (down >= 0, at rest) it starts landed."""
        q = np.asarray(quat, dtype=float)
        vals = np.concatenate([pos_ned, vel_ned, q / np.linalg.norm(q), omega_frd, motor_speed])
        if vals.shape != (N_X,) or not np.all(np.isfinite(vals)):
            raise ValueError("reset needs finite pos(3), vel(3), quat(4), omega(3), motors(4)")
        self.x[:] = vals
        wind = self.aux[A_WIND : A_WIND + 3].copy()
        self.aux[:] = 0.0
        self.aux[A_WIND : A_WIND + 3] = wind
        if self.x[X_POS + 2] >= 0.0:
            self.x[X_POS + 2] = 0.0
            self.aux[A_ON_GROUND] = 1.0
            self.x[X_VEL : X_VEL + 3] = 0.0
            self.x[X_OMEGA : X_OMEGA + 3] = 0.0
            from skyherd.flight.quadrotor_kernels import _level_with_yaw

            _level_with_yaw(self.x)
        self.aux[A_SPECIFIC + 2] = -self.params.gravity

    @property
    def t(self) -> float:
        return self.time_us * 1e-6

    @property
    def wind_ned(self) -> np.ndarray:
        """(3,) wind velocity [m/s], NED."""
        return self.aux[A_WIND : A_WIND + 3].copy()

    @wind_ned.setter
    def wind_ned(self, w) -> None:
        w = np.asarray(w, dtype=float).reshape(3)
        if not np.all(np.isfinite(w)):
            raise ValueError("wind must be finite")
        self.aux[A_WIND : A_WIND + 3] = w

    @property
    def on_ground(self) -> bool:
        return self.aux[A_ON_GROUND] > 0.5

    @property
    def motor_speed(self) -> np.ndarray:
        """(4,) rotor speeds [rad/s]."""
        return self.x[X_MOTOR:].copy()

    @property
    def thrust(self) -> float:
        """Total rotor thrust [N]."""
        return float(self.aux[A_THRUST])

    @property
    def energy_j(self) -> float:
        """Rotor shaft energy since reset [J]."""
        return float(self.aux[A_ENERGY])

    def substeps(self, dt: float) -> tuple[int, float]:
        n = max(1, math.ceil(dt / self.params.physics_dt - 1e-9))
        return n, dt / n

    def step(self, dt: float, motor_cmd: np.ndarray) -> VehicleState:
        """Advance by dt [s] with motor commands (4,) held constant."""
        if not (dt > 0 and math.isfinite(dt)):
            raise ValueError(f"dt must be positive and finite, got {dt}")
        u = self._u
        u[:] = motor_cmd  # (4,); NaN → 0 and clipping happen in the kernel
        n, h = self.substeps(dt)
        from skyherd.flight.quadrotor_kernels import physics_steps  # numba: imported when flown

        physics_steps(self.x, self.aux, self.p, u, h, n)
        self.time_us += round(dt * 1e6)
        return self.state()

    def state(self) -> VehicleState:
        x = self.x.copy()
        return VehicleState(
            t=self.time_us * 1e-6,
            pos_ned=x[0:3],
            vel_ned=x[3:6],
            quat=x[6:10],
            omega_frd=x[10:13],
            accel_frd=self.aux[0:3].copy(),
            on_ground=bool(self.aux[A_ON_GROUND] > 0.5),
        )
