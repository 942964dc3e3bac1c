"""What `skyherd sim` builds and runs, as one frozen record: `SimSetup` (each field named as its
command-line option), checked before anything starts, then opened into one world (world.build)
or a fleet (world.fleet) and run to its end (world.serve)."""

from __future__ import annotations

import dataclasses
import math
import os
from dataclasses import dataclass

from skyherd.runio import ports
from skyherd.runio.constants import CAMERA_HZ, LOCKSTEP_LATENCY_S, LOOPBACK
from skyherd.world.build import WorldError, parse_home, parse_windows


@dataclass(frozen=True)
class SimSetup:
    """`skyherd sim`'s parameters (docs: `skyherd sim --help`, one field per option)."""

    airframe: str = "quadrotor"
    instance: int = 0
    seed: int = 0
    ugvs: str = "composite"  # the UGV team's scenario, or "none"
    home: str | None = None  # LAT,LON,ALT (None: the default home)
    ugv_start: str = "offboard"
    speedup: float | None = None  # None: flight.clock.default_speedup
    camera_hz: float = CAMERA_HZ
    free_run: bool = False
    latency: float = LOCKSTEP_LATENCY_S  # [s of simulation time]
    duration: float | None = None  # [s of simulation time]; None: until stopped
    zenoh_port: int | None = None  # None: the instance's
    zenoh_config: str | None = None
    bind: str = LOOPBACK
    remote: str = LOOPBACK
    follow: str | None = None  # the outside vehicle's MAVLink address
    autopilot: str = "builtin"  # builtin | px4 | ardupilot
    follow_system: int = 0
    param: tuple[str, ...] = ()  # NAME=VALUE of the built-in autopilot
    wind: str | None = None  # the fault options (flight.faults.parse_fault_args)
    gust: str | None = None
    noise: str | None = None
    fault: tuple[str, ...] = ()
    signing_key: str | None = None
    cut_link: tuple[str, ...] = ()  # T:D
    cut_camera: tuple[str, ...] = ()  # T:D
    fleet: str | None = None  # a fleet file (world.fleet)

    @classmethod
    def of(cls, options) -> SimSetup:
        """The setup from any object with the options as attributes (an argparse namespace)."""
        values = {f.name: getattr(options, f.name) for f in dataclasses.fields(cls)}
        return cls(**{k: tuple(v) if isinstance(v, list) else v for k, v in values.items()})

    @property
    def builtin(self) -> bool:
        """The built-in vehicle (neither followed nor a real autopilot on our physics)."""
        return not self.follow and self.autopilot == "builtin"

    def checked(self) -> SimSetup:
        """This setup with the instance's Zenoh port and the speed-up's default filled in, once
        every check that needs nothing started passed: the instance and its ports, the world's
        parameters, the faults, the autopilot's parameters, the signing key, the fleet file.
        WorldError (one line, naming the option) otherwise."""
        try:
            port = ports.checked_zenoh_port(self.instance, self.zenoh_port)
        except ValueError as e:
            raise WorldError(str(e)) from None
        for flag, value, low in (("--latency", self.latency, 0.0), ("--camera-hz", self.camera_hz, None),
                                 ("--duration", self.duration, None)):  # fmt: skip
            if value is not None and not (
                math.isfinite(value) and (value >= low if low is not None else value > 0)
            ):
                raise WorldError(f"{flag} {value:g}: must be a finite number {'>= 0' if low is not None else '> 0'}")  # fmt: skip
        s = dataclasses.replace(self, zenoh_port=port, speedup=self._speedup())
        s.world_params()
        s.faults()
        if s.builtin:
            from skyherd.flight.airframes_registry import param_store
            from skyherd.flight.params import check_assignments

            check_assignments(param_store(s.airframe), s.param, s.airframe)
        if s.signing_key:
            from skyherd.flight.mavlink.signing import SigningError, load_key

            try:
                load_key(s.signing_key)
            except SigningError as e:
                raise WorldError(f"--signing-key: {e}") from None
        if s.zenoh_config is not None and not os.path.isfile(s.zenoh_config):
            raise WorldError(
                f"--zenoh-config {s.zenoh_config}: no such file; pass a Zenoh JSON5 file"
            )
        if s.fleet:
            s.read_fleet()
        return s

    def _speedup(self) -> float:
        """The team's checks, then the speed-up (its default) checked."""
        from skyherd.flight.clock import default_speedup
        from skyherd.task.scenarios import FLOCK, TEAMS

        if self.ugvs not in TEAMS + ("none",):
            raise WorldError(
                f"--ugvs {self.ugvs!r} is not a team: use one of " + ", ".join(TEAMS) + " or none"
            )
        if self.ugvs == FLOCK and (not self.builtin or self.fleet):
            raise WorldError(
                "--ugvs flock flees the built-in vehicle only: drop --follow, --autopilot, --fleet"
            )
        if self.ugvs == "none" and (not self.builtin or self.cut_camera):
            raise WorldError(
                "--ugvs none is the built-in vehicle alone: drop --follow, --autopilot, --cut-camera"
            )
        speedup = default_speedup(self.speedup, self.free_run)
        if not (speedup == 0 or speedup >= 1):
            raise WorldError("--speedup must be 0 (as fast as possible) or >= 1")
        if self.free_run and speedup == 0:
            raise WorldError(
                "--free-run needs a pacer: give --speedup >= 1 (a free-running companion cannot keep up with 0)"
            )
        return speedup

    def world_params(self):
        """(world.sim.WorldParams, flight.mavlink.EndpointConfig) of the vehicle."""
        from skyherd.flight.lockstep import LockstepParams
        from skyherd.flight.mavlink import EndpointConfig
        from skyherd.world.sim import WorldParams

        try:
            params = WorldParams(
                airframe=self.airframe, instance=self.instance, seed=self.seed, scenario=self.ugvs,
                camera_hz=self.camera_hz, ugv_start=self.ugv_start, lockstep=not self.free_run,
                lockstep_params=LockstepParams(latency_s=self.latency), speedup=self.speedup,
                link_cuts=parse_windows(self.cut_link, "--cut-link"),
                camera_losses=parse_windows(self.cut_camera, "--cut-camera"),
                home=parse_home(self.home), camera="roi" if self.airframe == "fixedwing" else "down",
            )  # fmt: skip
            endpoint = EndpointConfig(instance=self.instance, bind_host=self.bind,
                                      remote_host=self.remote, signing_key=self.signing_key)  # fmt: skip
        except WorldError:
            raise
        except ValueError as e:
            raise WorldError(str(e)) from None
        return params, endpoint

    def faults(self, seed: int | None = None):
        """The fault plan of the fault options for `seed` (default: the setup's); None: calm
        air, a perfect state estimate."""
        from skyherd.flight.faults import parse_fault_args

        if not (self.wind or self.gust or self.noise or self.fault):
            return None
        try:
            return parse_fault_args(self.wind, self.gust, self.noise, list(self.fault),
                                    seed=self.seed if seed is None else seed)  # fmt: skip
        except ValueError as e:
            raise WorldError(str(e)) from None

    def read_fleet(self) -> list:
        """The fleet file (world.fleet.read_fleet), checked with the options it flies with."""
        from skyherd.world.fleet import read_fleet

        if self.ugvs != "none":
            raise WorldError("--fleet flies built-in vehicles alone: add --ugvs none")
        if not self.builtin or self.airframe != "quadrotor" or self.param or self.cut_link:
            raise WorldError("--fleet: built-in quadrotors only; drop --follow, --autopilot, --airframe, "
                             "--param, --cut-link (or run one `skyherd sim` per vehicle)")  # fmt: skip
        try:
            return read_fleet(self.fleet)
        except ValueError as e:
            raise WorldError(str(e)) from None
