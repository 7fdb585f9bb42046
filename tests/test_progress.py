"""Progress bars in a log are plain lines, not one line of carriage returns (issue 38, point 6).

Every progress bar of long work is made by :func:`hptvsim._output.progress_bar`: tqdm's bar on a
terminal, and, where the stream is not a terminal (a log file, a pipe), one plain line when it
starts, at most every ``interval_s`` seconds, and when it ends.
"""

from __future__ import annotations

import io
import re
import subprocess
import sys
from pathlib import Path

from hptvsim._output import progress_bar

PACKAGE = Path(__file__).resolve().parents[1] / "hptvsim"


class Terminal(io.StringIO):
    """A text stream that says it is a terminal."""

    def isatty(self) -> bool:
        return True


def test_a_bar_in_a_log_prints_whole_lines() -> None:
    log = io.StringIO()
    bar = progress_bar(total=4, desc="work", unit="step", file=log, interval_s=0.0)
    for _ in range(4):
        bar.update(1)
    bar.close()
    text = log.getvalue()
    assert "\r" not in text and "\x1b" not in text
    lines = text.splitlines()
    assert text.endswith("\n")
    assert [re.match(r"work: +(\d+)%", ln).group(1) for ln in lines] == ["0", "25", "50", "75", "100"]  # type: ignore[union-attr]
    assert lines[-1].endswith("]") and "4/4" in lines[-1]


def test_a_bar_in_a_log_prints_at_most_every_interval() -> None:
    log = io.StringIO()
    bar = progress_bar(total=1000, desc="work", file=log, interval_s=3600.0)
    for k in range(1000):
        bar.update(1)
        bar.set_postfix_str(f"item {k}", refresh=True)  # asks for a refresh every time
    bar.close()
    lines = log.getvalue().splitlines()
    assert len(lines) == 2, lines  # the start and the end
    assert "0/1000" in lines[0] and "1000/1000" in lines[1] and "item 999" in lines[1]


def test_a_bar_that_would_vanish_stays_in_a_log() -> None:
    log = io.StringIO()
    for _ in progress_bar(range(3), desc="sweep", file=log, leave=False, interval_s=0.0):
        pass
    assert "\r" not in log.getvalue() and log.getvalue().splitlines()[-1].startswith("sweep: 100%")


def test_a_bar_on_a_terminal_is_redrawn_in_place() -> None:
    term = Terminal()
    bar = progress_bar(total=2, desc="work", file=term)
    bar.update(2)
    bar.close()
    assert term.getvalue().count("\r") >= 2 and term.getvalue().count("\n") == 1


def test_every_bar_is_made_by_the_one_helper() -> None:
    users = sorted(
        str(p.relative_to(PACKAGE))
        for p in PACKAGE.rglob("*.py")
        if re.search(r"^\s*(from tqdm|import tqdm)", p.read_text(encoding="utf-8"), re.M)
    )
    assert users == ["_output.py"]


def test_an_episode_logged_to_a_file_has_no_carriage_returns(tmp_path: Path) -> None:
    res = subprocess.run(
        [sys.executable, "-m", "hptvsim.cli", "episode", "--scenario", "target", "--max-steps", "20"],
        cwd=tmp_path,
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert res.returncode == 0, res.stderr
    assert "Traceback" not in res.stderr
    assert "\r" not in res.stderr, res.stderr[:500]
    bar = [ln for ln in res.stderr.splitlines() if ln.startswith("episode target:")]
    assert bar and "0/" in bar[0] and bar[-1].startswith("episode target: 100%"), res.stderr[:500]
