"""Where a tool the suite uses is missing, its tests skip on a developer's machine and fail under CI."""

from __future__ import annotations

from pathlib import Path

import pytest

pytest_plugins = ["pytester"]

INNER = """
import pytest
from needs import needs, missing

@needs(False, "no frobnicator (apt install frobnicator)")
def test_marked():
    pass

def test_called():
    missing("mounting needs root")

@needs(True, "never shown")
def test_present():
    pass
"""


@pytest.mark.parametrize("ci", [False, True])
def test_a_missing_tool_skips_here_and_fails_under_ci(
    pytester: pytest.Pytester, monkeypatch: pytest.MonkeyPatch, ci: bool
) -> None:
    if ci:
        monkeypatch.setenv("CI", "true")
    else:
        monkeypatch.delenv("CI", raising=False)
    monkeypatch.setenv("PYTHONPATH", str(Path(__file__).parent))  # the inner run imports needs.py
    pytester.makepyfile(test_inner=INNER)
    result = pytester.runpytest_subprocess("-p", "needs", "-rfs", "-p", "no:cacheprovider")
    if ci:
        result.assert_outcomes(passed=1, failed=1, errors=1)  # the mark fails in setup
        result.stdout.fnmatch_lines(
            ["*no frobnicator (apt install frobnicator) (under CI the test command provides it)*"]
        )
    else:
        result.assert_outcomes(passed=1, skipped=2)
        result.stdout.fnmatch_lines(["*no frobnicator (apt install frobnicator)*", "*mounting needs root*"])
