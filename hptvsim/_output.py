"""What commands and reports print, shared by every layer's commands and by the benchmarks.

* :func:`emit`: a benchmark result as its table or as JSON;
* :func:`machine_summary`: the machine a figure was measured on (benchmark tables, the
  reproduction report);
* :func:`check_choice`: a user's name checked against the valid ones, as a click error naming
  both;
* :func:`progress_bar`: every progress bar of long work (tqdm's on a terminal, plain lines every
  :data:`PLAIN_PROGRESS_INTERVAL_S` seconds in a log or a pipe).
"""

from __future__ import annotations

import functools
import json
import os
import platform
import sys
import time
from collections.abc import Collection, Iterable
from pathlib import Path
from typing import Any, Protocol, TextIO

__all__ = [
    "PLAIN_PROGRESS_INTERVAL_S",
    "Printable",
    "check_choice",
    "emit",
    "machine_summary",
    "progress_bar",
]

PLAIN_PROGRESS_INTERVAL_S = 30.0  # s
"""How often a progress bar prints a line where its stream is not a terminal (a log, a pipe)."""


class Printable(Protocol):
    """A result a command prints: a text table, or a JSON-ready mapping."""

    def table(self) -> str:
        """The result as text."""
        ...

    def as_dict(self) -> dict[str, object]:
        """The result as a JSON-ready mapping."""
        ...


def emit(result: Printable, as_json: bool) -> None:
    """Print a result (a benchmark's): its ``table()``, or its ``as_dict()`` as JSON."""
    import click

    if as_json:
        click.echo(json.dumps(result.as_dict(), indent=2))
    else:
        click.echo(result.table())


def check_choice(value: str, valid: Collection[str], *, what: str, param_hint: str) -> None:
    """Refuse a name that is not one of ``valid`` with one line naming it and the valid ones.

    Raises:
        click.BadParameter: ``unknown <what> '<value>'; valid: <valid>``.
    """
    import click

    if value not in valid:
        raise click.BadParameter(
            f"unknown {what} {value!r}; valid: {', '.join(valid)}", param_hint=param_hint
        )


def machine_summary() -> str:
    """One line naming the CPU and core count."""
    cpu = platform.processor() or platform.machine()
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                cpu = line.split(":", 1)[1].strip()
                break
    except OSError:
        pass
    return f"{cpu}, {os.cpu_count()} cores, Python {platform.python_version()}"


def progress_bar(
    iterable: Iterable[Any] | None = None,
    *,
    total: float | None = None,
    desc: str = "",
    unit: str = "it",
    initial: float = 0,
    unit_scale: bool = False,
    leave: bool = True,
    disable: bool = False,
    file: TextIO | None = None,
    interval_s: float = PLAIN_PROGRESS_INTERVAL_S,
) -> Any:
    """A progress bar for long work: the one place that makes them.

    On a terminal (or in a notebook) it is tqdm's bar, redrawn in place. Where the stream is not
    a terminal (output redirected to a log file or a pipe) a bar redrawn with carriage returns
    would be one ever-growing line, so it prints one plain line (``desc: 40%|...| 4/10 [...]``)
    when it starts, at most every ``interval_s`` seconds while it runs, and when it ends.

    Args:
        iterable: What to iterate over (the bar is then an iterator over it), or None.
        total: The expected count (None: unknown, or ``len(iterable)``).
        desc: The bar's label.
        unit: What is counted (``"step"``, ``"ep"``).
        initial: The count to start from (a resumed run).
        unit_scale: Scale large counts with SI prefixes (``1.2M``).
        leave: Keep the finished bar on a terminal (plain lines always stay).
        disable: Show nothing (the bar still counts).
        file: The stream (default: standard error).
        interval_s: Seconds between plain lines where the stream is not a terminal.

    Returns:
        A ``tqdm`` instance (``update``, ``set_postfix_str``, ``close``, iteration).
    """
    stream = sys.stderr if file is None else file
    kwargs: dict[str, Any] = {
        "total": total,
        "desc": desc,
        "unit": unit,
        "initial": initial,
        "unit_scale": unit_scale,
        "disable": disable,
        "file": stream,
    }
    from tqdm import std
    from tqdm.autonotebook import tqdm as auto_tqdm  # the notebook's bar in a notebook, else std's

    if auto_tqdm is not std.tqdm:  # a notebook: its widget
        return auto_tqdm(iterable, leave=leave, **kwargs)
    isatty = getattr(stream, "isatty", None)
    if isatty is not None and isatty():
        return std.tqdm(iterable, leave=leave, dynamic_ncols=True, **kwargs)
    return _plain_progress_class()(
        iterable, interval_s=interval_s, maxinterval=max(interval_s, 1.0), **kwargs
    )


@functools.cache
def _plain_progress_class() -> type:
    """Tqdm's bar printing whole lines instead of redrawing one (see :func:`progress_bar`)."""
    from tqdm import std

    class PlainProgress(std.tqdm):  # type: ignore[misc]  # tqdm is untyped
        """A tqdm bar whose every refresh is a new line: no carriage returns, no cursor moves."""

        def __init__(self, *args: Any, interval_s: float, **kwargs: Any) -> None:
            # set before tqdm's __init__, which displays the first line
            self._interval_s = interval_s  # s, the least time between two lines
            self._shown_at: float | None = None  # time.monotonic() of the last line [s]
            self._shown_n: float | None = None  # the count the last line showed
            self._closing = False
            super().__init__(*args, leave=True, ascii=True, mininterval=interval_s, **kwargs)

        def display(self, msg: str | None = None, pos: int | None = None) -> bool:
            """Start a new line with the bar's state, at most every ``interval_s`` (and the last one)."""
            text = self.__str__() if msg is None else msg
            if not text:
                return False
            now = time.monotonic()
            if self._shown_at is not None:
                if self._closing and self.n == self._shown_n:
                    return True  # the last line said it already
                if not self._closing and now - self._shown_at < self._interval_s:
                    return True  # a refresh asked for too soon (set_postfix_str and the like)
            self.fp.write(("\n" if self._shown_at is not None else "") + text)
            self.fp.flush()
            self._shown_at, self._shown_n = now, self.n
            return True

        def close(self) -> None:
            """The final line (unless the last one showed the final count), then tqdm's close."""
            self._closing = True
            super().close()

        def clear(self, nolock: bool = False) -> None:
            """Nothing to clear: printed lines stay."""

        def moveto(self, n: int) -> None:
            """No cursor moves in a log."""

    return PlainProgress
