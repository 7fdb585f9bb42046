"""Package attributes imported on first use (PEP 562).

Importing a package (as the command line does for each package's commands) then does not import
its heavy modules.
"""

from __future__ import annotations

import importlib
from collections.abc import Callable, Mapping
from typing import Any


def lazy_getattr(package: str, where: Mapping[str, str]) -> Callable[[str], Any]:
    """A module ``__getattr__`` that imports each of ``where``'s names from its module when asked.

    Args:
        package: The package's name, for the error message.
        where: Attribute name -> the module that defines it.
    """

    def getattr_(name: str) -> Any:
        module = where.get(name)
        if module is None:
            raise AttributeError(f"module {package!r} has no attribute {name!r}")
        return getattr(importlib.import_module(module), name)

    return getattr_
