"""What commands and reports print, shared by every layer's commands and by the benchmarks.

* :func:`emit`: a benchmark result as its table or as JSON;
* :func:`machine_summary`: the machine a figure was measured on (benchmark tables, the
  reproduction report);
* :func:`check_choice`: a user's name checked against the valid ones, as a click error naming
  both.
"""

from __future__ import annotations

import json
import os
import platform
from collections.abc import Collection
from pathlib import Path
from typing import Protocol

__all__ = ["Printable", "check_choice", "emit", "machine_summary"]


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
