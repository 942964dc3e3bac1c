"""A fixed-wing airframe simulated by JSBSim, seen through skyherd's frames.

JSBSim is loaded quietly (debug level 0, no banner) and only from the `jsbsim` wheel's own
data (the J3Cub ships in it) or from `flight/fixedwing/aircraft/` when a project aircraft
with that name exists there. Nothing is read from the working directory or FlightGear.

Frames: JSBSim's body axes are already FRD and its local frame is NED; positions come back
geodetic and are turned into NED about `home` through `flight.geo`, attitude into a
quaternion (w, x, y, z) body → NED. The runway is flat at the home altitude.

Surface command convention (ours, not JSBSim's, see `Surfaces`): positive aileron rolls
right, positive elevator pitches the nose up, positive rudder yaws the nose right. The
J3Cub's rudder and elevator properties have the opposite sign; the mapping lives in
`_apply` only.
"""

from __future__ import annotations

import math
import re
from dataclasses import dataclass, field
from pathlib import Path

import jsbsim
import numpy as np

from skyherd.flight.frames import euler_to_quat, wrap_pi
from skyherd.flight.geo import Home, geodetic_to_ned, ned_to_geodetic
from skyherd.flight.state import VehicleState

FT = 0.3048  # [m/ft]
KT = 0.514444  # [m/s per knot]
PROJECT_AIRCRAFT_DIR = Path(__file__).parent / "aircraft"


@dataclass(frozen=True)
class Surfaces:
    """Normalised actuator commands.

    aileron  [-1, 1]  + rolls right
    elevator [-1, 1]  + pitches nose up
    rudder   [-1, 1]  + yaws nose right (also steers the tail wheel on the ground)
    throttle [0, 1]
    brake    [0, 1]   both main wheels
    """

    aileron: float = 0.0
    elevator: float = 0.0
    rudder: float = 0.0
    throttle: float = 0.0
    brake: float = 0.0

    def clipped(self) -> Surfaces:
        """Clip to the ranges above; NaN becomes the neutral value (0)."""

        def c(v: float, lo: float, hi: float) -> float:
            return lo if not math.isfinite(v) else min(hi, max(lo, float(v)))

        return Surfaces(
            c(self.aileron, -1, 1) if math.isfinite(self.aileron) else 0.0,
            c(self.elevator, -1, 1) if math.isfinite(self.elevator) else 0.0,
            c(self.rudder, -1, 1) if math.isfinite(self.rudder) else 0.0,
            c(self.throttle, 0, 1) if math.isfinite(self.throttle) else 0.0,
            c(self.brake, 0, 1) if math.isfinite(self.brake) else 0.0,
        )


@dataclass(frozen=True)
class ModelParams:
    """Which aircraft and how JSBSim integrates it.

    aircraft    JSBSim model name (wheel's `aircraft/<name>` or project `aircraft/<name>`)
    physics_dt  [s] JSBSim integration step
    """

    aircraft: str = "J3Cub"
    physics_dt: float = 1.0 / 150.0


@dataclass
class JSBSimPlane:
    """One JSBSim aircraft on a flat field at `home`. Not thread-safe."""

    home: Home = field(default_factory=Home)
    params: ModelParams = field(default_factory=ModelParams)

    def __post_init__(self) -> None:
        if not (0.0 < self.params.physics_dt <= 0.05):
            raise ValueError(f"physics_dt must be in (0, 0.05] s, got {self.params.physics_dt}")
        if not re.fullmatch(r"[A-Za-z0-9_\-]+", self.params.aircraft):
            raise ValueError(f"aircraft name must be a plain name, got {self.params.aircraft!r}")
        jsbsim.FGJSBBase().debug_lvl = 0  # no banner, no trim chatter
        project = PROJECT_AIRCRAFT_DIR / self.params.aircraft
        root = Path(jsbsim.get_default_root_dir())
        fdm = jsbsim.FGFDMExec(str(root), None)
        fdm.set_debug_level(0)
        if project.is_dir():
            fdm.set_aircraft_path(str(PROJECT_AIRCRAFT_DIR))
        elif not (root / "aircraft" / self.params.aircraft).is_dir():
            raise ValueError(
                f"unknown aircraft {self.params.aircraft!r}: not in {PROJECT_AIRCRAFT_DIR} "
                f"nor in the jsbsim wheel"
            )
        if not fdm.load_model(self.params.aircraft):
            raise RuntimeError(f"JSBSim could not load {self.params.aircraft!r}")
        fdm.set_dt(self.params.physics_dt)
        self._fdm = fdm
        self._n_engines = fdm.get_propulsion().get_num_engines()
        self._t = 0.0
        self._surfaces = Surfaces()
        self._engine_on = False
        self.reset_on_ground()

    # ---- initial conditions ------------------------------------------------------------
    def _ic(self, pos_ned: np.ndarray, heading: float, airspeed: float, agl: float) -> None:
        lat, lon, _ = ned_to_geodetic(self.home, np.asarray(pos_ned, dtype=float))
        f = self._fdm
        f["ic/lat-geod-deg"] = lat
        f["ic/long-gc-deg"] = lon
        f["ic/terrain-elevation-ft"] = self.home.alt_m / FT
        f["ic/h-agl-ft"] = agl / FT
        f["ic/psi-true-deg"] = math.degrees(heading) % 360.0
        f["ic/vt-kts"] = airspeed / KT
        f["ic/gamma-deg"] = 0.0
        for w in ("north", "east", "down"):
            f[f"atmosphere/wind-{w}-fps"] = 0.0
        if not f.run_ic():
            raise RuntimeError("JSBSim rejected the initial conditions")
        self._t = 0.0

    def reset_on_ground(self, heading: float = 0.0, pos_ne: tuple[float, float] = (0, 0)) -> None:
        """Rest the aircraft on its wheels at `pos_ne` [m] about home, engine off, brakes on."""
        self._ic(np.array([pos_ne[0], pos_ne[1], 0.0]), heading, 0.0, 0.0)
        self.set_engine(False)
        self._surfaces = Surfaces(brake=1.0)
        self._apply(self._surfaces)
        for _ in range(int(4.0 / self.params.physics_dt)):  # settle on the gear
            self._fdm.run()
        self._t = 0.0
        self.ground_cg_height = self.agl  # [m] CG height above ground when resting

    def reset_airborne(
        self, altitude: float, airspeed: float, heading: float = 0.0, wind_ned=None
    ) -> Surfaces:
        """Level flight at `altitude` [m] above home, trimmed; returns the trim surfaces.

        With `wind_ned` (3,) [m/s] the aircraft starts trimmed *in the air mass*: the same
        airspeed, attitude and surfaces as the calm trim, its ground velocity the calm one +
        the wind (JSBSim's own trim does not converge with wind set, so the calm trim is moved
        with the air). Without it the start is exactly the calm one."""
        self._ic(np.array([0.0, 0.0, -altitude]), heading, airspeed, altitude)
        self.set_engine(True)
        trim = self.trim()
        w = np.zeros(3) if wind_ned is None else np.asarray(wind_ned, dtype=float)
        if w.shape != (3,) or not np.all(np.isfinite(w)):
            raise ValueError(f"wind must be 3 finite numbers [m/s], got {wind_ned!r}")
        if np.any(w):
            f = self._fdm
            theta = f["attitude/theta-deg"]
            v = self.state().vel_ned + w
            f["ic/vw-mag-fps"] = float(np.hypot(w[0], w[1])) / FT
            f["ic/vw-dir-deg"] = math.degrees(math.atan2(w[1], w[0]))
            f["ic/theta-deg"] = theta
            f["ic/vn-fps"], f["ic/ve-fps"], f["ic/vd-fps"] = (float(x) / FT for x in v)
            if not f.run_ic():
                raise RuntimeError("JSBSim rejected the initial conditions in wind")
            self.set_wind(w)
            self._apply(trim)
            self._t = 0.0
        return trim

    def trim(self) -> Surfaces:
        """JSBSim's full trim about the present condition; returns the trimmed commands."""
        f = self._fdm
        f["fcs/throttle-cmd-norm"] = 0.5
        try:
            f.do_trim(1)
        except jsbsim.TrimFailureError as e:  # keep flying the untrimmed state
            raise RuntimeError(f"JSBSim trim failed: {e}") from e
        # Fold the pitch trim into the elevator command, ours is the only channel.
        el = -(f["fcs/elevator-cmd-norm"] + f["fcs/pitch-trim-cmd-norm"])
        ail = f["fcs/aileron-cmd-norm"] + f["fcs/roll-trim-cmd-norm"]
        rud = -(f["fcs/rudder-cmd-norm"] + f["fcs/yaw-trim-cmd-norm"])
        for p in ("fcs/pitch-trim-cmd-norm", "fcs/roll-trim-cmd-norm", "fcs/yaw-trim-cmd-norm"):
            f[p] = 0.0
        s = Surfaces(ail, el, rud, f["fcs/throttle-cmd-norm"], 0.0)
        self._surfaces = s
        self._apply(s)
        return s

    # ---- commands ----------------------------------------------------------------------
    def set_engine(self, on: bool) -> None:
        """Start (instantly, no cranking) or stop the engine."""
        f = self._fdm
        if on:
            f["fcs/mixture-cmd-norm"] = 1.0
            f["propulsion/magneto_cmd"] = 3
            f["propulsion/set-running"] = -1
        else:
            f["fcs/mixture-cmd-norm"] = 0.0
            f["propulsion/magneto_cmd"] = 0
            # Not "propulsion/set-running" = 0: that *starts* engine 0 (its value is an index).
            for i in range(self._n_engines):
                f[f"propulsion/engine[{i}]/set-running"] = 0
            f["fcs/throttle-cmd-norm"] = 0.0
        self._engine_on = on

    def set_wind(self, wind_ned: np.ndarray) -> None:
        """Steady wind [m/s], NED (the direction the air moves *to*)."""
        w = np.asarray(wind_ned, dtype=float)
        if w.shape != (3,) or not np.all(np.isfinite(w)):
            raise ValueError(f"wind must be 3 finite numbers [m/s], got {wind_ned!r}")
        for name, v in zip(("north", "east", "down"), w):
            self._fdm[f"atmosphere/wind-{name}-fps"] = v / FT

    def _apply(self, s: Surfaces) -> None:
        f = self._fdm
        f["fcs/aileron-cmd-norm"] = s.aileron
        f["fcs/elevator-cmd-norm"] = -s.elevator
        f["fcs/rudder-cmd-norm"] = -s.rudder
        f["fcs/steer-cmd-norm"] = s.rudder
        f["fcs/throttle-cmd-norm"] = s.throttle if self._engine_on else 0.0
        f["fcs/left-brake-cmd-norm"] = s.brake
        f["fcs/right-brake-cmd-norm"] = s.brake

    def step(self, dt: float, surfaces: Surfaces) -> VehicleState:
        """Hold `surfaces` for `dt` [s] (a whole number of physics steps) and return the state."""
        n = round(dt / self.params.physics_dt)
        if n < 1 or abs(n * self.params.physics_dt - dt) > 1e-9 * max(1.0, dt):
            raise ValueError(f"dt={dt} is not a multiple of physics_dt={self.params.physics_dt}")
        self._surfaces = surfaces.clipped()
        self._apply(self._surfaces)
        f = self._fdm
        for _ in range(n):
            if not f.run():
                raise RuntimeError("JSBSim stopped")
        self._t += n * self.params.physics_dt
        return self.state()

    # ---- outputs -----------------------------------------------------------------------
    def state(self) -> VehicleState:
        """The present state in skyherd's frames (see module docstring).

        accel_frd is JSBSim's `a-pilot` specific force: an accelerometer at the model's
        eyepoint (about 0.6 m aft of the CG on the J3Cub), so it carries a small p, q, r term.
        """
        f = self._fdm
        pos = geodetic_to_ned(
            self.home,
            f["position/lat-geod-deg"],
            f["position/long-gc-deg"],
            f["position/h-sl-meters"],
        )
        vel = (
            np.array(
                [
                    f["velocities/v-north-fps"],
                    f["velocities/v-east-fps"],
                    f["velocities/v-down-fps"],
                ]
            )
            * FT
        )
        quat = euler_to_quat(
            f["attitude/phi-rad"], f["attitude/theta-rad"], wrap_pi(f["attitude/psi-rad"])
        )
        omega = np.array(
            [f["velocities/p-rad_sec"], f["velocities/q-rad_sec"], f["velocities/r-rad_sec"]]
        )
        acc = (
            np.array(
                [
                    f["accelerations/a-pilot-x-ft_sec2"],
                    f["accelerations/a-pilot-y-ft_sec2"],
                    f["accelerations/a-pilot-z-ft_sec2"],
                ]
            )
            * FT
        )
        return VehicleState(self._t, pos, vel, quat, omega, acc, self.wheels_down())

    def wheels_down(self) -> bool:
        """True while any landing-gear wheel touches the ground."""
        f = self._fdm
        return any(f[p] > 0.5 for p in ("gear/unit[0]/WOW", "gear/unit[1]/WOW", "gear/unit[2]/WOW"))

    @property
    def t(self) -> float:
        """Time since the last reset [s]."""
        return self._t

    @property
    def airspeed(self) -> float:
        """True airspeed [m/s]."""
        return self._fdm["velocities/vt-fps"] * FT

    @property
    def agl(self) -> float:
        """CG height above the (flat) ground [m]."""
        return self._fdm["position/h-agl-ft"] * FT

    @property
    def fuel_fraction(self) -> float:
        """Fuel left over capacity [0, 1] (the piston J3Cub's stand-in for a battery)."""
        f = self._fdm
        return min(1.0, max(0.0, float(f["propulsion/tank/pct-full"]) / 100.0))

    @property
    def surfaces(self) -> Surfaces:
        return self._surfaces

    def get_property(self, name: str) -> float:
        """Any JSBSim property (for tests and diagnostics)."""
        return float(self._fdm[name])
