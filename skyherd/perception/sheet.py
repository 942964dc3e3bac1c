"""A contact sheet of a flight's camera frames (frames.png, watch's strip.png): a bounded,
evenly spread sample of annotated frames, each labelled with its simulation time, altitude and
phase, and a legend band that says what the marks are.

`FrameSample` keeps at most `2 * max_tiles` frames whatever the flight's length: one every
`every_s` of simulation time, and when full it drops every other one and doubles the interval
(the kept frames stay evenly spread over the whole flight). The sheet shows at most
`max_tiles`, a whole number of rows (no empty tile), the first and the last frame included.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from skyherd.perception.detector import BLUE, GREEN, RED, Detections, annotate, contact_sheet

FONT = cv2.FONT_HERSHEY_SIMPLEX
LABEL_SCALE = 0.75  # tile labels: legible when a sheet of 4 columns is shown page-wide
LEGEND_SCALE = 0.7


@dataclass(frozen=True)
class SheetParams:
    max_tiles: int = 12  # tiles on the sheet, whatever the flight's length
    cols: int = 4  # tiles per row
    every_s: float = 6.0  # first sampling interval [s of simulation time]; doubles when full
    scale: int = 2  # annotated frames are this many times the camera's pixels

    def __post_init__(self) -> None:
        if not (self.cols >= 1 and self.max_tiles >= self.cols and self.every_s > 0):
            raise ValueError(f"SheetParams: need cols >= 1, max_tiles >= cols, every_s > 0: {self}")


@dataclass(frozen=True)
class Sample:
    t: float  # simulation time [s]
    image: np.ndarray  # the received frame, RGB (H, W, 3)
    det: Detections
    altitude_m: float  # the autopilot's estimate at capture [m above home]; nan if unknown
    phase: str  # the mission's phase when it arrived ("" if unknown)


class FrameSample:
    """Frames kept for the sheet (module docstring); `add` is cheap (no drawing)."""

    def __init__(self, params: SheetParams = SheetParams()):
        self.p = params
        self.every_s = params.every_s
        self.kept: list[Sample] = []
        self.last: Sample | None = None  # the newest frame: the sheet ends on it

    def __bool__(self) -> bool:
        return self.last is not None

    def add(self, t: float, image: np.ndarray, det: Detections, altitude_m: float = float("nan"),
            phase: str = "") -> None:  # fmt: skip
        s = Sample(float(t), image, det, float(altitude_m), str(phase))
        self.last = s
        if self.kept and t < self.kept[-1].t + self.every_s:
            return
        self.kept.append(s)
        if len(self.kept) > 2 * self.p.max_tiles:
            self.kept = self.kept[::2]
            self.every_s *= 2.0

    def chosen(self) -> list[Sample]:
        """At most max_tiles samples, a whole number of rows, evenly spread, first and last."""
        pool = list(self.kept)
        if self.last is not None and (not pool or self.last.t > pool[-1].t):
            pool.append(self.last)
        if len(pool) <= self.p.cols:
            return pool
        n = min(self.p.max_tiles, len(pool)) // self.p.cols * self.p.cols
        idx = np.unique(np.linspace(0, len(pool) - 1, n).round().astype(int))
        return [pool[i] for i in idx]

    def sheet(self) -> np.ndarray | None:
        """The annotated, labelled tiles and the legend band (None: no frame arrived)."""
        chosen = self.chosen()
        if not chosen:
            return None
        tiles = [annotate(s.image, s.det, scale=self.p.scale) for s in chosen]
        sheet = contact_sheet(label(tiles, [tile_label(s) for s in chosen]),
                              cols=min(self.p.cols, len(tiles)))  # fmt: skip
        return np.vstack([sheet, legend(sheet.shape[1])])


def tile_label(s: Sample) -> str:
    alt = "" if not np.isfinite(s.altitude_m) else f"  {round(s.altitude_m, 1) + 0.0:.1f} m"
    return f"t {s.t:.1f} s{alt}" + (f"  {s.phase}" if s.phase else "")


def label(tiles: list[np.ndarray], labels: list[str]) -> list[np.ndarray]:
    """Each tile with its label in the bottom-left corner, white on a dark band (the detector's
    count sits top-left)."""
    out = []
    for img, text in zip(tiles, labels):
        img = img.copy()
        w = cv2.getTextSize(text, FONT, LABEL_SCALE, 2)[0][0]
        h = img.shape[0]
        cv2.rectangle(img, (0, h - 30), (min(img.shape[1], 12 + w), h), (0, 0, 0), -1)
        cv2.putText(img, text, (5, h - 9), FONT, LABEL_SCALE, (255, 255, 255), 2, cv2.LINE_AA)
        out.append(img)
    return out


def legend(width: int, label_says: str = "sim time, altitude above home, phase") -> np.ndarray:
    """A band saying what the marks are (the colours of perception.detector.annotate), wrapped
    onto as many lines as the width needs."""
    items = (("dot", RED, "image centre"), ("dot", BLUE, "UGVs' centre of mass"),
             ("ring", BLUE, "their spread (enclosing circle)"), ("ring", GREEN, "a detected UGV"),
             ("text", None, f"label: {label_says}"))  # fmt: skip
    placed, x, line = [], 8, 0
    for kind, colour, text in items:
        w = (18 if kind != "text" else 0) + cv2.getTextSize(text, FONT, LEGEND_SCALE, 1)[0][0]
        if x > 8 and x + w > width - 8:
            x, line = 8, line + 1
        placed.append((kind, colour, text, x, line))
        x += w + 24
    band = np.full((34 * (line + 1), width, 3), 255, np.uint8)
    for kind, colour, text, x, line in placed:
        y = 17 + 34 * line
        if kind != "text":
            filled = kind == "dot"
            cv2.circle(band, (x + 6, y), 5 if filled else 7, colour, -1 if filled else 2,
                       cv2.LINE_AA)  # fmt: skip
            x += 18
        cv2.putText(band, text, (x, y + 7), FONT, LEGEND_SCALE, (0, 0, 0), 1, cv2.LINE_AA)
    return band
