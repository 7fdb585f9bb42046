"""Where shipped files live: a checkout's top-level folders, or their copies inside the wheel.

The wheel packs ``fmus/``, ``scenarios/``, ``configs/``, ``policies/`` and ``web/`` under
``hptvsim/_data/`` (see ``pyproject.toml``); a checkout keeps them at the top. Every lookup of
shipped files goes through :func:`shipped_dir`.
"""

from __future__ import annotations

import os
from importlib import resources
from pathlib import Path

__all__ = ["shipped_dir"]

_CHECKOUT = Path(__file__).resolve().parents[1]


def shipped_dir(*parts: str, env: str | None = None) -> Path:
    """The folder of shipped files ``parts`` (e.g. ``"configs", "train"``).

    Args:
        *parts: The folder relative to the checkout's top (and to ``hptvsim/_data`` in a wheel).
        env: An environment variable that, when set, names the folder instead.

    Returns:
        ``$env`` if set, else the checkout's folder if it exists, else the wheel's copy.
    """
    if env is not None and os.environ.get(env):
        return Path(os.environ[env])
    checkout = _CHECKOUT.joinpath(*parts)
    if checkout.is_dir():
        return checkout
    return Path(str(resources.files("hptvsim").joinpath("_data", *parts)))
