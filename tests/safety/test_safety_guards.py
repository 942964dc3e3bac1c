"""Every guard stated in every constraint set, and the wind guard judged: refused before the
flight above the set's limit, the airframe's fallback when the autopilot's estimate rises
above it in flight (a scripted timeline on the simulation clock)."""

import math
import subprocess
import sys
import tomllib
from pathlib import Path

import numpy as np
import pytest

from skyherd.flight.autopilot_api import FlightMode, Setpoint
from skyherd.flight.geo import GRAVITY
from skyherd.flight.state import VehicleState
from skyherd.safety.campaign import wind_limit
from skyherd.safety.config import ENVELOPE_DIR, GUARD_KEYS, EnvelopeFileError, load_envelope
from skyherd.safety.health import HealthTracker
from skyherd.safety.net import load_net
from skyherd.safety.supervisor import Health, Mode, Supervisor, SupervisorParams

GROUNDAIR = ENVELOPE_DIR / "quadrotor_groundair.toml"


def st(t, p=(0.0, 0.0, -20.0), v=(0.0, 0.0, 0.0)):
    return VehicleState(t, np.array(p, float), np.array(v, float), np.array([1.0, 0, 0, 0]),
                        np.zeros(3), np.array([0, 0, -GRAVITY]), False)  # fmt: skip


@pytest.mark.parametrize("path", sorted(ENVELOPE_DIR.glob("*.toml")), ids=lambda p: p.name)
def test_every_shipped_set_states_every_guard(path):
    """The file itself names each guard (no default fills a gap), and the net runs with them."""
    raw = tomllib.loads(path.read_text())["guards"]
    assert set(raw) == set(GUARD_KEYS)
    spec, table = load_envelope(path)
    net = load_net(spec.airframe, path)
    for k in GUARD_KEYS:
        want = None if raw[k] == "off" else float(raw[k])
        assert getattr(spec.guards, k) == want == getattr(net.p, k) == table[k]
    assert spec.guards.gps_jump_m is not None  # the GPS guard is on in every shipped set
    assert wind_limit(spec) == spec.guards.wind_limit_mps  # the campaign drills this limit


def _set(tmp_path, old: str, new: str) -> Path:
    text = GROUNDAIR.read_text()
    assert old in text
    f = tmp_path / "set.toml"
    f.write_text(text.replace(old, new, 1))
    return f


@pytest.mark.parametrize("key", GUARD_KEYS)
def test_a_guard_left_out_is_an_error_naming_the_key_and_the_file(tmp_path, key):
    line = next(ln for ln in GROUNDAIR.read_text().splitlines() if ln.startswith(f"{key} ="))
    f = _set(tmp_path, line, "")
    with pytest.raises(EnvelopeFileError) as e:
        load_envelope(f)
    msg = str(e.value)
    assert key in msg and str(f) in msg and "missing" in msg and "\n" not in msg


@pytest.mark.parametrize(
    "old, new, words",
    [
        ("[guards]", "[guardz]", "missing [guards] table"),
        ("gps_jump_m = 3.0", "gps_jump_m = 0", 'or "off"'),  # 0 is not an "off"
        ("wind_limit_mps = 12.0", "wind_limit_mps = -12.0", "wind_limit_mps must be within"),
        ("link_timeout_s = 1.5", 'link_timeout_s = "no"', "link_timeout_s must be within"),
        (
            "camera_timeout_s = 1.0",
            "camera_timeout_s = 1.0\nsmoke_m = 3.0",
            "unknown key 'smoke_m'",
        ),
        ("hysteresis_s = 2.0", "hysteresis_s = 2.0\ngps_jump_m = 5.0", "state it in [guards]"),
    ],
)
def test_bad_guards_are_refused_in_one_line(tmp_path, old, new, words):
    f = _set(tmp_path, old, new)
    with pytest.raises(EnvelopeFileError) as e:
        load_envelope(f)
    assert words in str(e.value) and str(f) in str(e.value)


def test_off_is_stated_and_turns_the_guard_off(tmp_path):
    f = _set(tmp_path, "gps_jump_m = 3.0", 'gps_jump_m = "off"')
    spec, _ = load_envelope(f)
    assert spec.guards.gps_jump_m is None and load_net("quadrotor", f).p.gps_jump_m is None
    with pytest.raises(ValueError, match="gps_jump_m must be > 0 or None"):
        SupervisorParams(gps_jump_m=0.0)


def test_wind_above_the_limit_flies_the_fallback_while_it_lasts():
    """Scripted on the simulation clock (50 Hz): the autopilot's estimate 3 m/s, a gust front
    to 16 m/s at 4 s (12 m/s limit, tolerance 3 m/s), 8 m/s from 20 s. Closed form of the mean
    w̄ (low-pass τ = wind_mean_s 5 s, Euler at 50 Hz): it passes L + 3 = 15 m/s after
    ln(1/13)/ln(1 − 0.004) = 640 steps (12.8 s) → FALLBACK in the autopilot's own HOLD with
    the reason, held (no PID) until w̄ <= 12 m/s (from 15.47 m/s at 20 s: 3.12 s later); then
    settled → PID → AI."""
    sup = load_net("quadrotor", GROUNDAIR)
    sp = Setpoint(vel_ned=np.array([1.0, 0.0, 0.0]))
    modes, reasons, aps = [], [], []
    for k in range(40 * 50):
        t = k * 0.02
        wind = 3.0 if t < 4.0 - 1e-9 else (16.0 if t < 20.0 - 1e-9 else 8.0)
        d = sup.update(t, st(t), sp, Health(wind_mps=wind))
        modes.append(d.mode)
        reasons.append(d.reason)
        aps.append(d.autopilot_mode)
    first = modes.index(Mode.FALLBACK)
    steps = math.ceil(math.log(1 / 13) / math.log(1 - 0.02 / 5.0))
    assert first == 199 + steps  # the 16 m/s estimate is first averaged in at step 200
    assert reasons[first] == "wind 15.0 m/s (mean) above the airframe's limit 12 m/s"
    w20 = 16.0 - 13.0 * (1 - 0.004) ** 800
    clear = 999 + math.ceil(math.log(4 / (w20 - 8.0)) / math.log(1 - 0.004))
    assert all(m is Mode.FALLBACK for m in modes[first:clear])
    assert all(a is FlightMode.HOLD for a in aps[first:clear])
    assert modes[clear + 60] is Mode.PID and modes[-1] is Mode.AI  # the usual way back
    # a steady wind up to the limit + tolerance never trips; the guard off judges nothing
    at = load_net("quadrotor", GROUNDAIR)
    assert all(at.update(k * 0.02, st(k * 0.02), sp, Health(wind_mps=14.9)).mode is Mode.AI
               for k in range(1000))  # fmt: skip
    off = Supervisor(sup.envelope, SupervisorParams(wind_limit_mps=None))
    assert off.update(0.0, st(0.0), sp, Health(wind_mps=40.0)).mode is Mode.AI


def test_health_tracker_drops_a_stale_or_bad_wind_estimate():
    h = HealthTracker()
    assert h.wind_at(0.0) is None
    h.wind(1.0, 13.5)
    assert h.wind_at(1.0) == 13.5 and h.wind_at(6.0) == 13.5
    assert h.wind_at(6.1) is None  # older than max_wind_age_s (5 s)
    h.wind(0.5, 2.0)  # backwards in time
    h.wind(2.0, float("nan"))
    h.wind(2.0, -1.0)
    assert h.rejected == 3 and h.wind_at(2.0) == 13.5


def test_fly_refuses_wind_above_the_limit_before_anything_starts(tmp_path):
    """Exit 2, one line with the reason and what to do; no run folder, no process."""
    skyherd = str(Path(sys.executable).parent / "skyherd")
    r = subprocess.run([skyherd, "fly", "--wind", "20,180", "--speedup", "0", "--runs-dir",
                        str(tmp_path / "runs")], capture_output=True, text=True, timeout=120)  # fmt: skip
    assert r.returncode == 2, r.stderr
    assert r.stderr.count("\n") == 1 and "Traceback" not in r.stderr
    assert "20.0 m/s is above the quadrotor's wind limit 12 m/s" in r.stderr
    assert "--envelope" in r.stderr and not (tmp_path / "runs").exists()
    r = subprocess.run([skyherd, "fly", "--airframe", "fixedwing", "--wind", "11,0", "--runs-dir",
                        str(tmp_path / "runs")], capture_output=True, text=True, timeout=120)  # fmt: skip
    assert r.returncode == 2 and "fixedwing's wind limit 10 m/s" in r.stderr


def test_a_repeated_sample_is_no_gps_jump():
    """Through a cut link the companion's state keeps the last position and velocity while its
    clock runs on (`skyherd fly --cut-link 22:3` with the guard on tripped "position jumped
    3.2 m" at 22.8 s: 0.8 s × 4.08 m/s dead-reckoned from a frozen sample). A repeated sample
    is no news; after the gap the dead reckoning restarts; a real step is still caught."""
    sup = Supervisor(load_net("quadrotor", GROUNDAIR).envelope, SupervisorParams(gps_jump_m=3.0))
    v = (0.0, -4.0, 0.0)
    t, p = 0.0, np.array([10.0, 0.0, -20.0])
    for _ in range(20):
        assert sup._position_check(st(t, p, v)) == ""
        t, p = t + 0.1, p + [0.0, -0.4, 0.0]
    frozen = st(t, p, v)
    for k in range(30):  # 3 s of the same sample, the clock running on
        assert sup._position_check(VehicleState(t + 0.1 * k, frozen.pos_ned, frozen.vel_ned,
                                                frozen.quat, frozen.omega_frd, frozen.accel_frd,
                                                False)) == ""  # fmt: skip
    t += 3.0
    assert sup._position_check(st(t, p + [0.0, -1.0, 0.0], (0, 0, 0))) == ""  # restarted
    t += 0.1
    why = sup._position_check(st(t, p + [20.0, -1.0, 0.0], (0, 0, 0)))
    assert why.startswith("position jumped 20.0 m")
