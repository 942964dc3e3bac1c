"""`skyherd fly`'s figures of one flight, from its run folder's records: the flight on one time
axis (the mission's phases shaded and named, start and end marked, altitude with the envelope's
ceiling and floor, the features, the safety net's verdict per decision as a coloured strip) and
the track over the fence (inclusion outline, exclusion zones filled).

groundair.png: the UAV over the UGV team, the track inside the fence, the time panels.
track.png (fixed-wing orbit): the orbit inside the fence, its altitude and what the camera saw.
"""

from __future__ import annotations

from contextlib import contextmanager
from pathlib import Path

import numpy as np

# the net's verdict per decision (safety.supervisor.Decision.verdict) → strip colour
VERDICT_COLOURS = {"accepted": "#2ca02c", "projected": "#f2c12e", "rejected": "#ff7f0e",
                   "pid": "#9467bd", "fallback": "#d62728"}  # fmt: skip
PHASE_SHADES = ("#f2f2f2", "#dfe8f3")  # alternating backgrounds of the phases


@contextmanager
def _without_set_docstrings():
    """Imports inside it skip the property tables of the artists' `set()` docstrings: matplotlib
    builds one per Artist class as the class is defined (matplotlib.artist.kwdoc, ~0.07 CPU s of
    a process that only saves figures; `help(Line2D.set)` in that process lists no properties).
    Classes already defined are as they were; matplotlib's kwdoc is back on leaving."""
    import matplotlib.artist as artist

    kwdoc = getattr(artist, "kwdoc", None)
    if kwdoc is not None:
        artist.kwdoc = lambda _artist: ""
    try:
        yield
    finally:
        if kwdoc is not None:
            artist.kwdoc = kwdoc


def pyplot():
    """matplotlib.pyplot on the Agg backend, imported `_without_set_docstrings`. Already
    imported: as it is."""
    import matplotlib

    matplotlib.use("Agg")
    with _without_set_docstrings():
        import matplotlib.pyplot as plt
    return plt


def figure(size):
    """A matplotlib Figure of `size` inches on the Agg canvas, without pyplot: no figure
    manager, no global state to close, and pyplot's import (backend selection) not paid.
    matplotlib is imported `_without_set_docstrings`."""
    with _without_set_docstrings():
        from matplotlib.backends.backend_agg import FigureCanvasAgg
        from matplotlib.figure import Figure

    fig = Figure(figsize=size)
    FigureCanvasAgg(fig)
    return fig


def phase_spans(track_rows: list[dict], column: str = "phase") -> list[tuple[float, float, str]]:
    """(start, end, value) of each run of one value of a metrics.csv column: the companion's
    phases ("phase"), or the autopilot's modes as its heartbeats said them ("mode")."""
    spans: list[list] = []
    for r in track_rows:
        t, ph = float(r["t"]), r.get(column) or ""
        if spans and spans[-1][2] == ph:
            spans[-1][1] = t
        else:
            if spans:
                spans[-1][1] = t
            spans.append([t, t, ph])
    return [tuple(s) for s in spans if s[2]]


def shade_phases(axes, spans, label_ax=None) -> None:
    """Each phase a background band on every time axis; its name over `label_ax` (a phase
    shorter than 2 % of the flight is shaded, unnamed: its name would cover its neighbour's)."""
    whole = max((s[1] for s in spans), default=0.0) - min((s[0] for s in spans), default=0.0)
    runs = [(t0, t1 - t0) for t0, t1, _ in spans]
    shades = [PHASE_SHADES[k % 2] for k in range(len(spans))]
    for ax in axes if spans else ():  # one collection per axis, the bands its whole height
        ax.broken_barh(runs, (0, 1), color=shades, lw=0, zorder=0,
                       transform=ax.get_xaxis_transform())  # fmt: skip
    for t0, t1, ph in spans:
        if label_ax is not None and t1 - t0 >= 0.02 * whole:
            label_ax.text((t0 + t1) / 2, 1.02, ph, transform=label_ax.get_xaxis_transform(),
                          ha="center", va="bottom", fontsize=7, rotation=30, clip_on=False)  # fmt: skip


def mark_start_end(axes, t_start: float | None, t_end: float | None) -> None:
    """Dashed lines at the hand-over to the AI and at its end (companion.json's authority)."""
    for t, what in ((t_start, "AI starts"), (t_end, "AI ends")):
        if t is None:
            continue
        for ax in axes:
            ax.axvline(t, color="k", ls="--", lw=0.8, zorder=1)
        axes[-1].annotate(what, (t, 0), xycoords=("data", "axes fraction"), xytext=(2, 2),
                          textcoords="offset points", fontsize=7)  # fmt: skip


def verdict_strip(ax, decisions: list[dict], t_end: float) -> None:
    """The net's verdict per decision as a coloured strip (each lasts until the next, the last
    one a median decision period); a legend with each verdict's count."""
    from matplotlib.patches import Patch

    ts = [float(d["t"]) for d in decisions]
    period = float(np.median(np.diff(ts))) if len(ts) > 1 else 0.5
    counts: dict[str, int] = {}
    spans: dict[str, list[tuple[float, float]]] = {}  # verdict → its runs (start, width)
    for k, d in enumerate(decisions):
        v = d.get("verdict", "")
        counts[v] = counts.get(v, 0) + 1
        t1 = ts[k + 1] if k + 1 < len(ts) else min(ts[k] + period, max(t_end, ts[k] + period))
        same = k > 0 and decisions[k - 1].get("verdict", "") == v
        if same:  # the run of this verdict goes on: one rectangle, not one per decision
            t0, _ = spans[v][-1]
            spans[v][-1] = (t0, t1 - t0)
        else:
            spans.setdefault(v, []).append((ts[k], t1 - ts[k]))
    for v, runs in spans.items():  # one collection per verdict: drawn at a fraction of the cost
        ax.broken_barh(runs, (0, 1), color=VERDICT_COLOURS.get(v, "grey"), lw=0)
    ax.set_yticks([])
    ax.set_ylim(0, 1)
    ax.set_ylabel("the net's\nverdict", rotation=0, ha="right", va="center", fontsize=8)
    handles = [Patch(color=VERDICT_COLOURS.get(v, "grey"), label=f"{v} ({counts[v]})")
               for v in VERDICT_COLOURS if v in counts]  # fmt: skip
    handles += [Patch(color="grey", label=f"{v} ({n})") for v, n in counts.items()
                if v not in VERDICT_COLOURS]  # fmt: skip
    if handles:
        ax.legend(handles=handles, fontsize=7, ncol=len(handles), loc="upper center",
                  bbox_to_anchor=(0.5, -2.6), frameon=False,
                  title="the net's verdict per decision (count)", title_fontsize=7)  # fmt: skip


def mode_strip(ax, track_rows: list[dict]) -> None:
    """The autopilot's mode over time (metrics.csv), each run of a mode a named segment."""
    import matplotlib

    cmap = matplotlib.colormaps["Pastel1"]
    names: dict[str, int] = {}
    spans = phase_spans(track_rows, "mode")
    whole = max((s[1] for s in spans), default=0.0) - min((s[0] for s in spans), default=0.0)
    colours = [cmap(names.setdefault(mode, len(names)) % cmap.N) for _, _, mode in spans]
    if spans:  # one collection, a colour per run: the pixels of one per run, at less cost
        ax.broken_barh([(t0, max(t1 - t0, 1e-3)) for t0, t1, _ in spans], (0, 1), color=colours,
                       lw=0)  # fmt: skip
    for t0, t1, mode in spans:
        if t1 - t0 >= 0.04 * whole:
            ax.text((t0 + t1) / 2, 0.5, mode, ha="center", va="center", fontsize=7)
    ax.set_yticks([])
    ax.set_ylim(0, 1)
    ax.set_ylabel("autopilot\nmode", rotation=0, ha="right", va="center", fontsize=8)


def draw_fence(ax, envelope: dict | None) -> None:
    """The envelope's inclusion polygons (outline) and exclusion zones (filled), east right,
    north up (config.json's envelope: points as [north, east])."""
    if not envelope:
        return
    for k, (name, pts) in enumerate((envelope.get("inclusions") or {}).items()):
        p = np.asarray(pts, float).reshape(-1, 2)
        p = np.vstack([p, p[:1]])
        ax.plot(p[:, 1], p[:, 0], "-", color="tab:red", lw=1.2,
                label=f"fence: {name}" if k == 0 else None)  # fmt: skip
    for k, (name, pts) in enumerate((envelope.get("exclusions") or {}).items()):
        p = np.asarray(pts, float).reshape(-1, 2)
        ax.fill(p[:, 1], p[:, 0], color="tab:red", alpha=0.35, lw=0,
                label="exclusion zone" if k == 0 else None)  # fmt: skip
        ax.annotate(name.split(" (")[0], (p[:, 1].mean(), p[:, 0].mean()), fontsize=7,
                    ha="center", va="center")  # fmt: skip


def legend(ax, loc: str) -> None:
    """The axis's legend (7 pt) at `loc`; none when the axis names nothing (no empty box, and
    no warning from matplotlib)."""
    if ax.get_legend_handles_labels()[0]:
        ax.legend(fontsize=7, loc=loc)


def altitude_limits(ax, envelope: dict | None, floor: bool = True) -> None:
    lim = (envelope or {}).get("limits") or {}
    if lim.get("ceiling_m") is not None:
        ax.axhline(lim["ceiling_m"], color="tab:red", lw=1, ls="-", label="ceiling")
    if floor and lim.get("floor_m"):
        ax.axhline(lim["floor_m"], color="tab:red", lw=1, ls=":", label="floor (AI phase)")


def _track(rows: list[dict]) -> np.ndarray:
    return np.array([[float(r["t"]), float(r["north"]), float(r["east"]), float(r["down"])]
                     for r in rows]).reshape(-1, 4)  # fmt: skip


def _ugvs(world: list[dict]) -> int:
    return sum(1 for k in (world[0] if world else {}) if k.startswith("ugv") and k.endswith("_n"))


def _time_panels(fig, grid, n: int):
    """n time axes stacked in `grid` sharing x; the last two (the strips) thin."""
    from matplotlib.gridspec import GridSpecFromSubplotSpec

    sub = GridSpecFromSubplotSpec(n, 1, grid, height_ratios=[3] * (n - 2) + [0.55, 0.55],
                                  hspace=0.15)  # fmt: skip
    axes = [fig.add_subplot(sub[0])]
    axes += [fig.add_subplot(sub[i], sharex=axes[0]) for i in range(1, n)]
    for ax in axes[:-1]:
        ax.xaxis.set_tick_params(labelbottom=False)
    axes[-1].set_xlabel("simulation time [s]")
    return axes


def ticks_once(fig) -> None:
    """Each axis's ticks placed and written once, where and as its default locator and formatter
    put them in the figure's final view: matplotlib asks the locator and formatter again at each
    layout step of the drawing (a few dozen times in a figure of 6 axes) and makes a Tick (three
    lines, two texts) for each location it gets, the ones outside the view too. Call it when the
    figure is complete (limits, aspect, size, margins): the picture is the one drawn without it.
    An axis not linear, or whose formatter writes an offset or a multiplier (its corner text),
    keeps its own."""
    from matplotlib.ticker import FixedFormatter, FixedLocator

    for ax in fig.axes:
        ax.apply_aspect()  # the view limits an equal aspect ("datalim") sets at drawing
    done = set()
    for axis in (a for ax in fig.axes for a in (ax.xaxis, ax.yaxis)):
        if id(axis.major) in done:  # axes sharing x share their locator and formatter
            continue
        done.add(id(axis.major))
        locator, formatter = axis.get_major_locator(), axis.get_major_formatter()
        if axis.get_scale() != "linear" or isinstance(locator, FixedLocator):
            continue  # set_yticks([]) (the strips) is fixed already
        locs = list(locator())
        labels = formatter.format_ticks(locs)  # written as they are among all the locations
        if formatter.get_offset():
            continue
        lo, hi = sorted(axis.get_view_interval())
        tol = (hi - lo) * 1e-10  # matplotlib's own: a tick at the view's edge is drawn
        keep = [k for k, x in enumerate(locs) if lo - tol <= x <= hi + tol]
        axis.set_major_locator(FixedLocator([locs[k] for k in keep]))
        axis.set_major_formatter(FixedFormatter([labels[k] for k in keep]))


def _finish(fig, axes, decisions, authority: dict, t_end: float, path: Path) -> Path:
    """The time panels' common end: the verdict strip (axes[2]), the AI's start and end, the
    time span; the figure saved to `path`."""
    verdict_strip(axes[2], decisions, t_end)
    mark_start_end(axes, authority.get("t_start"), authority.get("t_end"))
    axes[0].set_xlim(0, max(t_end, 1.0))
    fig.subplots_adjust(left=0.05, right=0.99, top=0.88, bottom=0.22)
    ticks_once(fig)
    fig.savefig(path, dpi=100)
    return path


def plot_groundair(run_dir: Path, decisions, track_rows, world, envelope, authority) -> Path:
    """groundair.png (module docstring)."""
    from matplotlib.gridspec import GridSpec

    fig = figure((16, 6.2))
    gs = GridSpec(1, 3, figure=fig, width_ratios=[1, 1, 1.7], wspace=0.28)
    team, fence = fig.add_subplot(gs[0]), fig.add_subplot(gs[1])
    alt, feat, net, modes = _time_panels(fig, gs[2], 4)
    track = _track(track_rows)
    t_dec = np.array([float(d["t"]) for d in decisions])
    t0 = t_dec[0] if len(t_dec) else 0.0
    moving = [r for r in world if float(r["t"]) >= t0]
    for i in range(_ugvs(world)):
        team.plot([float(r[f"ugv{i}_e"]) for r in moving], [float(r[f"ugv{i}_n"]) for r in moving],
                  lw=0.8, alpha=0.8, label=f"UGV {i}")  # fmt: skip
    for ax, sel in ((team, track[:, 0] >= t0), (fence, np.ones(len(track), bool))):
        if sel.any():
            ax.plot(track[sel, 2], track[sel, 1], "k-", lw=1.3, label="UAV")
            ax.plot(track[sel][0, 2], track[sel][0, 1], "o", color="tab:green", ms=6, label="start")
            ax.plot(track[sel][-1, 2], track[sel][-1, 1], "s", color="k", ms=6, label="end")
    team.set(xlabel="east [m]", ylabel="north [m]", title="UAV over the UGV team, AI phase")
    draw_fence(fence, envelope)
    fence.set(xlabel="east [m]", ylabel="north [m]", title="the whole flight inside the fence")
    for ax in (team, fence):
        ax.set_aspect("equal", adjustable="datalim")
        legend(ax, "upper left" if ax is team else "best")  # the fence's corners hold its zones
    spans = phase_spans(track_rows)
    shade_phases([alt, feat, net], spans, label_ax=alt)
    mode_strip(modes, track_rows)
    if len(track):
        alt.plot(track[:, 0], -track[:, 3], "k-", lw=1.2, label="altitude (autopilot's estimate)")
    altitude_limits(alt, envelope)
    alt.set_ylabel("altitude above\nhome [m]")
    legend(alt, "upper right")
    if decisions:
        phi = np.array([d["phi"] for d in decisions if d.get("phi") is not None]).reshape(-1, 8)
        tp = np.array([float(d["t"]) for d in decisions if d.get("phi") is not None])
        if len(tp):
            feat.step(tp, phi[:, 5], "g-", where="post", label="all UGVs in view (φ6)")
            feat.plot(tp, phi[:, 2], "b-", label="spread (φ3)")
    feat.set_ylim(-0.05, 1.1)
    feat.set_ylabel("feature [0..1]")
    legend(feat, "lower left")
    t_end = float(track[-1, 0]) if len(track) else 1.0
    return _finish(fig, [alt, feat, net, modes], decisions, authority, t_end,
                   run_dir / "groundair.png")  # fmt: skip


def plot_orbit(run_dir: Path, world, track_rows, plan: dict, t_est, envelope, authority,
               sight: list[dict], decisions: list[dict]) -> Path:  # fmt: skip
    """track.png of the fixed-wing orbit (module docstring)."""
    from matplotlib.gridspec import GridSpec

    fig = figure((16, 7))
    gs = GridSpec(1, 2, figure=fig, width_ratios=[1, 1.5], wspace=0.2)
    ax = fig.add_subplot(gs[0])
    alt, seen, net, modes = _time_panels(fig, gs[1], 4)
    n_ugv = _ugvs(world)
    w = np.array([[float(r["t"]), float(r["north"]), float(r["east"]), float(r["down"])]
                  for r in world]).reshape(-1, 4)  # fmt: skip
    draw_fence(ax, envelope)
    if len(w):
        c = np.array([np.mean([[float(r[f"ugv{i}_n"]), float(r[f"ugv{i}_e"])] for i in range(n_ugv)],
                              axis=0) for r in world]).reshape(-1, 2)  # fmt: skip
        ax.plot(w[:, 2], w[:, 1], "-", lw=0.8, color="tab:blue", label="aircraft (truth)")
        ax.plot(c[:, 1], c[:, 0], "-", lw=1.5, color="tab:green", label="UGV team centre (truth)")
        ax.plot(w[0, 2], w[0, 1], "o", color="tab:green", ms=6, label="start")
        ax.plot(w[-1, 2], w[-1, 1], "s", color="k", ms=6, label="end")
        if t_est is not None and plan:
            k = min(int(np.searchsorted(w[:, 0], t_est)), len(c) - 1)
            a = np.linspace(0, 2 * np.pi, 200)
            R = plan["radius_m"]
            ax.plot(c[k, 1] + R * np.sin(a), c[k, 0] + R * np.cos(a), "k:", lw=1,
                    label=f"planned orbit R = {R:.0f} m (at t = {t_est:.0f} s)")  # fmt: skip
    ax.set(xlabel="east [m]", ylabel="north [m]", title="fixed-wing orbit inside the fence (NED)")
    ax.set_aspect("equal", adjustable="datalim")
    ax.legend(fontsize=7, loc="best")
    spans = phase_spans(track_rows)
    shade_phases([alt, seen, net], spans, label_ax=alt)
    mode_strip(modes, track_rows)
    if len(w):
        alt.plot(w[:, 0], -w[:, 3], "-", color="tab:blue", lw=1.2, label="altitude (truth)")
    if plan.get("altitude_m") is not None:
        alt.axhline(plan["altitude_m"], color="k", ls=":", lw=1, label="planned h")
    altitude_limits(alt, envelope)
    alt.set_ylabel("altitude above\nhome [m]")
    legend(alt, "upper right")
    if sight:
        ts = np.array([float(r["t"]) for r in sight])
        seen.plot(ts, [int(r["detected"]) for r in sight], "-", color="tab:green", lw=0.8,
                  label="UGVs detected")  # fmt: skip
        seen.axhline(n_ugv, color="k", ls=":", lw=1, label=f"team ({n_ugv})")
        seen.legend(fontsize=7, loc="lower right")
    seen.set_ylabel("UGVs detected\n(camera)")
    t_end = float(w[-1, 0]) if len(w) else 1.0
    return _finish(fig, [alt, seen, net, modes], decisions, authority, t_end,
                   run_dir / "track.png")  # fmt: skip
