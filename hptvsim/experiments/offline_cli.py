"""Offline RL commands: ``hptvsim collect``, ``hptvsim dt train|evaluate|figures|pipeline``.

Collecting and evaluating start from the policy zoo's names (the experts), so these commands live
above the zoo, with the experiments (:mod:`hptvsim.experiments.collect`,
:mod:`hptvsim.experiments.dt_evaluate`, :mod:`hptvsim.experiments.dt_pipeline`).
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import click

_DEFAULT_DATASETS = "hptvsim-out/datasets"


def _parse_pairs(items: tuple[str, ...], what: str) -> dict[str, str]:
    out = {}
    for item in items:
        key, sep, value = item.partition("=")
        if not sep or not key.strip() or not value.strip():
            raise click.BadParameter(f"{item!r}: expected {what}")
        out[key.strip()] = value.strip()
    return out


def _parse_value(text: str) -> Any:
    import tomllib

    try:
        return tomllib.loads(f"v = {text}")["v"]
    except tomllib.TOMLDecodeError:
        return text


def _targets(values: tuple[str, ...]) -> list[float | str]:
    out: list[float | str] = []
    for v in values:
        try:
            out.append(float(v))
        except ValueError:
            out.append(v)
    return out


def register(main: click.Group) -> None:
    """Add the offline commands to ``hptvsim``."""

    @main.command("collect")
    @click.option("--scenario", default="target", show_default=True, help="Scenario name or file.")
    @click.option(
        "--pursuers",
        default=None,
        help="Zoo spec of the expert pursuers [default: shipped MAISAC ones, else scripted:pure_pursuit].",
    )
    @click.option(
        "--evader",
        default=None,
        help="Zoo spec of the evader [default: the shipped MAISAC evader, else scripted:potential_field].",
    )
    @click.option(
        "--policy", "policy_items", multiple=True, metavar="AGENT=SPEC", help="Spec of one agent or role."
    )
    @click.option(
        "--role",
        "roles",
        multiple=True,
        type=click.Choice(["pursuer", "evader"]),
        help="Whose data to write [default: pursuer].",
    )
    @click.option("--episodes", type=int, default=200, show_default=True)
    @click.option(
        "--num-envs", type=int, default=50, show_default=True, help="Environments stepped together."
    )
    @click.option("--seed", type=int, default=0, show_default=True)
    @click.option("--max-steps", type=int, default=None, help="Override the scenario's step limit.")
    @click.option(
        "--per",
        type=click.Choice(["agent", "role"]),
        default="agent",
        show_default=True,
        help="One dataset per agent, or one per role.",
    )
    @click.option(
        "--name",
        default="expert",
        show_default=True,
        help="Dataset name (ids: hptvsim/SCENARIO/NAME-AGENT-v0).",
    )
    @click.option(
        "--out",
        type=click.Path(file_okay=False, path_type=Path),
        default=Path(_DEFAULT_DATASETS),
        show_default=True,
        help="Datasets folder (MINARI_DATASETS_PATH while writing).",
    )
    @click.option(
        "--format", "data_format", type=click.Choice(["hdf5", "arrow"]), default="hdf5", show_default=True
    )
    @click.option("--overwrite", is_flag=True, help="Replace datasets with the same ids.")
    @click.option(
        "--ref-episodes",
        type=int,
        default=100,
        show_default=True,
        help="Random-policy episodes for ref_min_score.",
    )
    @click.option("--no-progress", is_flag=True)
    def collect_cmd(
        scenario: str,
        pursuers: str | None,
        evader: str | None,
        policy_items: tuple[str, ...],
        roles: tuple[str, ...],
        episodes: int,
        num_envs: int,
        seed: int,
        max_steps: int | None,
        per: str,
        name: str,
        out: Path,
        data_format: str,
        overwrite: bool,
        ref_episodes: int,
        no_progress: bool,
    ) -> None:
        """Roll out expert policies and write offline datasets in Minari format (one per agent)."""
        from hptvsim.experiments.collect import collect

        try:
            res = collect(
                scenario=scenario,
                pursuers=pursuers,
                evader=evader,
                overrides=_parse_pairs(policy_items, "AGENT=SPEC"),
                roles=roles or ("pursuer",),
                episodes=episodes,
                num_envs=num_envs,
                seed=seed,
                max_steps=max_steps,
                per=per,  # type: ignore[arg-type]  # click.Choice
                name=name,
                out=out,
                data_format=data_format,  # type: ignore[arg-type]  # click.Choice
                overwrite=overwrite,
                ref_episodes=ref_episodes,
                progress=not no_progress,
            )
        except ValueError as exc:
            raise click.ClickException(str(exc)) from None
        click.echo(res.table())

    @main.group("dt")
    def dt() -> None:
        """Decision Transformer: train on offline datasets, evaluate in the game, draw figures."""

    @dt.command("train")
    @click.argument("config", required=False, type=click.Path(dir_okay=False, exists=True, path_type=Path))
    @click.option("--dataset", "datasets", multiple=True, help="Dataset id or folder (one model each).")
    @click.option(
        "--dataset-dir", default=None, help=f"Where ids are looked up [default: {_DEFAULT_DATASETS}]."
    )
    @click.option("--shared", is_flag=True, default=None, help="One model on all datasets pooled.")
    @click.option("--updates", type=int, default=None, help="Gradient updates per model.")
    @click.option("--seed", type=int, default=None)
    @click.option(
        "--set", "sets", multiple=True, metavar="KEY=VALUE", help="Config override (model.layers=2)."
    )
    @click.option(
        "--out",
        type=click.Path(file_okay=False, path_type=Path),
        default=Path("hptvsim-out/dt/run"),
        show_default=True,
        help="Run folder (re-run the same command to resume).",
    )
    @click.option("--no-progress", is_flag=True)
    @click.option("--no-tensorboard", is_flag=True)
    def dt_train(
        config: Path | None,
        datasets: tuple[str, ...],
        dataset_dir: str | None,
        shared: bool | None,
        updates: int | None,
        seed: int | None,
        sets: tuple[str, ...],
        out: Path,
        no_progress: bool,
        no_tensorboard: bool,
    ) -> None:
        """Train Decision Transformers (one per dataset, or shared); resume by re-running."""
        from hptvsim.offline.trainer import apply_overrides, config_from_mapping, load_train_config, train

        over: dict[str, Any] = {k: _parse_value(v) for k, v in _parse_pairs(sets, "KEY=VALUE").items()}
        for key, value in (
            ("datasets", list(datasets) or None),
            ("dataset_dir", dataset_dir),
            ("shared", shared),
            ("updates", updates),
            ("seed", seed),
        ):
            if value is not None:
                over[key] = value
        try:
            if config is not None:
                cfg = load_train_config(config, over)
            elif (out / "config.toml").is_file() and not over:
                cfg = load_train_config(out / "config.toml")
            else:
                cfg = config_from_mapping(
                    apply_overrides({"dataset_dir": _DEFAULT_DATASETS}, over), "options"
                )
            res = train(cfg, out, progress=not no_progress, tensorboard=not no_tensorboard)
        except (ValueError, FileNotFoundError) as exc:
            raise click.ClickException(str(exc)) from None
        how = f"resumed at {res.resumed_from}" if res.resumed_from else "fresh"
        click.echo(f"{res.updates} updates ({how})")
        for f, la in zip(res.first_loss, res.last_loss, strict=True):
            click.echo(f"  loss {f:.4f} -> {la:.4f} ({f / max(la, 1e-12):.1f}x)")
        click.echo(f"policy: dt:{res.policy_path}  (wall {res.wall_s:.0f} s)")

    @dt.command("evaluate")
    @click.argument("policy", type=click.Path(exists=True, path_type=Path))
    @click.option("--scenario", default=None, help="Scenario [default: the training data's].")
    @click.option("--evader", default=None, help="Evader spec [default: the training data's].")
    @click.option(
        "--expert", "expert_items", multiple=True, metavar="AGENT=SPEC", help="Expert pursuer spec."
    )
    @click.option(
        "--target",
        "targets",
        multiple=True,
        help="Target return: a number, mean, max, min, q10..q90 [default: q50].",
    )
    @click.option("--episodes", type=int, default=100, show_default=True)
    @click.option("--seed", type=int, default=0, show_default=True)
    @click.option(
        "--num-envs", type=int, default=None, help="Environments per batch [default: min(episodes, 100)]."
    )
    @click.option("--max-steps", type=int, default=None)
    @click.option(
        "--precision", type=click.Choice(["float32", "bfloat16"]), default="float32", show_default=True
    )
    @click.option("--no-baselines", is_flag=True, help="Skip the expert and random pursuers (no scores).")
    @click.option(
        "--out",
        type=click.Path(file_okay=False, path_type=Path),
        default=None,
        help="Folder for eval.json/md.",
    )
    @click.option("--json", "as_json", is_flag=True)
    @click.option("--no-progress", is_flag=True)
    def dt_evaluate(
        policy: Path,
        scenario: str | None,
        evader: str | None,
        expert_items: tuple[str, ...],
        targets: tuple[str, ...],
        episodes: int,
        seed: int,
        num_envs: int | None,
        max_steps: int | None,
        precision: str,
        no_baselines: bool,
        out: Path | None,
        as_json: bool,
        no_progress: bool,
    ) -> None:
        """DT pursuers vs the evader over seeded episodes: SAC metrics plus normalised scores."""
        from hptvsim.experiments.dt_evaluate import evaluate_dt, write_report
        from hptvsim.offline.policy import DEFAULT_TARGET

        path = policy / "dt.pt" if policy.is_dir() else policy
        try:
            report = evaluate_dt(
                path,
                scenario=scenario,
                evader=evader,
                experts=_parse_pairs(expert_items, "AGENT=SPEC") or None,
                targets=_targets(targets) or [DEFAULT_TARGET],
                episodes=episodes,
                seed=seed,
                num_envs=num_envs,
                max_steps=max_steps,
                include_baselines=not no_baselines,
                precision=precision,
                progress=not no_progress,
            )
        except (ValueError, FileNotFoundError) as exc:
            raise click.ClickException(str(exc)) from None
        folder = out if out is not None else path.parent / "eval"
        write_report(report, folder)
        if as_json:
            d = report.as_dict()
            for s in d["sets"]:
                s.pop("episodes")
            click.echo(json.dumps(d, indent=1, default=float))
        else:
            click.echo(report.markdown())
            click.echo(f"written: {folder / 'eval.json'}, {folder / 'eval.md'}")

    @dt.command("figures")
    @click.argument("run", type=click.Path(exists=True, path_type=Path))
    @click.option("--out", type=click.Path(file_okay=False, path_type=Path), default=None)
    @click.option("--scenario", default=None)
    @click.option("--evader", default=None)
    @click.option("--target", default="q50", show_default=True, help="Target return of the drawn episode.")
    @click.option("--seed", type=int, default=0, show_default=True, help="Seed of the drawn episode.")
    @click.option("--max-steps", type=int, default=None)
    def dt_figures(
        run: Path,
        out: Path | None,
        scenario: str | None,
        evader: str | None,
        target: str,
        seed: int,
        max_steps: int | None,
    ) -> None:
        """Figs. 14-17: loss curves, one episode's trajectories and pursuer-evader distances."""
        from hptvsim.experiments.dt_pipeline import figures_for_run

        path = run / "dt.pt" if run.is_dir() else run
        run_dir = path.parent
        tgt: float | str = _targets((target,))[0]
        try:
            written = figures_for_run(
                path,
                out if out is not None else run_dir / "figures",
                run_dir=run_dir,
                scenario=scenario,
                evader=evader,
                target=tgt,
                seed=seed,
                max_steps=max_steps,
            )
        except (ValueError, FileNotFoundError) as exc:
            raise click.ClickException(str(exc)) from None
        for p in written:
            click.echo(str(p))

    @dt.command("pipeline")
    @click.option(
        "--out",
        type=click.Path(file_okay=False, path_type=Path),
        default=Path("hptvsim-out/dt-target"),
        show_default=True,
    )
    @click.option("--scenario", default="target", show_default=True)
    @click.option(
        "--pursuers", default=None, help="Expert pursuers [default: shipped MAISAC, else pure pursuit]."
    )
    @click.option(
        "--evader",
        default=None,
        help="Evader [default: the shipped MAISAC evader, else scripted:potential_field].",
    )
    @click.option("--episodes", type=int, default=200, show_default=True, help="Expert episodes to collect.")
    @click.option("--config", type=click.Path(dir_okay=False, exists=True, path_type=Path), default=None)
    @click.option("--set", "sets", multiple=True, metavar="KEY=VALUE", help="Training config override.")
    @click.option("--eval-episodes", type=int, default=100, show_default=True)
    @click.option("--target", "targets", multiple=True, help="Target returns [default: q50].")
    @click.option("--seed", type=int, default=0, show_default=True)
    @click.option("--max-steps", type=int, default=None)
    @click.option("--no-progress", is_flag=True)
    def dt_pipeline(
        out: Path,
        scenario: str,
        pursuers: str | None,
        evader: str | None,
        episodes: int,
        config: Path | None,
        sets: tuple[str, ...],
        eval_episodes: int,
        targets: tuple[str, ...],
        seed: int,
        max_steps: int | None,
        no_progress: bool,
    ) -> None:
        """Collect expert data, train the DT pursuers, evaluate them, draw Figs. 14-17 (resumable)."""
        from hptvsim.experiments.dt_pipeline import run_pipeline
        from hptvsim.offline.policy import DEFAULT_TARGET

        try:
            run_pipeline(
                out=out,
                scenario=scenario,
                pursuers=pursuers,
                evader=evader,
                episodes=episodes,
                seed=seed,
                max_steps=max_steps,
                config=config,
                overrides={k: _parse_value(v) for k, v in _parse_pairs(sets, "KEY=VALUE").items()},
                eval_episodes=eval_episodes,
                targets=_targets(targets) or [DEFAULT_TARGET],
                progress=not no_progress,
                log=click.echo,
            )
        except (ValueError, FileNotFoundError) as exc:
            raise click.ClickException(str(exc)) from None
