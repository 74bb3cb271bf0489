"""The visual diff and report.html (issue 23 items 1 and 2): ``learn --report`` and ``ilcnc report STATE``.

Real runs: samples/own/square.ngc (2 iterations, a comment holding ``<`` and ``&`` added on a cutting line) and
the dense third-party locket_outside.ngc (10,206 commands, 1 iteration), both on configs/example-mill.yaml.
The page is opened in headless Chromium where it is installed (Debian's ``chromium``).
"""

from __future__ import annotations

import json
import re
import shutil
import subprocess
from pathlib import Path

import numpy as np
import pytest
from PIL import Image
from typer.testing import CliRunner

from ilcnc.cli import app
from ilcnc.program import read_program
from ilcnc.shop.html_report import DIFF_ROWS
from ilcnc.shop.state import LearnState

from .conftest import OWN, REPO, SAMPLES, cli_output

PROFILE = REPO / "configs" / "example-mill.yaml"
FIGURES = ("corrections.png", "corrections-zoom.png", "corrections-along-path.png")
COMMENT = "(edge <A> & B)"
runner = CliRunner()


def _ok(*args: object) -> str:
    res = runner.invoke(app, [str(a) for a in args])
    assert res.exit_code == 0, cli_output(res)
    return res.stdout


def _learn(tmp: Path, program: Path, iterations: int) -> tuple[Path, Path, dict]:
    out = tmp / f"out{program.suffix}"
    rep = tmp / "rep"
    _ok("learn", program, "--profile", PROFILE, "--out", out, "--iterations", iterations, "--report", rep, "--json")
    state = tmp / f"{out.name}.state"
    again = json.loads(_ok("report", state, "--out", tmp / "again", "--profile", PROFILE, "--json"))
    return rep, state, again


@pytest.fixture(scope="module")
def square(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, Path, dict]:
    tmp = tmp_path_factory.mktemp("square")
    text = (OWN / "square.ngc").read_text()
    assert "G1 X50 F3000\n" in text
    prog = tmp / "square.ngc"
    prog.write_text(text.replace("G1 X50 F3000\n", f"G1 X50 F3000 {COMMENT}\n"))
    return _learn(tmp, prog, 2)


@pytest.fixture(scope="module")
def locket(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, Path, dict]:
    tmp = tmp_path_factory.mktemp("locket")
    prog = tmp / "locket_outside.ngc"
    lines = (SAMPLES / "contour" / "locket_outside.ngc").read_text().splitlines(keepends=True)
    # a comment holding < and & on every G1 line: the worst commands and the diff must show it escaped
    prog.write_text("".join(ln.rstrip("\n") + f" {COMMENT}\n" if ln.startswith("G1 ") else ln for ln in lines))
    assert prog.read_text().count(COMMENT) > 5000
    return _learn(tmp, prog, 1)


def _worst_cutting_line(state_dir: Path) -> tuple[int, str]:
    """The source line of the cutting command of largest |E(k)| in iteration 0, computed from the state's files."""
    st = LearnState.load(state_dir)
    prog = read_program(st.file(st.part["file"]))
    e, _t, valid = st.read_errors(st.iterations[0])
    mag = np.where(valid, np.linalg.norm(e, axis=1), -1.0)
    z = prog.command_end_mm[:, 2]
    mag[z > 0.0] = -1.0  # example-mill has no stock top: work Z0 is the top, ends above it are air
    k = int(np.argmax(mag))
    line = int(prog.command_line[k])
    return line, prog.line_text(line)[1]


def test_figures_are_pngs_with_the_factor_in_their_title(square: tuple[Path, Path, dict]) -> None:
    rep, _state, again = square
    for name in FIGURES:
        with Image.open(rep / name) as im:
            im.load()  # decodes the whole image: a truncated file raises
            assert im.format == "PNG" and im.width > 500 and im.height > 300
            title = im.text["Title"]
        if name == "corrections.png":
            assert f"corrections ×{again['magnify']:g}" in title
        if name == "corrections-zoom.png":
            assert f"×{again['zoom_magnify']:g}" in title and f"line {again['worst_line']}" in title
    # ilcnc report STATE draws the same figures as learn --report
    for name in FIGURES:
        assert (rep / name).read_bytes() == (Path(again["files"][0]).parent / name).read_bytes()


def _check_page(rep: Path, state: Path, again: dict) -> str:
    """The page's iteration rows, its worst command (line and escaped text) and that it loads nothing."""
    page = (rep / "report.html").read_text(encoding="utf-8")
    line, text = _worst_cutting_line(state)
    assert again["worst_line"] == line
    worst = page.split('<table id="worst">')[1].split("</table>")[0]
    first = worst.split("</tr>")[1]  # the header, then the worst command
    esc = text.replace("&", "&amp;").replace("<", "&lt;").replace(">", "&gt;")
    assert f'<td class="n">{line}</td>' in first and esc in first
    iters = page.split('<table id="iterations">')[1].split("</table>")[0]
    assert len(re.findall(r"<tr class=", iters)) == len(LearnState.load(state).iterations)
    assert page.count('src="data:image/png;base64,') >= 5  # 3 corrections figures + learn --report's plots
    assert "http://" not in page and "https://" not in page and "<script" not in page
    # the comment's < and & are escaped everywhere, never written raw
    assert "&lt;A&gt; &amp; B" in page and "<A>" not in page and "& B" not in page
    return page


def test_html_square(square: tuple[Path, Path, dict]) -> None:
    rep, state, again = square
    page = _check_page(rep, state, again)
    # example-mill's path estimate moves one point of the 50 mm square (whose error is the planner's rounding of its
    # G64 P0.05 corners): the plunge's end 1 µm deeper, Z0 -> Z-0.001, and the Z0 the next line then needs
    assert again["arrows_total"] == 1 and again["diff_changed"] == 2
    assert "2 line(s) changed" in page


def test_dense_program_is_decimated_and_capped(locket: tuple[Path, Path, dict]) -> None:
    rep, state, again = locket
    assert again["arrows_total"] > 3000 and again["arrows_drawn"] < again["arrows_total"] / 5
    assert again["worst_line"] == _worst_cutting_line(state)[0]
    page = _check_page(rep, state, again)
    diff = page.split('<table id="diff">')[1].split("</table>")[0]
    assert diff.count("<tr>") == DIFF_ROWS + 1  # the header and the listed lines
    assert diff.count("&lt;A&gt; &amp; B") == 2 * DIFF_ROWS  # original and output text of each
    left = again["diff_changed"] - DIFF_ROWS
    assert left > 0 and f"{left} more changed lines are not listed" in page
    assert len(page) < 3_000_000  # a page a shop can mail


def test_report_refuses_bad_input(tmp_path: Path, square: tuple[Path, Path, dict]) -> None:
    _rep, state, _again = square
    res = runner.invoke(app, ["report", str(tmp_path)])
    assert res.exit_code == 1 and cli_output(res).startswith("error: ") and "state.json" in cli_output(res)
    res = runner.invoke(app, ["report", str(state), "--out", str(state / "inside")])
    assert res.exit_code == 1 and "inside the learning state" in cli_output(res)
    assert not (state / "inside").exists()


# --------------------------------------------------------------------------- headless Chromium

CHROMIUM = shutil.which("chromium")
# Console messages of the page reach stderr as "INFO:CONSOLE(...)" lines with --enable-logging=stderr (checked
# below with a page that logs one); the other stderr lines are the browser's own (D-Bus, GPU) and say nothing
# about the page.
_FLAGS = ("--headless", "--no-sandbox", "--disable-gpu", "--disable-quic", "--no-first-run",
          "--disable-background-networking", "--disable-component-update", "--disable-sync", "--enable-logging=stderr",
          "--v=0", "--force-device-scale-factor=1", "--hide-scrollbars", "--window-size=1200,2000")


def _chromium(tmp: Path, page: Path, *what: str) -> subprocess.CompletedProcess[str]:
    assert CHROMIUM is not None
    return subprocess.run([CHROMIUM, *_FLAGS, f"--user-data-dir={tmp / 'profile'}", *what, page.resolve().as_uri()],
                          capture_output=True, text=True, timeout=60, check=False)


def _console(stderr: str) -> list[str]:
    return [ln for ln in stderr.splitlines() if ":CONSOLE" in ln]


def _find(screen: np.ndarray, image: np.ndarray, tol: int) -> tuple[int, int] | None:
    """Top-left corner where ``image`` appears in ``screen`` at 1:1 scale (every channel within ``tol``)."""
    h, w, _ = image.shape
    row = int(np.argmax([len(np.unique(r.view(np.dtype((np.void, 6))))) for r in image]))  # the most varied row
    # its pixel of the colour rarest in the image (a colour the image draws often, such as a line's, seeds the
    # search at every pixel of that line on the screen)
    key = (image[..., 0].astype(np.int64) << 16) | (image[..., 1].astype(np.int64) << 8) | image[..., 2]
    colours, counts = np.unique(key, return_counts=True)
    col = int(np.argmin(counts[np.searchsorted(colours, key[row])]))
    seed = np.abs(screen - image[row, col]).max(axis=2) <= tol
    for y, x in np.argwhere(seed)[:20000]:
        y0, x0 = y - row, x - col
        if y0 < 0 or x0 < 0 or y0 + h > screen.shape[0] or x0 + w > screen.shape[1]:
            continue
        if np.abs(screen[y0:y0 + h, x0:x0 + w] - image).max() <= tol:
            return int(y0), int(x0)
    return None


@pytest.mark.skipif(CHROMIUM is None, reason="Debian's chromium is not installed (apt-get install chromium): the"
                    " rendering of report.html is not checked")
def test_report_renders_in_headless_chromium(tmp_path: Path, square: tuple[Path, Path, dict]) -> None:
    rep, _state, _again = square
    # the console check sees a page's console: a page that logs shows it
    probe = tmp_path / "probe.html"
    probe.write_text("<!DOCTYPE html><html><body><script>console.error('probe-error')</script></body></html>")
    assert any("probe-error" in ln for ln in _console(_chromium(tmp_path, probe, "--dump-dom").stderr))

    page = rep / "report.html"
    dom = _chromium(tmp_path, page, "--dump-dom")
    assert dom.returncode == 0, dom.stderr[-2000:]
    assert _console(dom.stderr) == []
    for table in ("facts", "iterations", "worst", "diff"):
        assert f'<table id="{table}">' in dom.stdout
    assert dom.stdout.count("<img ") >= 5

    shot = tmp_path / "shot.png"
    res = _chromium(tmp_path, page, f"--screenshot={shot}")
    assert res.returncode == 0 and shot.is_file(), res.stderr[-2000:]
    assert _console(res.stderr) == []
    screen = np.asarray(Image.open(shot).convert("RGB"), dtype=np.int16)
    assert screen.shape == (2000, 1200, 3)
    assert (screen != 255).any(axis=2).mean() > 0.05  # not blank: text, tables and the figure are drawn
    figure = np.asarray(Image.open(rep / "corrections.png").convert("RGB"), dtype=np.int16)
    # A lossless PNG drawn 1:1 (device scale 1, no CSS scaling, sRGB in and out) comes out with the same pixel
    # values; 2 of 255 leaves room for a colour-managed pipeline's rounding.
    assert _find(screen, figure, tol=2) is not None
