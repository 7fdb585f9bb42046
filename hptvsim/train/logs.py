"""Training logs: CSV files for people and plots, TensorBoard scalars for live curves.

``episodes.csv``: one row per agent per finished episode (stage, episode, env step, return,
length, how it ended, the latest training statistics, the agent's last ``info`` as JSON).
``updates.csv``: one row per agent every ``log_every`` env steps (losses, entropy coefficient,
gradient steps). TensorBoard events go to ``tb/``. On resume both CSVs are cut back to their
size at the checkpoint and TensorBoard purges events after its step, so nothing is counted twice.
"""

from __future__ import annotations

import csv
import io
import json
import math
from pathlib import Path
from typing import Any

__all__ = ["EPISODE_COLUMNS", "UPDATE_COLUMNS", "RunLogger"]

STAT_COLUMNS = (
    "actor_loss",
    "critic_loss",
    "ent_coef",
    "ent_coef_loss",
    "policy_gradient_loss",
    "value_loss",
    "entropy_loss",
    "approx_kl",
)
EPISODE_COLUMNS = (
    "stage_index",
    "stage",
    "episode",
    "agent",
    "env_step",
    "return",
    "length",
    "terminated",
    "truncated",
    *STAT_COLUMNS,
    "info",
)
UPDATE_COLUMNS = ("stage_index", "stage", "env_step", "agent", "n_updates", *STAT_COLUMNS)


def _json_safe(value: Any) -> Any:
    if isinstance(value, bool | int | str) or value is None:
        return value
    if isinstance(value, float):
        return value if math.isfinite(value) else None
    if isinstance(value, dict):
        return {str(k): _json_safe(v) for k, v in value.items()}
    if isinstance(value, list | tuple):
        return [_json_safe(v) for v in value]
    try:
        import numpy as np

        if isinstance(value, np.generic):
            return _json_safe(value.item())
        if isinstance(value, np.ndarray) and value.size <= 64:
            return _json_safe(value.tolist())
    except ImportError:  # pragma: no cover
        pass
    return None


class _Csv:
    def __init__(self, path: Path, columns: tuple[str, ...], truncate_to: int | None) -> None:
        self.path = path
        self.columns = columns
        if truncate_to is not None and path.exists():
            with path.open("r+b") as f:
                f.truncate(truncate_to)
        new = not path.exists() or path.stat().st_size == 0
        self.file = path.open("a", newline="")
        self.writer = csv.DictWriter(self.file, fieldnames=list(columns), extrasaction="ignore")
        if new:
            self.writer.writeheader()
            self.file.flush()

    def write(self, row: dict[str, Any]) -> None:
        self.writer.writerow({k: ("" if v is None else v) for k, v in row.items()})

    def size(self) -> int:
        self.file.flush()
        return self.file.tell()

    def close(self) -> None:
        self.file.close()


class RunLogger:
    """CSV and TensorBoard output of one training run.

    Args:
        run_dir: The run's folder.
        offsets: ``{"episodes": bytes, "updates": bytes}`` to cut the CSVs back to (resume).
        purge_step: TensorBoard drops events at or after this env step (resume).
        tensorboard: Write TensorBoard events.
    """

    def __init__(
        self,
        run_dir: Path,
        *,
        offsets: dict[str, int] | None = None,
        purge_step: int | None = None,
        tensorboard: bool = True,
    ) -> None:
        offsets = offsets or {}
        self.episodes = _Csv(run_dir / "episodes.csv", EPISODE_COLUMNS, offsets.get("episodes"))
        self.updates = _Csv(run_dir / "updates.csv", UPDATE_COLUMNS, offsets.get("updates"))
        self.tb: Any = None
        if tensorboard:
            try:
                from torch.utils.tensorboard import SummaryWriter

                self.tb = SummaryWriter(str(run_dir / "tb"), purge_step=purge_step)
            except ImportError:  # pragma: no cover - tensorboard is in the rl extra
                self.tb = None

    def episode(self, row: dict[str, Any], info: dict[str, Any] | None) -> None:
        """Log one agent's finished episode."""
        row = dict(row)
        row["info"] = json.dumps(_json_safe(info or {}), separators=(",", ":"))
        self.episodes.write(row)
        if self.tb is not None:
            agent, step = row["agent"], row["env_step"]
            self.tb.add_scalar(f"{agent}/episode_return", row["return"], step)
            self.tb.add_scalar(f"{agent}/episode_length", row["length"], step)

    def update(self, row: dict[str, Any]) -> None:
        """Log one agent's training statistics."""
        self.updates.write(row)
        if self.tb is not None:
            for k in STAT_COLUMNS:
                v = row.get(k)
                if isinstance(v, float) and math.isfinite(v):
                    self.tb.add_scalar(f"{row['agent']}/{k}", v, row["env_step"])

    def offsets(self) -> dict[str, int]:
        """Current CSV sizes (flushed), for a checkpoint."""
        if self.tb is not None:
            self.tb.flush()
        return {"episodes": self.episodes.size(), "updates": self.updates.size()}

    def close(self) -> None:
        """Flush and close everything."""
        self.episodes.close()
        self.updates.close()
        if self.tb is not None:
            self.tb.close()


def read_csv_rows(path: Path) -> list[dict[str, str]]:
    """All rows of a CSV log as dicts of strings."""
    with path.open(newline="") as f:
        return list(csv.DictReader(io.StringIO(f.read())))
