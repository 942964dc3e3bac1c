"""The vehicle's MAVLink endpoint: two UDP links, telemetry streams and protocol services.

`update()` is called by the SITL runner once per autopilot step (lockstep): it reads every
waiting datagram, answers it, finishes timed protocol work and sends the streams that are
due. Nothing here runs on its own thread and nothing reads the wall clock except the tlog
timestamps and the MAVLink 2 signing timestamps (wall time by the spec; flight.mavlink.signing).
Hostile input stays bounded: parameter lists and command retries are per-requester tables of
fixed size, one mission upload runs at a time, HEARTBEAT cannot be stopped by a client, and a
tlog that cannot be written stops logging, never the vehicle.
"""

from __future__ import annotations

import logging
import math
import select
from collections import Counter
from collections.abc import Callable
from pathlib import Path

from pymavlink.dialects.v20 import ardupilotmega as mavlink

from skyherd.flight.autopilot_api import Autopilot
from skyherd.flight.mavlink.commands import Cmd, CommandService, mode_source, refusal_result
from skyherd.flight.mavlink.config import EndpointConfig
from skyherd.flight.mavlink.link import Address, UdpLink
from skyherd.flight.mavlink.mission import MISSION, FenceShape, MissionService
from skyherd.flight.mavlink.modes import mode_of_packed
from skyherd.flight.mavlink.offboard import (
    SetpointError,
    manual_from_msg,
    setpoint_from_global,
    setpoint_from_local,
)
from skyherd.flight.mavlink.params import ParamFile, ParamService
from skyherd.flight.mavlink.payload import Payload
from skyherd.flight.mavlink.signing import Signing, load_key, save_key
from skyherd.flight.mavlink.statustext import split_text
from skyherd.flight.mavlink.streams import GCS_RATES_HZ, StreamScheduler
from skyherd.flight.mavlink.telemetry import Identity, TelemetryBuilder
from skyherd.flight.mavlink.tlog import TlogWriter

M = mavlink
log = logging.getLogger(__name__)

COMPONENT_ID = M.MAV_COMP_ID_AUTOPILOT1
_NEVER_US = 1 << 62  # a due time no simulation reaches [us]
DEFAULT_CONFIG = EndpointConfig()  # flight.mavlink.config
MAV_TYPES = {"quadrotor": M.MAV_TYPE_QUADROTOR, "fixedwing": M.MAV_TYPE_FIXED_WING}


class MavlinkEndpoint:
    """MAVLink 2 endpoint of one simulated vehicle (API link and ground-station link)."""

    def __init__(
        self,
        autopilot: Autopilot,
        config: EndpointConfig = DEFAULT_CONFIG,
        on_fence: Callable[[list[FenceShape]], None] | None = None,
    ):
        self.ap = autopilot
        self.config = config
        self.ident = Identity(
            config.system_id,
            COMPONENT_ID,
            config.personality,
            MAV_TYPES.get(autopilot.airframe, M.MAV_TYPE_GENERIC),
        )
        self.mav = M.MAVLink(None, config.system_id, COMPONENT_ID)  # message builder
        self.stats: Counter[str] = Counter()
        self.rx_types: Counter[str] = Counter()  # valid frames addressed to us, by type
        self.rx_commands: Counter[int] = Counter()  # commands received, by MAV_CMD
        self.signing = Signing(self._initial_key())  # raises SigningError on a bad key file
        self._tlog = (
            TlogWriter(config.tlog, autopilot.clock, flush_interval_s=0.5) if config.tlog else None
        )
        self._tlog_warned = False  # the tlog's failure was announced on STATUSTEXT
        self._text_id = 0  # id of the last chunked STATUSTEXT
        hook = (lambda _direction, frame: self._tlog.write(frame)) if self._tlog else None
        self.links: list[UdpLink] = []
        try:
            self.api = UdpLink(
                "api", config.api_bind, config.api_remote, config.system_id, COMPONENT_ID, hook,
                self.signing, link_id=0,
            )  # fmt: skip
            self.links.append(self.api)
            self.gcs = UdpLink(  # streams only heartbeats while no ground station listens
                "gcs", config.gcs_bind, config.gcs_remote, config.system_id, COMPONENT_ID, hook,
                self.signing, link_id=1, watch_remote=True,
            )  # fmt: skip
            self.links.append(self.gcs)
        except OSError:
            self.close()
            raise
        for link in self.links:  # a step's frames leave together, one system call per link
            link.coalesce = True  # and step (update() flushes them; a gate flushes its link)
        self.streams = {link.name: StreamScheduler(GCS_RATES_HZ if link is self.gcs else None,
                                                   self._streams_changed)
                        for link in self.links}  # fmt: skip
        self._streams_due_us = -1  # no stream is due before this simulation time [us]
        self._clock = autopilot.clock
        self._serving = False  # commands, missions or parameters have timed work (`_serve`)
        self._poller = select.poll() if hasattr(select, "poll") else None
        if self._poller is not None:
            for link in self.links:
                self._poller.register(link.sock.fileno(), select.POLLIN)
        self.last_heard: dict[str, float] = {}  # link name → sim time of the last valid frame
        self.last_setpoint_t: float | None = None  # sim time of the last accepted setpoint [s]
        self.telemetry = TelemetryBuilder(autopilot, self.ident)
        for sched in self.streams.values():  # streams only what this autopilot provides
            for msg_id in [m for m in sched.defaults if not self.telemetry.can_build(m)]:
                sched.drop(msg_id)
        pf = config.param_file(autopilot.airframe)
        self.params = ParamService(
            autopilot, self.mav, ParamFile(pf) if pf else None, self.broadcast, self.statustext,
            config.params_per_update,
        )  # fmt: skip
        if on_fence is None:  # the vehicle enforces its own uploaded fence (issue 11.3)
            on_fence = getattr(autopilot, "set_fence", None)
        self.missions = MissionService(autopilot, self.mav, self.statustext, on_fence)
        self.commands = CommandService(
            autopilot,
            self.mav,
            config.personality,
            self.statustext,
            self._request_message,
            lambda link, msg_id, interval: self.streams[link.name].set_interval(msg_id, interval),
            lambda link, msg_id: self.streams[link.name].interval_us(msg_id),
            lambda: len(self.missions.lists[MISSION]),
        )
        self.telemetry.mode_requests = self.commands  # ArduPilot: what the heartbeat shows
        self._sent_current: int | None = None
        self._drain_status = getattr(autopilot, "drain_status", None)
        self.gated: set[str] = set()  # links a lockstep gate reads instead of update()
        self._handlers = {
            "HEARTBEAT": self._on_heartbeat,
            "COMMAND_LONG": lambda m, r, k, link: self._on_command(Cmd.from_long(m), r, link),
            "COMMAND_INT": lambda m, r, k, link: self._on_command(Cmd.from_int(m), r, link),
            "SET_MODE": self._on_set_mode,
            "PARAM_REQUEST_LIST": lambda m, r, k, link: self.params.request_list(r, k),
            "PARAM_REQUEST_READ": lambda m, r, k, link: self.params.request_read(m, r),
            "PARAM_SET": lambda m, r, k, link: self.params.set(m, r),
            "MISSION_COUNT": lambda m, r, k, link: self.missions.on_count(m, r, k, _src(m)),
            "MISSION_ITEM_INT": lambda m, r, k, link: self.missions.on_item(m, r, k, _src(m)),
            "MISSION_ITEM": lambda m, r, k, link: self.missions.on_item(m, r, k, _src(m)),
            "MISSION_REQUEST_LIST": lambda m, r, k, link: self.missions.on_request_list(
                m, r, _src(m)
            ),
            "MISSION_REQUEST_INT": lambda m, r, k, link: self.missions.on_request(m, r, _src(m)),
            "MISSION_REQUEST": lambda m, r, k, link: self.missions.on_request(m, r, _src(m)),
            "MISSION_CLEAR_ALL": lambda m, r, k, link: self.missions.on_clear_all(m, r, _src(m)),
            "MISSION_SET_CURRENT": self._on_mission_set_current,
            "MISSION_ACK": lambda m, r, k, link: None,  # end of a download: nothing to do
            "SET_POSITION_TARGET_LOCAL_NED": self._on_setpoint,
            "SET_POSITION_TARGET_GLOBAL_INT": self._on_setpoint,
            "MANUAL_CONTROL": self._on_manual,
            "TIMESYNC": self._on_timesync,
            "PING": self._on_ping,
            "SETUP_SIGNING": self._on_setup_signing,
        }

    # --- the lockstep hook ---------------------------------------------------------------------
    def update(self, readable: bool | None = None) -> None:
        """Answer what arrived, finish timed work, send due streams. Call once per step.

        `readable`: whether the caller's poll found data on `read_links()` (a runner polls once
        per tick of its pacing, not per step: `Sitl.run`, `world.sim.run_worlds`); None: poll
        them here. A step with nothing arrived, nothing pending and nothing due costs a few
        comparisons: no system call, no message built. What the step's work sent leaves at
        its end, one datagram per link (links a lockstep gate reads: at the gate's mark)."""
        if readable is None:
            readable = self.poll()
        lines = self._drain_status() if self._drain_status is not None else ()
        prog = self.ap.mission_progress
        if (
            readable
            or lines
            or self._serving
            or prog.reached
            or prog.current != self._sent_current
            or self._clock.time_us >= self._streams_due_us
        ):
            self._work(readable, lines)
        if self._tlog is not None:
            self._tlog.maybe_flush()
            if self._tlog.error and not self._tlog_warned:  # a full disk: say so, keep flying
                self._tlog_warned = True
                self.statustext(M.MAV_SEVERITY_WARNING, self._tlog.error)
                self._flush_links()

    def _work(self, readable: bool, lines) -> None:
        """A step with something to do: requests answered, timed work, mission events, the
        autopilot's status `lines`, due streams; then what the step sent leaves, one datagram
        per link."""
        if readable:
            for link in self.read_links():
                for msg, addr in link.receive():
                    self._dispatch(link, msg, addr)
        if self._serving:  # timed protocol work, only after a request started some
            self._serve()
        prog = self.ap.mission_progress  # (a mission upload may have replaced it)
        if prog.reached or prog.current != self._sent_current:
            self._mission_events(prog)
        if self._drain_status is not None:  # and the lines the requests and the work caused
            lines = [*lines, *self._drain_status()]
        if lines:
            self._forward_status(lines)
        if self._clock.time_us >= self._streams_due_us:
            self._send_streams()
        self._flush_links()

    def _flush_links(self) -> None:
        for link in self.links:  # what this step sent leaves together (a gate flushes its own)
            if link.has_held and link.name not in self.gated:
                link.flush()

    def _serve(self) -> None:
        """Commands awaiting their result, a mission upload, a parameter list: each asked
        whether it has work; `_serving` stays on while any has."""
        if self.commands.pending:
            self.commands.service()
        if self.missions.busy:
            self.missions.service()
        if self.params.busy:
            self.params.pump()
        self._serving = bool(self.commands.pending or self.missions.busy or self.params.busy)

    def poll(self) -> bool:
        """Whether any socket of the endpoint has data (one system call; True without poll).
        Only POLLIN counts: a link that watches its remote has ICMP refusals queued (POLLERR)
        while nobody listens there, which `nobody_listens` drains, not `receive`."""
        if self._poller is None:
            return True
        return any(ev & select.POLLIN for _, ev in self._poller.poll(0))

    def read_links(self) -> list[UdpLink]:
        """The links `update()` reads: all but the gated ones, which are read at lockstep
        barriers only (flight.lockstep)."""
        return [link for link in self.links if link.name not in self.gated]

    def close(self) -> None:
        for link in self.links:
            link.close()
        if self._tlog is not None:
            self._tlog.close()

    # --- sending -------------------------------------------------------------------------------
    def broadcast(self, msg) -> None:
        for link in self.links:
            link.send(msg)

    def statustext(self, severity: int, text: str) -> None:
        """STATUSTEXT to every link; a text over 50 characters goes out in chunks (id, seq)."""
        if len(text) > 50:
            self._text_id = self._text_id % 65535 + 1
        for text_id, seq, chunk in split_text(text, self._text_id or 1):
            self.broadcast(self.mav.statustext_encode(severity, chunk, text_id, seq))

    def _send_streams(self) -> None:
        t = self.ap.clock.t
        built: dict[int, Payload] = {}  # a message due on both links is packed once
        for link in self.links:
            sched = self.streams[link.name]
            if t < sched.next_due - 1e-9:
                continue  # nothing due on this link
            if link.nobody_listens():  # the heartbeat goes on: it finds the next listener
                held = sched.held_back
                due = sched.due(t, only=M.MAVLINK_MSG_ID_HEARTBEAT)
                kept = [m for m in due if m == M.MAVLINK_MSG_ID_HEARTBEAT]
                self.stats["tx_stream_unheard"] += len(due) - len(kept) + sched.held_back - held
                due = kept
            else:
                due = sched.due(t)
            if not due:
                continue
            payloads = []
            for msg_id in due:
                p = built.get(msg_id)
                if p is None:
                    p = built[msg_id] = self._build(msg_id)
                payloads.append(p)
            link.send_payloads(payloads)
            self.stats["tx_stream"] += len(payloads)
        due = min([s.next_due for s in self.streams.values()])  # [s]; the links check exactly
        self._streams_due_us = math.floor(due * 1e6) - 1 if math.isfinite(due) else _NEVER_US

    def _streams_changed(self) -> None:
        """A rate changed (SET_MESSAGE_INTERVAL): look at the schedules at the next step."""
        self._streams_due_us = -1

    def _build(self, msg_id: int):
        if msg_id == M.MAVLINK_MSG_ID_MISSION_CURRENT:
            return self.telemetry.mission_current(total=len(self.missions.lists[MISSION]))
        return self.telemetry.build(msg_id)

    def _request_message(self, msg_id: int, reply, ack) -> int | None:
        if not self.telemetry.can_build(msg_id):
            return M.MAV_RESULT_UNSUPPORTED
        ack(M.MAV_RESULT_ACCEPTED)
        reply(self._build(msg_id))
        return None

    def _forward_status(self, lines: list) -> None:
        """The autopilot's own event lines (mode changes, failsafes) as STATUSTEXT INFO."""
        for line in lines:
            self.statustext(M.MAV_SEVERITY_INFO, str(line))

    def _mission_events(self, prog) -> None:
        if prog.reached:
            reached = list(prog.reached)
            prog.reached.clear()  # drained: each reached item is reported once
            for seq in reached:
                self.broadcast(self.mav.mission_item_reached_encode(int(seq)))
        if prog.current != self._sent_current:
            self._sent_current = prog.current
            self.broadcast(self._build(M.MAVLINK_MSG_ID_MISSION_CURRENT))

    # --- receiving -----------------------------------------------------------------------------
    def dispatch(self, link: UdpLink, batch: list[tuple[object, Address]]) -> None:
        """Handle messages a lockstep gate collected on `link`, in their arrival order."""
        for msg, addr in batch:
            self._dispatch(link, msg, addr)

    def _dispatch(self, link: UdpLink, msg, addr: Address) -> None:
        sysid = self.config.system_id
        ts = getattr(msg, "target_system", getattr(msg, "target", 0))
        tc = getattr(msg, "target_component", 0)
        mtype = msg.get_type()
        # Like PX4, mission messages may also be addressed to MAV_COMP_ID_MISSIONPLANNER.
        ok_tc = (
            (0, COMPONENT_ID, M.MAV_COMP_ID_MISSIONPLANNER)
            if mtype.startswith("MISSION_")
            else (0, COMPONENT_ID)
        )
        if ts not in (0, sysid) or tc not in ok_tc:
            self.stats["rx_wrong_target"] += 1
            return
        handler = self._handlers.get(mtype)
        self.rx_types[mtype] += 1
        if handler is None:
            self.stats["rx_ignored"] += 1
            return
        self.last_heard[link.name] = self.ap.clock.t

        def reply(m, _link=link, _addr=addr):
            _link.send(m, to=_addr)

        key = (link.name, addr, _src(msg))
        self._serving = True  # the handler may have started timed work: `_serve` looks
        try:
            handler(msg, reply, key, link)
            self.stats["rx_handled"] += 1
        except Exception:  # noqa: BLE001 - a malformed request must never stop the vehicle
            self.stats["rx_handler_error"] += 1
            log.exception("dropped %s from %s: handler failed", msg.get_type(), addr)

    def _on_command(self, cmd: Cmd, reply, link) -> None:
        self.rx_commands[cmd.command] += 1
        self.commands.handle(cmd, reply, link)

    def _on_heartbeat(self, msg, reply, key, link) -> None:
        pass  # last_heard is updated for every handled message

    def _on_set_mode(self, msg, reply, key, link) -> None:
        """Legacy SET_MODE (MAVProxy, ArduPilot tools): answered like ArduPilot, COMMAND_ACK 11."""
        result = M.MAV_RESULT_DENIED
        src = _src(msg)
        if msg.base_mode & M.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED:
            mode = mode_of_packed(self.config.personality, msg.custom_mode, self.ap.airframe)
            if mode is not None:
                res = self.ap.set_mode(mode, mode_source(src[1]))
                if res.ok:
                    result = M.MAV_RESULT_ACCEPTED
                    self.commands.mode_number = int(msg.custom_mode)
                    self.commands.guided_hover = False
                else:
                    result = refusal_result(res)
                    self.statustext(M.MAV_SEVERITY_WARNING, res.reason)
        reply(self.mav.command_ack_encode(M.MAVLINK_MSG_ID_SET_MODE, result, 0, 0, src[0], src[1]))

    def _on_mission_set_current(self, msg, reply, key, link) -> None:
        n = len(self.missions.lists[MISSION])
        if 0 <= msg.seq < n:
            res = self.ap.set_mission_current(msg.seq)
            if not res.ok:
                self.statustext(M.MAV_SEVERITY_WARNING, res.reason)
        reply(self._build(M.MAVLINK_MSG_ID_MISSION_CURRENT))

    def _on_setpoint(self, msg, reply, key, link) -> None:
        try:
            if msg.get_type() == "SET_POSITION_TARGET_LOCAL_NED":
                sp = setpoint_from_local(msg)
            else:
                sp = setpoint_from_global(msg, self.ap.home)
        except SetpointError as e:
            self.stats["setpoint_dropped"] += 1
            if self.stats["setpoint_dropped"] in (1, 10, 100, 1000):
                self.statustext(M.MAV_SEVERITY_WARNING, f"setpoint dropped: {e}")
            return
        res = self.ap.set_offboard_setpoint(sp)
        if res.ok:
            self.last_setpoint_t = self.ap.clock.t
        else:
            self.stats["setpoint_refused"] += 1

    def _on_manual(self, msg, reply, key, link) -> None:
        try:
            x, y, z, r = manual_from_msg(msg)
        except SetpointError:
            self.stats["manual_dropped"] += 1
            return
        self.ap.set_manual_control(x, y, z, r)

    def _initial_key(self) -> bytes | None:
        path = self.config.signing_key or self.config.key_file(self.ap.airframe)
        if path is None or (self.config.signing_key is None and not Path(path).exists()):
            return None
        return load_key(path)

    def _on_setup_signing(self, msg, reply, key, link) -> None:
        """SETUP_SIGNING: a new key (signing on, saved to `key_file`), or 32 zero bytes (off).

        Once signing is on, only a correctly signed SETUP_SIGNING gets here (the codec drops
        the others), so only a holder of the current key can change or remove it."""
        new = bytes(msg.secret_key)
        path = self.config.key_file(self.ap.airframe)
        if not any(new):
            if self.signing.enabled:
                self.signing.set_key(None)
                if path is not None:
                    path.unlink(missing_ok=True)
                self.statustext(M.MAV_SEVERITY_NOTICE, "signing disabled")
            return
        self.signing.set_key(new, msg.initial_timestamp)
        where = "kept in memory only (no state dir)"
        if path is not None:
            try:
                save_key(path, new)
                where = f"saved to {path}"
            except OSError as e:
                where = f"not saved ({e.strerror or e})"
        self.stats["setup_signing"] += 1
        self.statustext(M.MAV_SEVERITY_NOTICE, f"signing on: key {where}")

    def _on_ping(self, msg, reply, key, link) -> None:
        """PING (MAVSDK sends it): a request has target 0; answer addressed to the sender."""
        if msg.target_system == 0:
            src = _src(msg)
            reply(self.mav.ping_encode(msg.time_usec, msg.seq, src[0], src[1]))

    def _on_timesync(self, msg, reply, key, link) -> None:
        if msg.tc1 == 0:  # a request: answer with our (simulation) time in ns
            reply(self.mav.timesync_encode(self.ap.clock.time_us * 1000, msg.ts1))


def _src(msg) -> tuple[int, int]:
    return (msg.get_srcSystem(), msg.get_srcComponent())
