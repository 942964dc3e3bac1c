"""One safety-net wiring (issue 26 item 1): the supervisor's Health is built in one place
(safety.net.SafetyNet.health), a decision is mapped onto an autopilot mode in one place
(safety.net.autopilot_mode_for), and every loop — the ground-air and square missions, the orbit,
the formation, the drills — flies a SafetyNet. Checked on the source tree (AST, so comments and
docstrings do not count) and on the net's behaviour."""

import ast
from pathlib import Path

import numpy as np
import pytest

from skyherd.flight.autopilot_api import FlightMode, Setpoint
from skyherd.flight.multirotor.autopilot import MultirotorAutopilot
from skyherd.safety.net import SafetyNet, autopilot_mode_for, load_net
from skyherd.safety.supervisor import Decision, Mode, Severity

ROOT = Path(__file__).resolve().parents[2] / "skyherd"
PACKAGES = ("runio", "flight", "groundsim", "perception", "policy", "safety", "hil", "record",
            "world", "mission", "scripts", "../bench")  # fmt: skip


def _sources():
    for pkg in PACKAGES:
        for path in sorted((ROOT / pkg).rglob("*.py")):
            yield path, ast.parse(path.read_text(), str(path))


def _calls(tree: ast.AST, name: str):
    for node in ast.walk(tree):
        if isinstance(node, ast.Call):
            f = node.func
            called = (
                f.id if isinstance(f, ast.Name) else f.attr if isinstance(f, ast.Attribute) else ""
            )
            if called == name:
                yield node


def test_health_is_built_in_one_place():
    """Health(...) is constructed only by SafetyNet (and as the supervisor's own default)."""
    builders = {
        str(path.relative_to(ROOT)): len(list(_calls(tree, "Health"))) for path, tree in _sources()
    }
    builders = {k: n for k, n in builders.items() if n}
    assert set(builders) <= {"safety/net.py", "safety/supervisor.py"}, builders
    net_tree = ast.parse((ROOT / "safety/net.py").read_text())
    fns = {
        node.name: len(list(_calls(node, "Health")))
        for node in ast.walk(net_tree)
        if isinstance(node, ast.FunctionDef)
    }
    assert fns["health"] == 1  # SafetyNet.health: the one builder (warm_up passes the default)
    assert sum(fns.values()) == 1, fns


def test_decisions_are_mapped_to_modes_in_one_place():
    """Nobody but safety/net.py compares a decision's autopilot_mode with HOLD, and the profile's
    fallback_mode is read by nobody (the old per-mission mapping)."""
    for path, tree in _sources():
        rel = str(path.relative_to(ROOT))
        for node in ast.walk(tree):
            if isinstance(node, ast.Attribute) and node.attr == "fallback_mode":
                assert rel == "hil/autopilots.py", f"{rel}:{node.lineno} maps modes itself"
            if isinstance(node, ast.Compare) and rel != "safety/net.py":
                text = ast.unparse(node)
                assert not ("autopilot_mode" in text and "HOLD" in text), f"{rel}:{node.lineno}"


@pytest.mark.parametrize("module,cls", [("skyherd.mission.flight", "SingleVehicleMission"),
                                        ("skyherd.mission.orbit", "OrbitMission"),
                                        ("skyherd.mission.formation", "FormationNet")])  # fmt: skip
def test_every_loop_flies_a_safety_net(module, cls):
    src = (ROOT.parent / (module.replace(".", "/") + ".py")).read_text()
    tree = ast.parse(src)
    (node,) = [n for n in ast.walk(tree) if isinstance(n, ast.ClassDef) and n.name == cls]
    body = ast.unparse(node)
    assert ".step(" in body and "Supervisor(" not in body.replace("Supervisor(spec.envelope()", "")
    assert ".update(t, state" not in body  # no direct supervisor.update with a Health of its own


def _decision(mode: Mode, ap: FlightMode) -> Decision:
    sp = Setpoint(vel_ned=np.zeros(3))
    return Decision(sp, mode, Severity.FALLBACK, "", ap, False)


def test_the_mapping():
    assert autopilot_mode_for(_decision(Mode.FALLBACK, FlightMode.HOLD)) is FlightMode.HOLD
    # the autopilot's hold not trusted (ParamGuard): the fallback is flown as a setpoint
    assert autopilot_mode_for(_decision(Mode.FALLBACK, FlightMode.OFFBOARD)) is FlightMode.OFFBOARD
    assert (
        autopilot_mode_for(_decision(Mode.FALLBACK, FlightMode.HOLD), False) is FlightMode.OFFBOARD
    )
    assert autopilot_mode_for(_decision(Mode.PID, FlightMode.OFFBOARD)) is FlightMode.OFFBOARD
    assert autopilot_mode_for(_decision(Mode.AI, FlightMode.OFFBOARD)) is FlightMode.OFFBOARD


def _hover_state():
    return MultirotorAutopilot(start_pos_ned=(0.0, 0.0, -20.0)).state


def test_a_camera_that_never_delivered_is_lost_from_the_handover():
    """The blind flight of the issue: no frame ever. The camera is lost camera_timeout_s after
    the hand-over (a net event and the fallback), not unmonitored."""
    net = SafetyNet(load_net("quadrotor"), camera=True)
    st = _hover_state()
    net.handover(10.0, FlightMode.OFFBOARD)
    modes = []
    for k in range(40):  # 0.8 s of 20 ms ticks past the 1 s timeout
        t = 10.0 + 0.05 * k
        net.link(t, t)
        d = net.step(t, st, Setpoint(vel_ned=np.zeros(3)) if k % 4 == 0 else None)
        modes.append((t, d.mode, d.reason))
    lost = [(t, r) for t, m, r in modes if m is Mode.FALLBACK]
    assert lost and "camera" in lost[0][1]
    assert lost[0][0] == pytest.approx(10.0 + net.p.camera_timeout_s, abs=0.051)


def test_a_camera_that_delivers_keeps_the_ai_flying():
    net = SafetyNet(load_net("quadrotor"), camera=True)
    st = _hover_state()
    net.handover(10.0, FlightMode.OFFBOARD)
    for k in range(60):
        t = 10.0 + 0.05 * k
        net.link(t, t)
        if k % 2 == 0:
            net.frame(t)
        d = net.step(t, st, Setpoint(vel_ned=np.zeros(3)) if k % 4 == 0 else None)
        assert d.mode is Mode.AI, d.reason
    assert net.request(d) is None  # OFFBOARD is what the heartbeat shows: nothing to ask
