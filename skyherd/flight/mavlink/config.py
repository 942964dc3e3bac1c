"""The vehicle's MAVLink endpoint's configuration (`EndpointConfig`) and the personality it
presents (`Personality`), apart from the endpoint itself (flight.mavlink.endpoint) so that what
only checks or records them (`skyherd fly`'s checks of the simulator's arguments,
world.setup.SimSetup.world_params) imports neither the endpoint nor pymavlink's dialect.
"""

from __future__ import annotations

import enum
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING

from skyherd.runio import ports

if TYPE_CHECKING:
    from skyherd.flight.mavlink.link import Address

# Port layout (CONVENTIONS.md, contract): for instance N.
API_BIND_PORT, API_REMOTE_PORT = ports.API_BIND_BASE, ports.API_REMOTE_BASE
GCS_BIND_PORT, GCS_REMOTE_PORT = ports.GCS_BIND_BASE, ports.GCS_REMOTE_PORT


class Personality(enum.Enum):
    """How the vehicle presents itself: `px4` (MAV_AUTOPILOT_PX4) or `ardupilot`."""

    PX4 = "px4"
    ARDUPILOT = "ardupilot"

    @property
    def mav_autopilot(self) -> int:
        from pymavlink.dialects.v20 import ardupilotmega as mavlink

        if self is Personality.PX4:
            return mavlink.MAV_AUTOPILOT_PX4
        return mavlink.MAV_AUTOPILOT_ARDUPILOTMEGA


@dataclass(frozen=True)
class EndpointConfig:
    """Where and how the endpoint talks.

    instance      vehicle instance N: system id 1+N, ports offset by N
    personality   PX4 custom modes (default) or ArduCopter mode numbers
    bind_host     address both sockets bind to (127.0.0.1 unless opted out)
    remote_host   where the default peers (MAVSDK, the ground station: runio/ports.py) listen
    state_dir     parameter persistence root (None: parameters are not saved)
    tlog          write every frame in and out to this .tlog file (None: no log)
    signing_key   MAVLink 2 signing key file (32 bytes): signing on from the start. None:
                  the vehicle's own key file (`key_file`) if a SETUP_SIGNING stored one
    """

    instance: int = 0
    personality: Personality = Personality.PX4
    bind_host: str = "127.0.0.1"
    remote_host: str = "127.0.0.1"
    state_dir: Path | None = None
    tlog: Path | None = None
    params_per_update: int = 40
    signing_key: Path | None = None

    def __post_init__(self) -> None:
        ports.check_instance(self.instance, "instance")

    @property
    def system_id(self) -> int:
        return 1 + self.instance

    @property
    def api_bind(self) -> Address:
        return (self.bind_host, API_BIND_PORT + self.instance)

    @property
    def api_remote(self) -> Address:
        return (self.remote_host, API_REMOTE_PORT + self.instance)

    @property
    def gcs_bind(self) -> Address:
        return (self.bind_host, GCS_BIND_PORT + self.instance)

    @property
    def gcs_remote(self) -> Address:
        return (self.remote_host, GCS_REMOTE_PORT)

    def param_file(self, airframe: str) -> Path | None:
        if self.state_dir is None:
            return None
        return Path(self.state_dir) / f"{airframe}-{self.instance}" / "params.json"

    def key_file(self, airframe: str) -> Path | None:
        """Where SETUP_SIGNING stores this vehicle's key (None: kept in memory only)."""
        if self.state_dir is None:
            return None
        return Path(self.state_dir) / f"{airframe}-{self.instance}" / "signing.key"
