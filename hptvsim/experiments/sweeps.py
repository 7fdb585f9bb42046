"""Parameter sweeps on Ray: one training job per (setting, seed), local by default or on a cluster.

A sweep file names a base config, the seeds, fixed overrides and a grid of overrides whose
product gives the settings::

    name = "vmax"
    config = "paper"                # a shipped name or a path relative to this file
    seeds = [0, 1, 2]

    [set]                           # every job
    "sac.backend" = "batched"

    [grid]                          # the product of all lists
    "stage.0.env.options.pursuer_v_max" = [3.0, 3.25, 3.5]

The paper's studies are such grids: ``algo = ["maisac", "ippo"]`` (Figs. 7-8), the pursuers'
``v_max`` 3.0-3.5 m/s (Fig. 9), the evader's ``omega_max`` 3.0-4.0 rad/s (Fig. 10), and
``sac.ent_coef`` 0.1-0.4 (Fig. 11). Every job trains into ``OUT/<setting>-seed<seed>/`` with its
label in ``run.json``; ``OUT/sweep.json`` lists the jobs. Running a sweep again skips finished
jobs and resumes killed ones from their checkpoints.
"""

from __future__ import annotations

import itertools
import json
import re
import tomllib
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from hptvsim._process import set_torch_threads
from hptvsim.train.config import ConfigError, load_config, resolve_config_path

__all__ = ["Job", "SweepSpec", "load_sweep", "plan_jobs", "run_sweep"]


@dataclass(frozen=True, kw_only=True)
class SweepSpec:
    """A sweep file's content.

    Attributes:
        name: Sweep name.
        config: Path of the base training config.
        seeds: Training seeds; every setting runs once per seed.
        fixed: Overrides applied to every job.
        grid: Override key -> values; the settings are the product of the lists.
    """

    name: str
    config: Path
    seeds: tuple[int, ...] = (0,)
    fixed: Mapping[str, Any] = field(default_factory=dict)
    grid: Mapping[str, Sequence[Any]] = field(default_factory=dict)


@dataclass(frozen=True)
class Job:
    """One training run of a sweep."""

    label: str
    seed: int
    overrides: dict[str, Any]
    run_dir: str


def load_sweep(path: Path) -> SweepSpec:
    """Read and check a sweep file.

    Raises:
        ConfigError: Unknown keys, wrong types, or a grid that does not make valid configs.
    """
    try:
        with path.open("rb") as f:
            data = tomllib.load(f)
    except tomllib.TOMLDecodeError as exc:
        raise ConfigError(f"{path}: not valid TOML: {exc}") from None
    valid = {"name", "config", "seeds", "set", "grid"}
    unknown = sorted(set(data) - valid)
    if unknown:
        raise ConfigError(
            f"{path}: unknown key(s) {', '.join(unknown)}; valid keys: {', '.join(sorted(valid))}"
        )
    if "config" not in data:
        raise ConfigError(f"{path}: 'config' (the base training config) is required")
    seeds = data.get("seeds", [0])
    if not isinstance(seeds, list) or not all(isinstance(s, int) and not isinstance(s, bool) for s in seeds):
        raise ConfigError(f"{path}: seeds must be a list of integers, got {seeds!r}")
    grid = data.get("grid", {})
    for k, v in grid.items():
        if not isinstance(v, list) or not v:
            raise ConfigError(f"{path}: grid.{k} must be a non-empty list of values, got {v!r}")
    base = Path(str(data["config"]))
    config = (
        (path.parent / base) if (path.parent / base).is_file() else resolve_config_path(str(data["config"]))
    )
    spec = SweepSpec(
        name=str(data.get("name", path.stem)),
        config=config,
        seeds=tuple(seeds),
        fixed=dict(data.get("set", {})),
        grid=dict(grid),
    )
    for job in plan_jobs(spec):  # fail now, not in a worker an hour later
        load_config(spec.config, job.overrides)
    return spec


def _short(key: str) -> str:
    return key.split(".")[-1]


def _slug(text: str) -> str:
    return re.sub(r"[^A-Za-z0-9._=-]+", "_", text).strip("_") or "base"


def plan_jobs(spec: SweepSpec) -> list[Job]:
    """Every (setting, seed) job of a sweep, in a stable order."""
    keys = list(spec.grid)
    jobs = []
    for values in itertools.product(*(spec.grid[k] for k in keys)):
        setting = dict(zip(keys, values, strict=True))
        label = ", ".join(f"{_short(k)}={v}" for k, v in setting.items()) or "base"
        for seed in spec.seeds:
            overrides = {**spec.fixed, **setting, "seed": seed}
            slug = _slug("_".join(f"{_short(k)}={v}" for k, v in setting.items()))
            jobs.append(Job(label, seed, overrides, f"{slug}-seed{seed}"))
    return jobs


def _run_job(config: str, overrides: dict[str, Any], run_dir: str, label: str) -> dict[str, Any]:
    """Train one job (in a Ray worker or in this process); finished jobs are skipped, killed ones resumed."""
    from hptvsim.experiments.policies import named_policy
    from hptvsim.train.checkpoint import has_checkpoint
    from hptvsim.train.trainer import train

    set_torch_threads(1)
    out = Path(run_dir)
    if (out / "summary.json").is_file():
        return {"run_dir": run_dir, "status": "done before"}
    cfg = load_config(config, overrides)
    result = train(cfg, out, resume=has_checkpoint(out), progress=False, label=label, named=named_policy)
    return {"run_dir": run_dir, "status": "finished", "global_step": result.global_step}


def run_sweep(
    spec: SweepSpec,
    out: Path,
    *,
    address: str | None = None,
    num_cpus: int | None = None,
    serial: bool = False,
    progress: bool = True,
) -> list[dict[str, Any]]:
    """Run every job of a sweep; returns one status dict per job (also written to ``OUT/sweep.json``).

    Args:
        spec: The sweep.
        out: Folder of the sweep's runs.
        address: A Ray cluster's address (``"auto"`` or ``"ray://host:10001"``); default: a local Ray.
        num_cpus: CPUs of the local Ray (default: all); each job uses one.
        serial: Run the jobs one after another in this process, without Ray.
        progress: Show a progress bar over jobs.
    """
    out.mkdir(parents=True, exist_ok=True)
    jobs = plan_jobs(spec)
    manifest = {
        "name": spec.name,
        "config": str(spec.config),
        "jobs": [
            {"label": j.label, "seed": j.seed, "overrides": j.overrides, "run_dir": j.run_dir} for j in jobs
        ],
    }
    (out / "sweep.json").write_text(json.dumps(manifest, indent=2) + "\n")
    bar: Any = None
    if progress:
        from hptvsim._output import progress_bar

        bar = progress_bar(total=len(jobs), desc=f"sweep {spec.name}", unit="job")
    results: list[dict[str, Any]] = []
    try:
        if serial:
            for j in jobs:
                results.append(_run_job(str(spec.config), j.overrides, str(out / j.run_dir), j.label))
                if bar is not None:
                    bar.update(1)
        else:
            results = _run_on_ray(spec, jobs, out, address=address, num_cpus=num_cpus, bar=bar)
    finally:
        if bar is not None:
            bar.close()
    manifest["results"] = results
    (out / "sweep.json").write_text(json.dumps(manifest, indent=2) + "\n")
    return results


def _run_on_ray(
    spec: SweepSpec, jobs: list[Job], out: Path, *, address: str | None, num_cpus: int | None, bar: Any
) -> list[dict[str, Any]]:
    import ray

    started_here = not ray.is_initialized()
    if started_here:
        if address is None:
            ray.init(num_cpus=num_cpus, include_dashboard=False, log_to_driver=False)
        else:
            ray.init(address=address, log_to_driver=False)
    try:
        remote = ray.remote(num_cpus=1, max_retries=1)(_run_job)
        pending = {
            remote.remote(str(spec.config), j.overrides, str((out / j.run_dir).resolve()), j.label): j
            for j in jobs
        }
        done: dict[str, dict[str, Any]] = {}
        while pending:
            ready, _ = ray.wait(list(pending), num_returns=1)
            for ref in ready:
                job = pending.pop(ref)
                try:
                    done[job.run_dir] = ray.get(ref)
                except Exception as exc:  # a failed job is reported, the others go on
                    done[job.run_dir] = {"run_dir": job.run_dir, "status": "failed", "error": str(exc)}
                if bar is not None:
                    bar.update(1)
        return [done[j.run_dir] for j in jobs]
    finally:
        if started_here:
            ray.shutdown()
