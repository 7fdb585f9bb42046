"""Where shipped files live: a checkout's top-level folders, or their copies inside the wheel.

The wheel packs ``fmus/``, ``scenarios/``, ``configs/``, ``policies/`` and ``web/`` under
``hptvsim/_data/`` (see ``pyproject.toml``); a checkout keeps them at the top. Every lookup of
shipped files goes through :func:`shipped_dir`.
"""

from __future__ import annotations

import os
from importlib import resources
from pathlib import Path

__all__ = ["checkout_dir", "shipped_dir"]

_PACKED = Path(__file__).resolve().parent / "_data"
_CHECKOUT = Path(__file__).resolve().parents[1]


def checkout_dir() -> Path | None:
    """The top of the checkout this package runs from (None in an installed copy).

    Commands that write the repository's own files (regenerated FMUs, the frame schema) write
    there, and refuse without an explicit output folder in an installed copy, whose files
    belong to pip.
    """
    if _PACKED.is_dir() or not (_CHECKOUT / "pyproject.toml").is_file():
        return None
    return _CHECKOUT


def shipped_dir(*parts: str, env: str | None = None) -> Path:
    """The folder of shipped files ``parts`` (e.g. ``"configs", "train"``).

    Args:
        *parts: The folder relative to the checkout's top (and to ``hptvsim/_data`` in a wheel).
        env: An environment variable that, when set, names the folder instead.

    Returns:
        ``$env`` if set, else the wheel's copy in an installed package, else the checkout's
        folder (an installed package never looks beside itself in site-packages, where another
        distribution's folder of the same name could lie).
    """
    if env is not None and os.environ.get(env):
        return Path(os.environ[env])
    if _PACKED.is_dir():
        return Path(str(resources.files("hptvsim").joinpath("_data", *parts)))
    return _CHECKOUT.joinpath(*parts)
