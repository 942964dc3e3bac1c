"""MAVSDK-Python (real client, native library) flies the fixed-wing over MAVLink.

`skyherd sitl --airframe fixedwing` runs as its own process on 127.0.0.1; MAVSDK arms it,
takes off from the runway, flies a 4-waypoint mission, holds (loiter), returns and lands.
Everything asserted comes from MAVSDK's own telemetry.
"""

import asyncio
import math
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
from mavsdk.asyncio import ComponentType, Configuration, Mavsdk
from mavsdk.asyncio.plugins.action import ActionAsync
from mavsdk.asyncio.plugins.mission import MissionAsync, MissionItem, MissionPlan
from mavsdk.asyncio.plugins.param import ParamAsync
from mavsdk.asyncio.plugins.telemetry import TelemetryAsync
from mavsdk.plugins.telemetry import FlightMode, LandedState

from skyherd.flight.geo import DEFAULT_HOME, geodetic_to_ned, ned_to_geodetic

INSTANCE = 23  # ports 14563 / 14603 / 18593: away from the other suites' instances
SPEEDUP = 40.0  # the pacer only caps it: a busy machine runs slower, waits are generous
WAIT = 90.0  # [s wall] per phase
LAP_M = 2 * math.pi * 128.9  # one lap of the default loiter circle, V²/(g tan(0.7·35°)) [m]
WPS = [(500.0, 0.0, 50.0), (500.0, 500.0, 60.0), (0.0, 500.0, 60.0), (-200.0, 250.0, 50.0)]


def start_sitl(tmp: Path) -> subprocess.Popen:
    exe = Path(sys.executable).with_name("skyherd")
    cmd = [str(exe), "sitl", "--airframe", "fixedwing", "--instance", str(INSTANCE),
           "--speedup", str(SPEEDUP), "--no-tlog", "--state-dir", str(tmp / "state"),
           "--runs", str(tmp / "runs")]  # fmt: skip
    return subprocess.Popen(
        cmd, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, start_new_session=True
    )


async def call(fn, *args, tries: int = 3):
    """A MAVSDK call, repeated on a TIMEOUT result (as a ground station does): on a loaded
    2-core machine MAVSDK's wall-clock command timeout can expire. Other errors raise."""
    for i in range(tries):
        try:
            return await fn(*args)
        except Exception as e:  # ActionError / MissionError / ParamError carry the result
            result = getattr(getattr(e, "result", None), "name", "")
            if result != "TIMEOUT" or i == tries - 1:
                raise


def stop_sitl(proc: subprocess.Popen) -> None:
    """Interrupt the SITL process group we started (SIGINT, then SIGKILL after 10 s)."""
    if proc.poll() is None:
        os.killpg(proc.pid, signal.SIGINT)
        try:
            proc.wait(timeout=10)
        except subprocess.TimeoutExpired:
            os.killpg(proc.pid, signal.SIGKILL)
            proc.wait()


async def until(pred, wall_s: float, what: str, tel=None, poll: float = 0.05):
    """Poll the async predicate until true; fail after `wall_s` wall seconds (with where the
    aircraft was, as MAVSDK saw it, when `tel` is given)."""
    deadline = time.monotonic() + wall_s
    while time.monotonic() < deadline:
        if await pred():
            return
        await asyncio.sleep(poll)
    where = ""
    if tel is not None:
        p = await tel.position()
        ned = geodetic_to_ned(DEFAULT_HOME, p.latitude_deg, p.longitude_deg, p.absolute_altitude_m)
        where = (f" (at {np.round(ned, 1)} m NED, {await tel.flight_mode()}, "
                 f"{await tel.landed_state()}, armed {await tel.armed()})")  # fmt: skip
    raise AssertionError(f"timed out waiting for: {what}{where}")


async def fly(track: list) -> dict:
    cfg = Configuration.create_with_component_type(ComponentType.GROUND_STATION)
    async with Mavsdk(cfg) as mavsdk:
        await mavsdk.add_any_connection(f"udpin://127.0.0.1:{14540 + INSTANCE}")
        system = await mavsdk.first_autopilot(timeout_s=15.0)
        assert system is not None, "no autopilot seen by MAVSDK"
        action, mission = ActionAsync(system), MissionAsync(system)
        tel, param = TelemetryAsync(system), ParamAsync(system)
        out: dict = {}

        async def record():
            async for p in tel.subscribe_position():
                track.append(
                    geodetic_to_ned(
                        DEFAULT_HOME, p.latitude_deg, p.longitude_deg, p.absolute_altitude_m
                    )
                )

        rec = asyncio.create_task(record())
        await until(tel.health_all_ok, 15.0, "health all ok (armable, home set)")
        out["takeoff_alt_param"] = await call(param.get_param_float, "MIS_TAKEOFF_ALT")
        await call(param.set_param_float, "MIS_TAKEOFF_ALT", 40.0)

        await call(action.arm)
        await call(action.takeoff)
        await until(lambda: _flying_in(tel, FlightMode.HOLD), WAIT, "takeoff → hold", tel)
        out["alt_after_takeoff"] = (await tel.position()).relative_altitude_m

        items = []
        for n, e, alt in WPS:
            lat, lon, _ = ned_to_geodetic(DEFAULT_HOME, np.array([n, e, 0.0]))
            items.append(
                MissionItem(
                    latitude_deg=lat,
                    longitude_deg=lon,
                    relative_altitude_m=alt,
                    is_fly_through=True,
                    acceptance_radius_m=30.0,
                )  # fmt: skip
            )
        await call(mission.upload_mission, MissionPlan(items))
        await call(mission.start_mission)
        await until(mission.is_mission_finished, WAIT, "mission finished", tel)
        out["mission_progress"] = await mission.mission_progress()

        await call(action.hold)
        await until(lambda: _mode_is(tel, FlightMode.HOLD), 5.0, "hold")
        n0 = len(track)
        # One loiter lap (track length, so it does not depend on the machine's speed).
        await until(lambda: _flown(track, n0, LAP_M), WAIT, "one loiter lap", tel)
        out["hold_track"] = list(track[n0:])

        await call(action.return_to_launch)
        await until(lambda: _mode_is(tel, FlightMode.RETURN_TO_LAUNCH), 5.0, "return mode")
        await until(lambda: _near_home(tel, 200.0), WAIT, "back over home", tel)
        out["rtl_alt"] = (await tel.position()).relative_altitude_m
        out["mode_rtl"] = await tel.flight_mode()
        await call(action.land)
        await until(lambda: _landed(tel), WAIT, "landed and disarmed", tel)
        out["final"] = await tel.position()
        rec.cancel()
        return out


async def _flown(track: list, n0: int, dist: float) -> bool:
    seg = np.array(track[n0:])
    return len(seg) > 2 and float(np.sum(np.hypot(*np.diff(seg[:, :2], axis=0).T))) >= dist


async def _mode_is(tel, mode) -> bool:
    return await tel.flight_mode() == mode


async def _flying_in(tel, mode) -> bool:
    return await tel.landed_state() == LandedState.IN_AIR and await tel.flight_mode() == mode


async def _near_home(tel, r: float) -> bool:
    p = await tel.position()
    ned = geodetic_to_ned(DEFAULT_HOME, p.latitude_deg, p.longitude_deg, p.absolute_altitude_m)
    return math.hypot(ned[0], ned[1]) < r


async def _landed(tel) -> bool:
    return await tel.landed_state() == LandedState.ON_GROUND and not await tel.armed()


@pytest.mark.slow
def test_mavsdk_takeoff_mission_hold_rtl_land(tmp_path):
    proc = start_sitl(tmp_path)
    track: list = []
    try:
        out = asyncio.run(asyncio.wait_for(fly(track), timeout=300.0))
    except BaseException:
        stop_sitl(proc)
        print("skyherd sitl stderr:\n" + proc.stderr.read().decode(errors="replace")[-4000:])
        raise
    stop_sitl(proc)
    assert out["takeoff_alt_param"] == 40.0  # PX4's name, our default
    assert 35.0 < out["alt_after_takeoff"] < 45.0
    assert out["mission_progress"].current == out["mission_progress"].total == 4
    tr = np.array(track)
    for n, e, _ in WPS:
        assert np.min(np.hypot(tr[:, 0] - n, tr[:, 1] - e)) < 45.0, (n, e)
    hold = np.array(out["hold_track"])
    assert len(hold) > 20 and np.ptp(-hold[:, 2]) < 8.0  # loiter at a steady height
    r = np.hypot(*(hold[:, :2] - hold[:, :2].mean(axis=0)).T)  # about the lap's centre
    assert abs(np.mean(r) - 128.9) < 13.0 and np.ptp(r) < 30.0
    assert out["mode_rtl"] == FlightMode.RETURN_TO_LAUNCH and out["rtl_alt"] > 45.0
    f = out["final"]
    end = geodetic_to_ned(DEFAULT_HOME, f.latitude_deg, f.longitude_deg, f.absolute_altitude_m)
    assert abs(end[1]) < 10.0 and 0.0 < end[0] < 700.0  # stopped on home's runway (north)
    assert abs(f.relative_altitude_m) < 2.0
