"""CasADi, typed as ``Any`` for mypy.

casadi ships inline type hints that disagree with its runtime (``vertcat`` is annotated as
returning a ``Sparsity``), and mypy reads them even with ``follow_imports = skip`` because the
package has ``py.typed``. Importing it through this alias keeps the symbolic code free of
per-line ignores.
"""

from typing import Any

import casadi as _casadi

ca: Any = _casadi

__all__ = ["ca"]
