"""report.plots_flight's figures from a small made-up run (no flight): groundair.png and the
orbit's track.png are drawn with every panel, its labels, legends and strips; the ticks set once
(ticks_once) draw the picture matplotlib's own ticking draws, pixel for pixel."""

from __future__ import annotations

import warnings

import cv2
import numpy as np
import pytest

from skyherd.report import plots_flight
from skyherd.report.plots_flight import VERDICT_COLOURS, plot_groundair, plot_orbit

ENVELOPE = {
    "inclusions": {"exercise area": [[-200, -200], [-200, 200], [200, 200], [200, -200]]},
    "exclusions": {"tower (mast)": [[170, -190], [170, -170], [190, -170], [190, -190]]},
    "limits": {"ceiling_m": 60.0, "floor_m": 5.0},
}
AUTHORITY = {"t_start": 9.0, "t_end": 85.0}
PHASES = ((10, "takeoff", "TAKEOFF"), (70, "policy", "OFFBOARD"), (85, "descend", "OFFBOARD"),
          (100, "land", "LAND"))  # fmt: skip


def _phase(t: float) -> tuple[str, str]:
    return next((ph, mode) for end, ph, mode in PHASES if t < end or end == 100)


def _run(n_ugv: int = 3):
    ts = np.arange(0.0, 100.0, 0.5)
    track = [{"t": f"{t}", "north": f"{t / 3:.2f}", "east": f"{5 * np.sin(t / 9):.2f}",
              "down": f"{-min(t, 20.0):.2f}", "phase": _phase(t)[0], "mode": _phase(t)[1]}
             for t in ts]  # fmt: skip
    world = [{"t": f"{t}", **{k: f"{v:.2f}" for i in range(n_ugv)
                              for k, v in ((f"ugv{i}_n", 10 * i + t / 4), (f"ugv{i}_e", 3 * i - t / 9))}}
             for t in ts]  # fmt: skip
    decisions = [{"t": t, "verdict": "projected" if k % 3 == 0 else "accepted",
                  "phi": [0.1, 0.2, 0.3 + t / 400, 0.4, 0.5, float(t < 70), 0.7, 0.8]}
                 for k, t in enumerate(np.arange(10.0, 85.0, 0.5))]  # fmt: skip
    return decisions, track, world


@pytest.fixture
def figures(monkeypatch):
    """Every Figure report.plots_flight makes, kept for the test to look into."""
    made = []

    def figure(size):
        made.append(_figure(size))
        return made[-1]

    _figure = plots_flight.figure
    monkeypatch.setattr(plots_flight, "figure", figure)
    return made


def _texts(ax) -> set[str]:
    return {t.get_text() for t in ax.texts}


def _legend(ax) -> list[str]:
    leg = ax.get_legend()
    return [t.get_text() for t in leg.get_texts()] if leg is not None else []


def test_groundair_png_has_its_panels_labels_legends_and_strips(tmp_path, figures):
    decisions, track, world = _run()
    path = plot_groundair(tmp_path, decisions, track, world, ENVELOPE, AUTHORITY)
    assert path == tmp_path / "groundair.png"
    img = cv2.imread(str(path))
    assert img is not None and img.shape[:2] == (620, 1600)  # 16 x 6.2 in at 100 dpi
    (fig,) = figures
    team, fence, alt, feat, net, modes = fig.axes
    assert team.get_title() == "UAV over the UGV team, AI phase"
    assert fence.get_title() == "the whole flight inside the fence"
    assert _legend(team) == ["UGV 0", "UGV 1", "UGV 2", "UAV", "start", "end"]
    assert _legend(fence) == ["UAV", "start", "end", "fence: exercise area", "exclusion zone"]
    assert "tower" in _texts(fence)
    assert _legend(alt) == ["altitude (autopilot's estimate)", "ceiling", "floor (AI phase)"]
    assert _legend(feat) == ["all UGVs in view (φ6)", "spread (φ3)"]
    assert _legend(net) == ["accepted (100)", "projected (50)"]
    assert {"takeoff", "policy", "descend", "land"} <= _texts(alt)  # the phases named
    assert {"TAKEOFF", "OFFBOARD", "LAND"} <= _texts(modes)  # the autopilot's modes
    assert {"AI starts", "AI ends"} <= _texts(modes)
    # the time panels share one time axis, labelled on the lowest only
    assert all(ax.get_shared_x_axes().joined(alt, ax) for ax in (feat, net, modes))
    assert alt.get_xlim() == modes.get_xlim() == (0.0, 99.5)
    assert modes.get_xlabel() == "simulation time [s]"
    for ax in (alt, feat, net):
        assert not any(t.label1.get_visible() for t in ax.xaxis.get_major_ticks())
    assert [t.get_text() for t in modes.get_xticklabels()] == ["0", "20", "40", "60", "80"]
    # the verdict strip in the net's colours; the phases as bands on the three upper panels
    rgb = img[:, :, ::-1].reshape(-1, 3).astype(int)
    for v in ("accepted", "projected"):
        colour = [int(VERDICT_COLOURS[v][k : k + 2], 16) for k in (1, 3, 5)]
        assert (np.abs(rgb - colour).sum(axis=1) < 6).sum() > 200, v


def test_groundair_png_without_records_is_still_drawn(tmp_path, figures):
    """No decision, no track, no envelope: the panels, empty, without an empty legend box
    (matplotlib warned "No artists with labels found to put in legend")."""
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        path = plot_groundair(tmp_path, [], [], [], None, {})
    assert cv2.imread(str(path)).shape[:2] == (620, 1600)
    assert len(figures[0].axes) == 6
    assert all(ax.get_legend() is None for ax in figures[0].axes)


def test_orbit_track_png_has_its_panels(tmp_path, figures):
    decisions, track, world = _run(n_ugv=2)
    world = [{**w, "north": f"{120 * np.cos(float(w['t']) / 20):.2f}",
              "east": f"{120 * np.sin(float(w['t']) / 20):.2f}", "down": "-40"} for w in world]  # fmt: skip
    sight = [{"t": w["t"], "detected": "2"} for w in world[::4]]
    path = plot_orbit(tmp_path, world, track, {"radius_m": 120.0, "altitude_m": 40.0}, 30.0,
                      ENVELOPE, AUTHORITY, sight, decisions)  # fmt: skip
    assert cv2.imread(str(path)).shape[:2] == (700, 1600)
    ax, alt, seen, net, modes = figures[0].axes
    assert ax.get_title() == "fixed-wing orbit inside the fence (NED)"
    assert "planned orbit R = 120 m (at t = 30 s)" in _legend(ax)
    assert _legend(seen) == ["UGVs detected", "team (2)"]
    assert _legend(net) == ["accepted (100)", "projected (50)"]


@pytest.mark.parametrize("offset", [0.0, 1e4])
def test_ticks_set_once_draw_the_picture_matplotlib_draws(tmp_path, monkeypatch, figures, offset):
    """groundair.png with ticks_once and without it (matplotlib placing and writing the ticks at
    each step of the drawing): the same pixels; also with an axis whose ticks are written with an
    offset (the fence's north: 1e4 m away, 3 mm of track, no fence drawn), which keeps its own."""
    decisions, track, world = _run()
    envelope = ENVELOPE
    if offset:
        track = [{**r, "north": f"{offset + float(r['north']) / 1e4}"} for r in track]
        envelope = None
    plot_groundair(tmp_path, decisions, track, world, envelope, AUTHORITY)
    once = cv2.imread(str(tmp_path / "groundair.png"), cv2.IMREAD_UNCHANGED)
    assert bool(figures[0].axes[1].yaxis.get_offset_text().get_text()) == bool(offset)
    monkeypatch.setattr(plots_flight, "ticks_once", lambda fig: None)
    plot_groundair(tmp_path, decisions, track, world, envelope, AUTHORITY)
    every = cv2.imread(str(tmp_path / "groundair.png"), cv2.IMREAD_UNCHANGED)
    assert np.array_equal(once, every)
