"""What every world does at a camera instant t, whoever flies the vehicle:

1. the UGV team moves to t (parked until `ugv_start`: when the vehicle is first seen in OFFBOARD,
   at a time, or at once; a shepherded flock feels where the vehicle is);
2. the camera renders the team from the vehicle's pose on its mount (level gimbal, body-fixed,
   or the pan-tilt head pointed at the ROI) and the frame is published — none inside a
   `--cut-camera` window, none for a pose that is not finite;
3. the UGVs' truth and the clock are published (signed with the flight key);
4. world.csv gets one row: the vehicle, its mode and arming, the team's time, every UGV.

The built-in vehicle (world.sim.World), an outside autopilot followed over MAVLink
(world.follow.FollowWorld) and a real autopilot on skyherd's physics (world.bridged.BridgedWorld)
each own one `Scene`, so every world honours every option the same way.
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np

from skyherd.flight.state import VehicleState
from skyherd.groundsim.transport import UGVStatePublisher
from skyherd.groundsim.ugv import UGVModel
from skyherd.perception.camera import UAVPose
from skyherd.perception.mount import mounted_pose
from skyherd.perception.render_fast import FastRenderer
from skyherd.runio import CsvWriter, to_jsonable
from skyherd.runio.constants import CLOCK_KEY
from skyherd.runio.mac import sign_body, sign_record
from skyherd.task.params import TaskParams
from skyherd.world.team import new_team, team_states, ugv_columns

TRUTH_COLUMNS = ["t", "north", "east", "down", "vn", "ve", "vd", "mode", "armed", "team_t"]


def clock_payload(t: float, key: bytes | None) -> bytes:
    """The clock record {"t_sim": t} as sent, signed with `key` unless None. Signed, its
    canonical body (runio.mac) is written directly: json's encoder doubled its cost."""
    if key is not None and isinstance(t, float) and math.isfinite(t):  # numpy's too: a float
        return sign_body(b'{"t_sim":%r}' % float(t), key)
    return sign_record({"t_sim": t}, key)  # an int as an int; json writes NaN and Infinity


def during(windows: tuple[tuple[float, float], ...], t: float) -> bool:
    """t inside one of the (start, duration) windows [s]."""
    return any(t0 <= t < t0 + d for t0, d in windows)


class Scene:
    """The UGV team, the camera and world.csv of one vehicle (`params`: a world.sim.WorldParams)."""

    def __init__(self, params, task: TaskParams, session=None, run_dir: Path | None = None,
                 key: bytes | None = None):  # fmt: skip
        """session: Zenoh (None: nothing published); key: the flight key that signs the frames,
        the UGV states and the clock."""
        self.p = params
        # no team: the vehicle alone (a formation vehicle); its instants are kept all the same
        self.team = None if params.scenario == "none" else new_team(params.scenario, params.seed,
                                                                    task.n_ugvs)  # fmt: skip
        n_ugvs = 0 if self.team is None else len(self.team.positions())  # a flock: its own size
        self.team_t: float | None = None  # team time [s]; None while parked
        self._team_t0 = 0.0
        self.cam = task.camera
        if params.camera == "roi":
            from skyherd.perception.gimbal import ORBIT_CAMERA

            self.cam = ORBIT_CAMERA
        self.mount = "pointed" if params.camera == "roi" else "level" if params.gimbal else "body"
        self.roi_ned: np.ndarray | None = None  # where the pointed head looks (None: nadir)
        self.roi_commands = 0
        self.renderer = FastRenderer(self.cam, UGVModel())
        self.publisher = self._ugv_pub = self._clock_pub = None
        self._key = key
        if session is not None and self.team is not None:
            from skyherd.perception.transport import FramePublisher

            self.publisher = FramePublisher(session, params.vehicle, self.cam, mount=self.mount,
                                            rng=np.random.default_rng(params.seed), key=key)  # fmt: skip
            self._ugv_pub = UGVStatePublisher(session, n_ugvs, key=key)
            self._clock_pub = session.declare_publisher(CLOCK_KEY)
        self.run_dir = Path(run_dir) if run_dir is not None else None
        cols = TRUTH_COLUMNS + ugv_columns(n_ugvs)
        self._ugv_cells = 2 * n_ugvs  # world.csv's north, east of each UGV
        self.truth = CsvWriter(self.run_dir / "world.csv", cols) if self.run_dir else None
        self.truth_t = -np.inf  # time of world.csv's last row [s]
        self.handed_over = False  # the companion's first decision heard (listen_for_hand_over)
        self._decisions = None
        self.frames = 0
        self.render_failures = 0
        self.camera_dropped = 0  # frames not sent while the camera was lost

    def listen_for_hand_over(self, session) -> None:
        """Beside an outside autopilot the world cannot tell the hand-over from the mode
        (ArduPilot takes off in GUIDED, the mode the AI then flies in; a bridge carries no mode
        at all): the companion's first decision on skyherd/<vehicle>/decision is the hand-over
        (decisions start with the AI phase); with the flight key only an authentic one."""
        if session is None or self.team is None or self.p.ugv_start != "offboard":
            return
        import json

        from skyherd.runio.mac import record_ok

        def heard(sample) -> None:
            try:
                rec = json.loads(sample.payload.to_bytes())
            except ValueError:
                return  # not a record: never the hand-over
            if isinstance(rec, dict) and (self._key is None or record_ok(rec, self._key)):
                self.handed_over = True

        self._decisions = session.declare_subscriber(f"skyherd/{self.p.vehicle}/decision", heard)

    def point(self, roi_ned: np.ndarray | None) -> None:
        """Point the pan-tilt head at `roi_ned` (a DO_SET_ROI_LOCATION the world accepted)."""
        self.roi_ned = roi_ned
        self.roi_commands += 1

    def camera_pose(self, state: VehicleState) -> UAVPose:
        """The pose the camera renders from: the level downward gimbal (or body-fixed without
        one), or the pan-tilt head pointed at the ROI (straight down until one is set)."""
        return mounted_pose(self.cam, self.mount, state.pos_ned, state.quat, self.roi_ned)

    def instant(self, t: float, state: VehicleState, mode: str, armed: bool | None,
                offboard: bool) -> int | None:  # fmt: skip
        """Steps 1-4 at time t [s] with the vehicle `state` (the physics where the world has
        it, else the autopilot's report); mode / armed as the autopilot says ("" / None when
        the world cannot know); offboard: the vehicle is in OFFBOARD now (starts a team parked
        until "offboard"). Returns the published frame's sequence number, or None."""
        finite = bool(np.isfinite(state.pos_ned).all())  # an estimate not yet known: NaN
        self.move_team(t, offboard, state.pos_ned[:2] if finite else None)
        ugvs = None if self.team is None else team_states(self.team)
        seq = None
        if self.publisher is not None:
            if during(self.p.camera_losses, t):
                self.camera_dropped += 1  # the camera is lost: no frame leaves
            else:
                try:
                    uav = self.camera_pose(state)
                    # drawn straight into the payload that is published (no copy)
                    image = self.renderer.render(uav, ugvs, self.publisher.frame_buffer())
                except ValueError:  # a non-finite pose: no frame, as a real camera link would give
                    self.render_failures += 1
                else:
                    seq = self.publisher.publish(t, uav.pos_ned, uav.quat, image)
                    self.frames += 1
            self._ugv_pub.publish(t, ugvs)
            self._clock_pub.put(clock_payload(t, self._key))
        if finite:  # world.csv is the judge's truth: no row for a position nobody knows
            self.write_truth(t, state, mode, armed, ugvs)
        return seq

    def move_team(self, t: float, offboard: bool, shepherd_ne: np.ndarray | None) -> None:
        """The team to time t: parked until `ugv_start`, then driven on the world's clock."""
        if self.team is None:
            return
        if self.team_t is None:
            start = self.p.ugv_start
            if offboard if start == "offboard" else t >= float(start):
                self.team_t, self._team_t0 = 0.0, t
            return
        dt = (t - self._team_t0) - self.team_t
        if dt > 0:
            if shepherd_ne is not None and hasattr(self.team, "set_shepherd"):
                self.team.set_shepherd(shepherd_ne)  # a flock feels where the UAV is
            self.team.step(dt)
            self.team_t += dt

    def write_truth(self, t: float, state: VehicleState, mode: str, armed: bool | None,
                    ugvs=None) -> None:  # fmt: skip
        """One world.csv row (the team as it is now unless `ugvs` is given)."""
        if self.truth is None:
            return
        if ugvs is None and self.team is not None:
            ugvs = team_states(self.team)
        v = state.vel_ned if state.vel_ned is not None else np.full(3, np.nan)
        # the cells in the header's order as plain Python values (a row every camera instant:
        # no dict, no conversion per cell)
        row = [to_jsonable(t), *np.asarray(state.pos_ned).tolist(), *np.asarray(v).tolist(), mode,
               "" if armed is None else int(armed),
               "" if self.team_t is None else to_jsonable(round(self.team_t, 6))]  # fmt: skip
        ugv_ne = [] if ugvs is None else np.asarray(ugvs.pos_ne).ravel().tolist()
        ugv_ne += [""] * (self._ugv_cells - len(ugv_ne))  # a UGV missing from `ugvs`: empty
        self.truth.write_values(row + ugv_ne[: self._ugv_cells])
        self.truth_t = t

    def republish(self) -> None:
        if self.publisher is not None:
            self.publisher.republish()

    def close(self) -> None:
        if self.truth is not None:
            self.truth.close()
        if self.publisher is not None:
            self.publisher.close()
        if self._ugv_pub is not None:
            self._ugv_pub.close()
        for z in (self._clock_pub, self._decisions):
            if z is None:
                continue
            try:
                z.undeclare()
            except Exception:  # noqa: BLE001 - already closed with its session
                pass
