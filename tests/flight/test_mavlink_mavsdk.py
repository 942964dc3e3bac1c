"""The real MAVSDK-Python 4.x client flies the SITL (`skyherd sitl` in its own process)
over udpin://127.0.0.1:14540: health, arm, takeoff to 10 m, offboard velocity then position
setpoints, land, disarm — asserting on the telemetry MAVSDK itself receives.

MAVSDK runs in wall time and streams offboard setpoints at 20 Hz; with COM_OF_LOSS_T = 0.5 s
of simulation time the SITL runs at 4x (a setpoint every 0.2 s of simulation time).
"""

from __future__ import annotations

import asyncio
import math
import subprocess
import sys
import time
from pathlib import Path

import pytest
from mavsdk.asyncio import ComponentType, Configuration, Mavsdk
from mavsdk.asyncio.plugins.action import ActionAsync
from mavsdk.asyncio.plugins.offboard import OffboardAsync, PositionNedYaw, VelocityNedYaw
from mavsdk.asyncio.plugins.telemetry import FlightMode, LandedState, TelemetryAsync

SPEEDUP = 4.0
SKYHERD = str(Path(sys.executable).parent / "skyherd")  # the installed console script


async def _until(what: str, fn, timeout: float, poll: float = 0.05):
    """Await `fn()` until it returns a truthy value; fail after `timeout` wall seconds."""
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        v = await fn()
        if v:
            return v
        await asyncio.sleep(poll)
    raise AssertionError(f"timed out waiting for {what}")


async def fly(log) -> dict:
    """One MAVSDK session; returns the figures it measured from telemetry."""
    t0 = time.monotonic()
    out: dict = {}

    def say(text: str) -> None:
        log(f"[{time.monotonic() - t0:6.2f} s] {text}")

    cfg = Configuration.create_with_component_type(ComponentType.GROUND_STATION)
    async with Mavsdk(cfg) as mavsdk:
        await mavsdk.add_any_connection("udpin://127.0.0.1:14540")
        drone = await mavsdk.first_autopilot(timeout_s=15.0)
        assert drone is not None, "MAVSDK found no autopilot"
        tel, act, off = TelemetryAsync(drone), ActionAsync(drone), OffboardAsync(drone)
        say(
            f"autopilot found: system id {await drone.get_system_id()}, autopilot {await drone.autopilot_type()}"
        )

        async def healthy():
            h = await tel.health()
            return h if h.is_global_position_ok and h.is_home_position_ok and h.is_armable else None

        h = await _until("health", healthy, 15.0)
        say(
            f"health: global position ok {h.is_global_position_ok}, home ok {h.is_home_position_ok}, armable {h.is_armable}"
        )
        home = await tel.home()
        out["home"] = (home.latitude_deg, home.longitude_deg, home.absolute_altitude_m)
        say(
            f"home: {home.latitude_deg:.6f}, {home.longitude_deg:.6f}, {home.absolute_altitude_m:.1f} m AMSL"
        )

        await act.set_takeoff_altitude(10.0)  # PARAM_SET MIS_TAKEOFF_ALT
        out["takeoff_alt_param"] = await act.get_takeoff_altitude()
        await act.arm()
        await _until("armed", tel.armed, 5.0)
        say("armed")
        await act.takeoff()
        await _until("in air", tel.in_air, 10.0)

        async def settled_at_10():
            pv = await tel.position_velocity_ned()
            return (
                pv
                if abs(-pv.position.down_m - 10.0) < 0.2 and abs(pv.velocity.down_m_s) < 0.1
                else None
            )

        await _until("10 m", settled_at_10, 20.0)
        pos = await tel.position()
        out["takeoff_rel_alt"] = pos.relative_altitude_m
        out["mode_after_takeoff"] = await _until(
            "hold", lambda: _mode_is(tel, FlightMode.HOLD), 5.0
        )
        say(
            f"took off: relative altitude {pos.relative_altitude_m:.2f} m, mode {await tel.flight_mode()!r}"
        )

        # Offboard velocity: 2 m/s north, 1 m/s east, level.
        await off.set_velocity_ned(VelocityNedYaw(0.0, 0.0, 0.0, 0.0))
        await off.start()
        await _until("offboard", lambda: _mode_is(tel, FlightMode.OFFBOARD), 5.0)
        say("offboard started")
        await off.set_velocity_ned(VelocityNedYaw(2.0, 1.0, 0.0, 0.0))
        await asyncio.sleep(1.5)  # 6 s of simulation time
        v = (await tel.position_velocity_ned()).velocity
        out["offboard_velocity"] = (v.north_m_s, v.east_m_s, v.down_m_s)
        say(
            f"velocity setpoint (2, 1, 0) m/s: measured ({v.north_m_s:.2f}, {v.east_m_s:.2f}, {v.down_m_s:.2f}) m/s"
        )

        # Offboard position: (20, 10, -12) m, heading 90 deg.
        target = (20.0, 10.0, -12.0)
        await off.set_position_ned(PositionNedYaw(*target, 90.0))

        async def arrived():
            p = await tel.position_velocity_ned()
            d = math.dist((p.position.north_m, p.position.east_m, p.position.down_m), target)
            speed = math.hypot(p.velocity.north_m_s, p.velocity.east_m_s, p.velocity.down_m_s)
            return (p, d) if d < 0.3 and speed < 0.2 else None

        p, d = await _until("position setpoint", arrived, 20.0)
        await asyncio.sleep(0.5)  # 2 s of simulation time holding there
        p = (await tel.position_velocity_ned()).position
        out["offboard_position"] = (p.north_m, p.east_m, p.down_m)
        out["position_error"] = math.dist(out["offboard_position"], target)
        out["yaw_deg"] = (await tel.attitude_euler()).yaw_deg
        say(f"position setpoint {target}: measured ({p.north_m:.2f}, {p.east_m:.2f}, {p.down_m:.2f}) m, "
            f"error {out['position_error']:.2f} m, yaw {out['yaw_deg']:.1f} deg")  # fmt: skip
        await off.stop()
        await _until("hold after offboard", lambda: _mode_is(tel, FlightMode.HOLD), 5.0)

        await act.land()
        await _until("landing", lambda: _landed_is(tel, LandedState.LANDING), 5.0)
        say("landing")
        await _until("on ground", lambda: _landed_is(tel, LandedState.ON_GROUND), 30.0)
        say("on the ground")

        async def disarmed():
            return not await tel.armed()

        await _until("disarmed", disarmed, 10.0)
        p = (await tel.position_velocity_ned()).position
        out["landed_at"] = (p.north_m, p.east_m, p.down_m)
        say(f"disarmed at ({p.north_m:.2f}, {p.east_m:.2f}, {p.down_m:.2f}) m")
    return out


async def _mode_is(tel, mode):
    return (await tel.flight_mode()) == mode


async def _landed_is(tel, state):
    return (await tel.landed_state()) == state


def _start_sitl(tmp_path: Path, speedup: float) -> subprocess.Popen:
    cmd = [SKYHERD, "sitl", "--airframe", "quadrotor", "--speedup", str(speedup),
           "--state-dir", str(tmp_path / "state"), "--runs", str(tmp_path / "runs"), "--duration", "600"]  # fmt: skip
    proc = subprocess.Popen(
        cmd,
        cwd=Path(__file__).resolve().parents[2],
        stdout=subprocess.PIPE,
        stderr=subprocess.STDOUT,
        text=True,
    )
    banner = proc.stdout.readline()
    assert "skyherd sitl" in banner, banner
    return proc


def _stop(proc: subprocess.Popen) -> None:
    proc.terminate()
    try:
        proc.wait(timeout=10)
    except subprocess.TimeoutExpired:
        proc.kill()
        proc.wait()


@pytest.fixture
def sitl_process(tmp_path):
    proc = _start_sitl(tmp_path, SPEEDUP)
    try:
        yield proc, tmp_path
    finally:
        _stop(proc)


@pytest.mark.slow
def test_mavsdk_flies_the_sitl(sitl_process):
    proc, tmp = sitl_process
    out = asyncio.run(asyncio.wait_for(fly(print), timeout=150))
    lat, lon, alt = out["home"]
    assert (lat, lon, alt) == pytest.approx((-35.363261, 149.165230, 584.0), abs=1e-6)
    assert out["takeoff_alt_param"] == pytest.approx(10.0)
    assert out["takeoff_rel_alt"] == pytest.approx(10.0, abs=0.5)
    vn, ve, vd = out["offboard_velocity"]
    assert (vn, ve, vd) == pytest.approx((2.0, 1.0, 0.0), abs=0.2)
    assert out["position_error"] < 0.5
    assert out["yaw_deg"] == pytest.approx(90.0, abs=3.0)
    n, e, dn = out["landed_at"]
    assert math.hypot(n - 20.0, e - 10.0) < 1.0 and abs(dn) < 0.2
    # The SITL process ends cleanly on SIGTERM and records what MAVSDK asked for.
    proc.terminate()
    assert proc.wait(timeout=10) == 0
    summary = next((tmp / "runs").glob("*-sitl/summary.md")).read_text()
    assert "COMMAND_LONG" in summary and "SET_POSITION_TARGET_LOCAL_NED" in summary


async def mission_session(log) -> dict:
    """MAVSDK's mission and geofence plugins: upload, download, fly in AUTO, RTL."""
    import numpy as np
    from mavsdk.asyncio.plugins.geofence import (
        FenceType,
        GeofenceAsync,
        GeofenceData,
        Point,
        Polygon,
    )
    from mavsdk.asyncio.plugins.mission import MissionAsync, MissionItem, MissionPlan

    from skyherd.flight.geo import DEFAULT_HOME, ned_to_geodetic

    def ll(n: float, e: float) -> tuple[float, float]:
        lat, lon, _ = ned_to_geodetic(DEFAULT_HOME, np.array([n, e, 0.0]))
        return lat, lon

    out: dict = {}
    cfg = Configuration.create_with_component_type(ComponentType.GROUND_STATION)
    async with Mavsdk(cfg) as mavsdk:
        await mavsdk.add_any_connection("udpin://127.0.0.1:14540")
        drone = await mavsdk.first_autopilot(timeout_s=15.0)
        assert drone is not None
        tel, act, mis, geo = (
            TelemetryAsync(drone),
            ActionAsync(drone),
            MissionAsync(drone),
            GeofenceAsync(drone),
        )
        corners = ((20.0, 0.0), (20.0, 15.0), (0.0, 15.0))
        items = [
            MissionItem(*ll(n, e), 8.0, is_fly_through=False, acceptance_radius_m=1.0)
            for n, e in corners
        ]
        await mis.upload_mission(MissionPlan(items))
        down = (await mis.download_mission()).mission_items
        out["download"] = [(i.latitude_deg, i.longitude_deg, i.relative_altitude_m) for i in down]
        out["upload"] = [(i.latitude_deg, i.longitude_deg, i.relative_altitude_m) for i in items]
        log(f"mission: uploaded {len(items)} items, downloaded {len(down)}")
        square = [Point(*ll(n, e)) for n, e in ((-100, -100), (-100, 100), (100, 100), (100, -100))]
        await geo.upload_geofence(GeofenceData([Polygon(square, FenceType.INCLUSION)], []))
        g = await geo.download_geofence()
        out["fence_points"] = [(p.latitude_deg, p.longitude_deg) for p in g.polygons[0].points]
        out["fence_sent"] = [(p.latitude_deg, p.longitude_deg) for p in square]
        log(
            f"geofence: uploaded 1 polygon, downloaded {len(g.polygons)} polygon of {len(g.polygons[0].points)} points"
        )
        await act.arm()
        await mis.start_mission()
        seen, corners_seen = set(), []
        while not await mis.is_mission_finished():
            p = await mis.mission_progress()
            if p.current not in seen:
                seen.add(p.current)
                pv = (await tel.position_velocity_ned()).position
                corners_seen.append((p.current, pv.north_m, pv.east_m, pv.down_m))
            await asyncio.sleep(0.05)
        prog = await mis.mission_progress()
        out["progress"] = (prog.current, prog.total)
        out["after_mission"] = (await tel.position_velocity_ned()).position
        log(f"mission finished: progress {prog.current}/{prog.total}, at "
            f"({out['after_mission'].north_m:.2f}, {out['after_mission'].east_m:.2f}, {out['after_mission'].down_m:.2f}) m")  # fmt: skip
        await act.return_to_launch()

        async def disarmed():
            return not await tel.armed()

        await _until("disarmed after RTL", disarmed, 30.0)
        out["home_landing"] = (await tel.position_velocity_ned()).position
        log(
            f"RTL: landed at ({out['home_landing'].north_m:.2f}, {out['home_landing'].east_m:.2f}) m and disarmed"
        )
    return out


def test_mavsdk_mission_and_geofence(tmp_path):
    proc = _start_sitl(tmp_path, 10.0)  # no offboard stream here: 10x is fine
    try:
        out = asyncio.run(asyncio.wait_for(mission_session(print), timeout=120))
    finally:
        _stop(proc)
    for a, b in zip(out["upload"], out["download"], strict=True):
        assert a == pytest.approx(b, abs=1e-7)
    for a, b in zip(out["fence_sent"], out["fence_points"], strict=True):
        assert a == pytest.approx(b, abs=1e-7)
    assert out["progress"] == (3, 3)
    p = out["after_mission"]
    assert math.hypot(p.north_m - 0.0, p.east_m - 15.0) < 1.0 and abs(p.down_m + 8.0) < 0.5
    h = out["home_landing"]
    assert math.hypot(h.north_m, h.east_m) < 1.0 and abs(h.down_m) < 0.2
