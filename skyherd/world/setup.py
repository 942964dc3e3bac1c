"""What `skyherd sim` builds and runs, as one frozen record: `SimSetup` (each field named as its
command-line option), checked before anything starts, then opened into one world (world.build)
or a fleet (world.fleet) and run to its end (world.serve)."""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass

from skyherd.runio import ports
from skyherd.runio.constants import CAMERA_HZ, LOCKSTEP_LATENCY_S, LOOPBACK
from skyherd.world.build import WorldError, parse_home, parse_windows


@dataclass(frozen=True)
class SimSetup:
    """`skyherd sim`'s parameters, one field per option: its help is the field's comment or
    docstring (scripts.options)."""

    airframe: str = "quadrotor"
    """the vehicle: the quadrotor (downward camera) or the JSBSim fixed-wing (its camera on a
    pan-tilt gimbal pointed where a client sets the ROI: DO_SET_ROI_LOCATION)"""
    instance: int = 0  # MAVLink vehicle instance N (ports, system id 1+N)
    seed: int = 0  # seed of the vehicle, the UGV team and every random source
    ugvs: str = "composite"
    """UGV team: lateral, climb, descend, composite,
    groundsim:route|convoy|random|stopgo|speedoff|camouflage, flock (flees the UAV:
    groundsim/flock.py); none: the vehicle alone (no team, no camera, no Zenoh session)"""
    home: str | None = None
    """the vehicle's home [deg, deg, m AMSL] (default: the project's default home)"""
    ugv_start: str = "offboard"
    """when the UGVs start to drive: 'offboard' (when the vehicle is handed to the companion:
    OFFBOARD for the built-in vehicle; beside --follow or --autopilot, the companion's first
    decision on skyherd/<vehicle>/decision) or a simulation time [s] (default offboard)"""
    speedup: float | None = None  # None: flight.clock.default_speedup
    camera_hz: float = CAMERA_HZ
    """camera frames per simulated second (the companion's tick)"""
    free_run: bool = False  # do not wait for the companion (measure its lag instead)
    latency: float = LOCKSTEP_LATENCY_S
    """lockstep: the companion's declared compute latency [s of simulation time]"""
    duration: float | None = None
    """stop after this much simulation time [s] (default: until interrupted)"""
    zenoh_port: int | None = None  # None: the instance's
    zenoh_config: str | None = None
    """a Zenoh JSON5 configuration instead (e.g. a router for two hosts; docs/topology.md)"""
    bind: str = LOOPBACK  # address the MAVLink sockets bind to
    remote: str = LOOPBACK  # host the companion and the ground station listen on
    follow: str | None = None
    """no built-in vehicle: build the world (UGVs, camera) around the outside vehicle at this
    MAVLink address (a second link of PX4 / ArduPilot), free-running on its clock"""
    autopilot: str = "builtin"
    """builtin: skyherd's autopilot (default); px4 / ardupilot: a real one flies on skyherd's
    physics (PX4 none_iris on TCP 4560+N, ArduPilot --model JSON on UDP 9002+10N)"""
    pin_cpu: str = "auto"  # --autopilot ardupilot: the lockstep pair's CPU (runio.pin)
    follow_system: int = 0
    """with --follow: the followed autopilot's MAVLink system id (0: the first autopilot
    heard)"""
    param: tuple[str, ...] = ()
    """set a parameter of the built-in autopilot at start (repeatable), e.g. COM_OF_LOSS_T=3"""
    # the fault options (flight.faults.parse_fault_args):
    wind: str | None = None  # mean wind [m/s] from FROM degrees (270 = from the west); default calm
    gust: str | None = None  # gust std [m/s] and correlation time [s, default 2]; default none
    noise: str | None = None  # estimate noise std: position [m], velocity [m/s]; default none
    fault: tuple[str, ...] = ()
    """timed fault, repeatable: gps_glitch@30:20,0,0:5, gps_drift@30:0.5,0,0:20, gps_loss@30:10,
    baro@30:5:20, wind@40:16,90:10, battery@60:0.06, drain@10:300:60, disarm@25, rtl@25.02:0.05"""
    signing_key: str | None = None
    """MAVLink 2 signing key file (32 bytes): sign every frame, reject unsigned ones"""
    cut_link: tuple[str, ...] = ()
    """cut the companion's MAVLink link both ways at simulation time T [s] for D [s]
    (repeatable)"""
    cut_camera: tuple[str, ...] = ()  # stop the camera's frames at T [s] for D [s] (repeatable)
    fleet: str | None = None
    """several built-in vehicles in this one process (with --ugvs none): a JSON list of {"name":
    "uav0", "instance": N, "seed": S, "home": [LAT, LON, ALT]}; each writes into <run
    folder>/<name>/, each in lockstep with its own companion (docs/formation.md)"""

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
        try:
            from skyherd.flight.mavlink.keys import key_option
            from skyherd.runio.address import zenoh_config_file
            from skyherd.runio.pin import choose_cpu

            choose_cpu(s.pin_cpu, s.instance)
            if s.signing_key:
                key_option(s.signing_key)
            if s.zenoh_config is not None:
                zenoh_config_file(s.zenoh_config)
        except ValueError as e:  # SigningError, AddressError, --pin-cpu: one line naming the option
            raise WorldError(str(e)) from None
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
        """(world.params.WorldParams, flight.mavlink.config.EndpointConfig) of the vehicle: the
        records alone, not the simulator or the endpoint that run them."""
        from skyherd.flight.lockstep import LockstepParams
        from skyherd.flight.mavlink.config import EndpointConfig
        from skyherd.world.params import WorldParams

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
