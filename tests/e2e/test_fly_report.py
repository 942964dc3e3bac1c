"""What a reader of a run folder meets: report.html (one self-contained page: the verdict, the
judge's checks with figures, the tables, every figure embedded), groundair.png on one time
axis, frames.png with a bounded number of labelled tiles whatever the flight's length. The
page is checked structurally (its HTML parsed), and rendered in headless Chromium when the
machine has it (Debian's `chromium`; .ci/run installs it)."""

from __future__ import annotations

import base64
import hashlib
import json
import shutil
import subprocess
import sys
from html.parser import HTMLParser
from pathlib import Path

import cv2
import numpy as np
import pytest

from skyherd.perception.detector import Detector
from skyherd.perception.sheet import FrameSample, SheetParams
from skyherd.report.page import REPORT, markdown_to_html, write_report_html
from skyherd.scripts.cli import main
from skyherd.task.params import TaskParams

CHROMIUM = shutil.which("chromium") or shutil.which("chromium-browser")


class Page(HTMLParser):
    """The parts of report.html the tests look at."""

    def __init__(self):
        super().__init__()
        self.imgs, self.links, self.scripts, self.ids = [], [], 0, {}
        self.cells: list[str] = []
        self.classes: list[str] = []
        self._in, self._text = None, []

    def handle_starttag(self, tag, attrs):
        a = dict(attrs)
        if tag == "img":
            self.imgs.append(a.get("src", ""))
        if tag in ("link", "a") and a.get("href"):
            self.links.append(a["href"])
        if tag == "script":
            self.scripts += 1
        if a.get("class"):
            self.classes.append(a["class"])
        if a.get("id"):
            self._in, self._text = a["id"], []
            self.ids[a["id"]] = ""
        if tag == "td":
            self.cells.append("")

    def handle_data(self, data):
        if self._in is not None:
            self.ids[self._in] += data
        if self.cells is not None and self.lasttag == "td":
            self.cells[-1] += data

    def handle_endtag(self, tag):
        if tag in ("p", "figure"):
            self._in = None


def parse(path: Path) -> Page:
    p = Page()
    p.feed(path.read_text(encoding="utf-8"))
    return p


@pytest.fixture(scope="module")
def flown(tmp_path_factory) -> Path:
    """One short ground-air flight (the main job, 20 s behind the net)."""
    runs = tmp_path_factory.mktemp("runs")
    args = ["fly", "--duration", "20", "--speedup", "0", "--instance", "17",
            "--runs-dir", str(runs)]  # fmt: skip
    assert main(args) == 0
    (run,) = runs.iterdir()
    return run


@pytest.mark.slow
def test_report_html_is_one_self_contained_page_of_the_whole_flight(flown):
    page = parse(flown / REPORT)
    assert page.ids["verdict"].strip() == "skyherd fly: completed"
    assert "ok" in " ".join(page.classes)
    # every figure of the folder, embedded: the same bytes as the file, nothing fetched
    srcs = {s.split(",", 1)[0]: s for s in page.imgs}
    assert set(srcs) == {"data:image/png;base64"} and len(page.imgs) == 2
    embedded = {hashlib.sha256(base64.b64decode(s.split(",", 1)[1])).hexdigest() for s in page.imgs}
    on_disk = {hashlib.sha256((flown / n).read_bytes()).hexdigest()
               for n in ("groundair.png", "frames.png")}  # fmt: skip
    assert embedded == on_disk
    assert page.links == [] and page.scripts == 0
    text = (flown / REPORT).read_text()
    assert "http://" not in text and "https://" not in text
    # the judge's six checks, each passed, and the mission's table, as in summary.md
    assert page.cells.count("pass") == 6 and "FAIL" not in page.cells
    assert "all UGVs in view [fraction of decisions]" in page.cells
    assert "How it ended" in text and "20 s behind the safety net" in text


@pytest.mark.slow
def test_a_failed_flight_has_its_report_with_the_failed_check_first(flown, tmp_path, capsys):
    """The same records with the truth carried outside the fence: the real judge fails it and
    the page says so, the failed check in red."""
    import argparse
    import csv

    from skyherd.report.ending import append_ending
    from skyherd.report.fly import report

    run = tmp_path / flown.name
    shutil.copytree(flown, run)
    rows = list(csv.DictReader(open(run / "world.csv")))
    for r in rows[len(rows) // 2 :]:
        r["north"] = str(float(r["north"]) + 400.0)  # 200 m past the fence's north side
    with open(run / "world.csv", "w", newline="") as f:
        w = csv.DictWriter(f, fieldnames=list(rows[0]))
        w.writeheader()
        w.writerows(rows)
    args = argparse.Namespace(**json.loads((run / "config.json").read_text())["args"])
    assert report(run, args, 0, "") is False
    append_ending(run, ["companion: completed"])
    page = parse(run / REPORT)
    assert page.ids["verdict"].strip() == "skyherd fly: FAILED"
    assert "bad" in " ".join(page.classes)
    assert "FAIL" in page.cells and page.cells[page.cells.index("FAIL") - 1] == "fence"
    assert "first failed check: fence" in (run / REPORT).read_text()
    capsys.readouterr()


@pytest.mark.skipif(CHROMIUM is None, reason="no chromium on this machine (Debian: chromium)")
@pytest.mark.slow
def test_report_html_renders_in_headless_chromium(flown, tmp_path):
    shot = tmp_path / "report.png"
    r = subprocess.run([CHROMIUM, "--headless", "--no-sandbox", "--disable-gpu",
                        "--hide-scrollbars", f"--screenshot={shot}", "--window-size=1280,2400",
                        (flown / REPORT).as_uri()],
                       capture_output=True, text=True, timeout=120)  # fmt: skip
    assert r.returncode == 0 and shot.exists(), r.stderr[-2000:]
    img = cv2.imread(str(shot))
    assert img.shape[:2] == (2400, 1280)
    # drawn, not blank: the green banner of the verdict and the figures' many colours
    assert len(np.unique(img.reshape(-1, 3)[::97], axis=0)) > 50
    green = (img[:, :, 1].astype(int) - img[:, :, 2]) > 12
    assert green[:400].sum() > 2000


@pytest.mark.slow
def test_groundair_png_shows_the_flight_on_one_time_axis(flown):
    img = cv2.imread(str(flown / "groundair.png"))
    assert img.shape[:2] == (620, 1600)
    # the verdict strip: the net's colours (accepted green, projected yellow) are drawn
    rgb = img[:, :, ::-1].reshape(-1, 3).astype(int)
    for colour in ((0x2C, 0xA0, 0x2C), (0xF2, 0xC1, 0x2E)):
        assert (np.abs(rgb - colour).sum(axis=1) < 6).sum() > 200, colour


def _frame_at(det: Detector, shape=(240, 320)):
    img = np.full((*shape, 3), 110, np.uint8)
    for x in (100, 160, 220):
        cv2.circle(img, (x, 120), 6, (230, 30, 30), -1)
    return img, det.detect(img)


@pytest.mark.parametrize("flight_s", [5.0, 60.0, 600.0, 36000.0])
def test_frames_png_has_a_bounded_whole_grid_of_labelled_tiles(flight_s):
    """Whatever the flight's length: at most 12 tiles, whole rows, the first and last frame."""
    task = TaskParams()
    det = Detector(task.camera, task.n_ugvs)
    img, d = _frame_at(det)
    sample = FrameSample(SheetParams())
    ts = np.arange(0.0, flight_s + 1e-9, 0.1)
    for t in ts:
        sample.add(float(t), img, d, 20.0, "policy")
    assert len(sample.kept) <= 2 * SheetParams().max_tiles  # memory bounded too
    chosen = sample.chosen()
    n = len(chosen)
    assert n <= 12 and (n % 4 == 0 or n < 4)
    assert chosen[0].t == 0.0 and chosen[-1].t == pytest.approx(ts[-1])
    sheet = sample.sheet()
    h, w = img.shape[:2]
    cols = min(4, n)
    assert sheet.shape[1] == cols * 2 * w
    rows = -(-n // cols)
    assert rows * 2 * h < sheet.shape[0] <= rows * 2 * h + 90  # the tiles and the legend band
    assert not (sheet[: rows * 2 * h] == 255).all(axis=2).all(axis=1).any()  # no white row


def test_markdown_tables_keep_a_pipe_inside_a_cell():
    from skyherd.runio import markdown_table

    md = markdown_table(["metric", "value"], [["|distance − R|, p95 [m]", 7.2]])
    assert md.count("\\|") == 2
    html = markdown_to_html(md)
    assert "<td>|distance − R|, p95 [m]</td>" in html and html.count("<td>") == 2


def test_write_report_html_on_an_empty_folder_says_no_summary(tmp_path):
    assert write_report_html(tmp_path) is None
    page = parse(tmp_path / REPORT)
    assert "no summary" in page.ids["verdict"] and page.imgs == []


@pytest.mark.slow
def test_skyherd_companion_alone_says_its_own_name(flown, tmp_path, capsys):
    """The report of `skyherd companion` run alone says "skyherd companion", not "skyherd fly"."""
    import argparse

    from skyherd.report.fly import report

    run = tmp_path / flown.name
    shutil.copytree(flown, run)
    args = argparse.Namespace(**{**json.loads((run / "config.json").read_text())["args"],
                                 "command": "companion"})  # fmt: skip
    assert report(run, args, 0, "") is True
    assert (run / "summary.md").read_text().startswith("# skyherd companion: completed")
    out = capsys.readouterr().out
    assert "skyherd companion: completed;" in out and "skyherd fly" not in out


DRAW = """
import sys
from skyherd.report.plots_flight import pyplot
if sys.argv[1] == "plain":
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
else:
    plt = pyplot()
    import matplotlib.artist as artist
    assert artist.kwdoc.__name__ == "kwdoc"  # matplotlib's own again
fig = plt.figure(figsize=(4, 3))
ax = fig.add_subplot()
ax.plot([0, 1, 2], [0, 2, 1], label="a")
ax.set(title="t", xlabel="x")
ax.legend()
fig.savefig(sys.argv[2], dpi=50)
"""


def test_pyplot_without_set_docstrings_draws_the_same_pixels(tmp_path):
    """report.plots_flight.pyplot (matplotlib imported without its set() property tables,
    ~0.07 CPU s of fly) draws what matplotlib's own import draws, pixel for pixel."""
    for how in ("plain", "short"):
        subprocess.run([sys.executable, "-c", DRAW, how, str(tmp_path / f"{how}.png")], check=True,
                       timeout=120)  # fmt: skip
    a, b = (cv2.imread(str(tmp_path / f"{h}.png")) for h in ("plain", "short"))
    assert a is not None and np.array_equal(a, b)
