"""The companion's links, opened: the autopilot's MAVLink link (`open_link`, with the next step
in words when it does not open), the camera's Zenoh session and its frames (`open_camera`), and
the decisions and the net's events published on that session for a recorder or a live view.
A link that cannot open is a runio.UsageError with a one-line reason (exit 2)."""

from __future__ import annotations

import dataclasses
import errno
import time
from pathlib import Path

from skyherd.runio import CsvWriter, UsageError
from skyherd.runio.constants import COMPANION_COMPONENT
from skyherd.runio.process import say


class GaveUp(Exception):
    """open_client stopped waiting: its `give_up()` said so (the simulator ended, a signal)."""


def open_client(p, patience_s: float = 60.0, give_up=None):
    """A Zenoh session that connects to a simulator which may not listen yet (a client's open
    fails at once when nothing answers): retried every 0.05 s of wall time for `patience_s`
    (a refused open costs about a millisecond), until `give_up()` is True (GaveUp then)."""
    from skyherd.perception.transport import open_session

    deadline = time.monotonic() + patience_s
    while True:
        try:
            return open_session(p)
        except ValueError:
            if time.monotonic() > deadline:
                raise
            if give_up is not None and give_up():
                raise GaveUp() from None
            time.sleep(0.05)


def open_frames(endpoint: str, config_file: str | None, key_file: str | None,
                vehicle: str = "uav0"):  # fmt: skip
    """(the Zenoh session, vehicle's FrameInbox): a client of the simulator's peer at the Zenoh
    `endpoint` (Zenoh routes between its clients: a recorder, a viewer), or as `config_file`
    says; with the flight's key file only authentic frames."""
    from skyherd.mission.companion import FrameInbox
    from skyherd.perception.transport import FrameSubscriber, ZenohParams, subscriber_params

    p = ZenohParams(config_file=config_file) if config_file else dataclasses.replace(
        subscriber_params(endpoint), mode="client")  # fmt: skip
    try:
        session = open_client(p)
    except ValueError as e:
        raise UsageError(f"{e}; check --zenoh-connect / --zenoh-config") from None
    key = None
    if key_file:  # the flight's key authenticates the frames too
        from skyherd.flight.mavlink.signing import SigningError, load_key

        try:
            key = load_key(key_file)
        except SigningError as e:
            session.close()
            raise UsageError(f"--signing-key: {e}") from None
    return session, FrameInbox(FrameSubscriber(session, vehicle, key=key))


def publish_live(session, mission, vehicle: str = "uav0", key: bytes | None = None) -> None:
    """Decisions on skyherd/<vehicle>/decision and the net's events on .../safety/event, so a
    recorder or a live view in another process sees them (record.ZenohRecorder); with the
    flight's key each carries its MAC (runio.mac)."""
    from skyherd.safety.events import Tee, ZenohEventSink

    mission.rec.live = session.declare_publisher(f"skyherd/{vehicle}/decision")
    mission.rec.live_key = key
    if mission.net is not None:
        mission.net.set_events(Tee(mission.net.events, ZenohEventSink(session, vehicle, key)))


def open_camera(mission, run_dir: Path, endpoint: str, config_file: str | None,
                key_file: str | None, flock: bool = False):  # fmt: skip
    """The mission's camera: (the Zenoh session, its frames, each logged to frames.csv); the
    mission's decisions published live, and with `flock` the shepherd's flock read on it."""
    from skyherd.mission.build import attach_flock
    from skyherd.mission.companion import LoggedFrames

    session, frames = open_frames(endpoint, config_file, key_file)
    publish_live(session, mission, key=frames.sub.key)
    if flock:
        attach_flock(session, mission, key=frames.sub.key)
    return session, LoggedFrames(frames, CsvWriter(run_dir / "frames.csv", LoggedFrames.COLUMNS))


def open_link(address: str, instance: int, tlog: Path, key_file: str | None,
              setup_signing: bool = False, session=None):  # fmt: skip
    """The companion's MAVLink link to the autopilot of `instance` (component 191), its frames
    in `tlog`; `setup_signing`: first give an outside autopilot the key (SETUP_SIGNING) until it
    answers signed. UsageError naming the next step when it does not open (`session`, the
    camera's, is closed then)."""
    from skyherd.hil.link import LinkError, MavlinkLink

    try:
        link = MavlinkLink.open(address, source_system=1 + instance, source_component=COMPANION_COMPONENT,
                                tlog=tlog, signing_key=key_file)  # fmt: skip
    except (LinkError, ValueError) as e:  # ValueError: flight.mavlink.signing.SigningError
        if session is not None:
            session.close()
        raise UsageError(link_error_text(e, address, instance)) from None
    if setup_signing:
        try:
            sent = link.provision_signing()
        except LinkError as e:
            link.close()
            if session is not None:
                session.close()
            raise UsageError(str(e)) from None
        say(f"skyherd companion: --setup-signing: the vehicle signs with our key "
            f"({sent} SETUP_SIGNING sent)")  # fmt: skip
    return link


def link_error_text(e: Exception, address: str, instance: int) -> str:
    """Why the autopilot's link did not open, in one line with the next step."""
    cause = e.__cause__
    if isinstance(cause, ConnectionRefusedError):
        return (f"nothing is listening at {address} (connection refused): start the autopilot "
                "first, or check --connect")  # fmt: skip
    if isinstance(cause, TimeoutError):
        return f"no answer from {address} (timed out): is the autopilot there? check --connect"
    if isinstance(cause, OSError) and cause.errno == errno.EADDRINUSE:
        return (f"{address}: the port is taken (another companion of instance {instance}, or a "
                "ground station?): stop it, or pick another --instance / --connect")  # fmt: skip
    if isinstance(e, ValueError):
        return f"--signing-key: {e}"
    return f"{e}; check --connect"
