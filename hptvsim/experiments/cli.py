"""Training commands: ``hptvsim train``, ``evaluate``, ``figures``, ``sweep``, ``reproduce``.

They start from the policy zoo's names (a config's fixed policies, ``--policy``), which sit above
training, so they live here, above the zoo; the offline-RL commands are in
:mod:`hptvsim.experiments.offline_cli`, which :func:`register` adds too.
"""

from __future__ import annotations

import sys
import tomllib
from pathlib import Path
from typing import Any

import click

__all__ = ["register"]


def parse_overrides(items: tuple[str, ...]) -> dict[str, Any]:
    """``KEY=VALUE`` pairs; VALUE is read as TOML (``3e-4``, ``true``, ``[64, 64]``), else as a string."""
    out: dict[str, Any] = {}
    for item in items:
        if "=" not in item:
            raise click.BadParameter(f"expected KEY=VALUE, got {item!r}", param_hint="--set")
        key, raw = item.split("=", 1)
        try:
            value = tomllib.loads(f"v = {raw}")["v"]
        except tomllib.TOMLDecodeError:
            value = raw
        out[key.strip()] = value
    return out


def default_run_dir(name: str, algo: str, seed: int) -> Path:
    """``hptvsim-out/runs/<name>-<algo>-seed<seed>``."""
    return Path("hptvsim-out") / "runs" / f"{name}-{algo}-seed{seed}"


def _parse_env(text: str, options: dict[str, Any]) -> Any:
    """``KIND:SCENARIO/TASK`` (``SCENARIO`` and ``TASK`` optional) as an EnvSpec.

    ``SCENARIO`` may be a scenario file's path (``hptvsim:my/site.toml/goto``): the task follows
    the last ``/``, and a text ending in ``.toml`` is a scenario file without a task.
    """
    from hptvsim.train.envs import EnvSpec

    kind, _, rest = text.partition(":")
    scenario, task = rest, ""
    if "/" in rest and not rest.endswith(".toml"):
        scenario, _, task = rest.rpartition("/")
    return EnvSpec(kind=kind, scenario=scenario or "source", task=task or "pursuit", options=options)


def _used_specs(spec: Any, default: str, over: dict[str, str]) -> list[str]:
    """The policy spec of every agent of the env ``spec`` (by agent, then role, then ``default``)."""
    from hptvsim.envs.metrics import agent_role
    from hptvsim.train.envs import make_parallel_env

    env = make_parallel_env(spec)
    try:
        agents = list(env.possible_agents)
    finally:
        env.close()
    return [over.get(a) or over.get(agent_role(a)) or default for a in agents]


def register(main: click.Group) -> None:
    """Add the training and the offline-RL commands to ``hptvsim``."""
    from hptvsim.experiments import offline_cli

    offline_cli.register(main)

    @main.command("train")
    @click.argument("config", required=False)
    @click.option(
        "--out",
        "out_dir",
        type=click.Path(file_okay=False, path_type=Path),
        default=None,
        help="Run folder (default: hptvsim-out/runs/<name>-<algo>-seed<seed>).",
    )
    @click.option(
        "--resume", is_flag=True, help="Continue the run in the run folder from its last checkpoint."
    )
    @click.option("--seed", type=int, default=None, help="Override the config's seed.")
    @click.option(
        "--algo", type=click.Choice(["maisac", "ippo"]), default=None, help="Override the algorithm."
    )
    @click.option(
        "--set",
        "overrides",
        multiple=True,
        metavar="KEY=VALUE",
        help="Override a config key, e.g. --set sac.backend=batched --set stage.0.budget_steps=500.",
    )
    @click.option("--no-progress", is_flag=True, help="No progress bars.")
    @click.option("--no-tensorboard", is_flag=True, help="No TensorBoard events.")
    @click.option(
        "--seeds",
        default=None,
        metavar="SEEDS",
        help="Batched configs (regime = 'fast'): train these seeds in one process, e.g. 0-9 or 0,3,7; "
        "each writes the folder a run of that seed alone writes (OUT/seed<k>).",
    )
    @click.option(
        "--device",
        type=click.Choice(["auto", "cpu", "cuda"]),
        default=None,
        help="Batched configs: where the learners run (default: the config's, 'auto').",
    )
    def train_cmd(
        config: str | None,
        out_dir: Path | None,
        resume: bool,
        seed: int | None,
        algo: str | None,
        overrides: tuple[str, ...],
        no_progress: bool,
        no_tensorboard: bool,
        seeds: str | None,
        device: str | None,
    ) -> None:
        """Train MAISAC or IPPO through a curriculum (CONFIG: a file or a shipped name: quick, paper, toy).

        Writes CSV and TensorBoard logs, checkpoints every `checkpoint_every` env steps and each
        stage's models (SB3 zip and .pth). Every stage is checked before the first step. After a
        kill or Ctrl-C, run the same command with --resume to go on from the last checkpoint; a
        CONFIG (or --set) that corrects stages not started yet is taken, one that changes what is
        trained already is refused.
        """
        from hptvsim.train.config import ConfigError, load_config, raw_config

        sets = parse_overrides(overrides)
        try:
            batched = config is not None and raw_config(config).get("regime") == "fast"
        except ConfigError as exc:
            raise click.ClickException(str(exc)) from None
        if batched:
            assert config is not None
            _train_batched(config, out_dir, resume, seed, seeds, algo, device, sets, not no_progress)
            return
        if seeds is not None or device is not None:
            raise click.UsageError(
                "--seeds and --device are for batched configs (regime = 'fast', e.g. 'fast')"
            )
        if seed is not None:
            sets["seed"] = seed
        if algo is not None:
            sets["algo"] = algo
        try:
            if config is None:
                if not (resume and out_dir is not None):
                    raise click.UsageError("give a CONFIG (or --resume --out RUN_DIR)")
                if not (out_dir / "config.toml").is_file():
                    raise click.ClickException(
                        f"--resume: {out_dir} holds no run (no config.toml); start it with a CONFIG"
                    )
                cfg = load_config(out_dir / "config.toml", sets)  # --set corrects the run's own config
            else:
                cfg = load_config(config, sets)
        except ConfigError as exc:
            raise click.ClickException(str(exc)) from None
        run_dir = out_dir if out_dir is not None else default_run_dir(cfg.name, cfg.algo, cfg.seed)
        from hptvsim.experiments.policies import named_policy  # torch: after the config is read
        from hptvsim.train.trainer import TrainingInterrupted, train

        try:
            result = train(
                cfg,
                run_dir,
                resume=resume,
                progress=not no_progress,
                tensorboard=not no_tensorboard,
                update_config=resume and (config is not None or bool(sets)),
                log=lambda line: click.echo(line, err=True),
                named=named_policy,
            )
        except TrainingInterrupted as exc:
            click.echo(str(exc), err=True)
            sys.exit(130)
        except (FileExistsError, FileNotFoundError, ValueError, RuntimeError) as exc:
            raise click.ClickException(str(exc)) from None
        click.echo(f"run folder: {result.run_dir.resolve()}")
        click.echo(f"env steps: {result.global_step}")
        for folder in result.stage_dirs:
            click.echo(f"models: {folder}")

    @main.command("evaluate")
    @click.argument("run_dirs", nargs=-1, type=click.Path(file_okay=False, exists=True, path_type=Path))
    @click.option(
        "--stage", default=None, help="Evaluate this stage's models and env (default: the last stage)."
    )
    @click.option(
        "--env",
        "env_text",
        default=None,
        metavar="KIND:SCENARIO/TASK",
        help="Environment (default: the runs' stage env), e.g. hptvsim:target/pursuit or toy:source/goto.",
    )
    @click.option(
        "--env-option",
        "env_options",
        multiple=True,
        metavar="KEY=VALUE",
        help="Environment option, over the runs' env or --env's (an observation option that "
        "contradicts the policies' own layout is refused).",
    )
    @click.option(
        "--policy",
        default=None,
        help="Policy of every agent without a more specific one: run:DIR[@STAGE], zip:PATH, "
        "scripted:NAME, toy:greedy, random (default: the run's models).",
    )
    @click.option("--pursuers", default=None, help="Policy spec of the pursuers.")
    @click.option("--evaders", default=None, help="Policy spec of the evaders.")
    @click.option(
        "--agent", "agent_specs", multiple=True, metavar="NAME=SPEC", help="Policy spec of one agent."
    )
    @click.option(
        "--episodes",
        type=click.IntRange(min=1),
        default=100,
        show_default=True,
        help="Episodes per policy set.",
    )
    @click.option(
        "--seed", type=int, default=0, show_default=True, help="Picks the fixed list of episode seeds."
    )
    @click.option("--label", default=None, help="Row name in the table (default: the run or the policy).")
    @click.option(
        "--json",
        "json_path",
        type=click.Path(dir_okay=False, path_type=Path),
        default=None,
        help="Write episodes and summaries as JSON.",
    )
    @click.option(
        "--md",
        "md_path",
        type=click.Path(dir_okay=False, path_type=Path),
        default=None,
        help="Write the Markdown table (appended to an existing file).",
    )
    def evaluate_cmd(
        run_dirs: tuple[Path, ...],
        stage: str | None,
        env_text: str | None,
        env_options: tuple[str, ...],
        policy: str | None,
        pursuers: str | None,
        evaders: str | None,
        agent_specs: tuple[str, ...],
        episodes: int,
        seed: int,
        label: str | None,
        json_path: Path | None,
        md_path: Path | None,
    ) -> None:
        """Capture rate, time to capture, collisions, distances and returns over fixed seeds.

        With RUN_DIRS (e.g. one per training seed) every run is evaluated with its own models
        in the env it trained in, and a last row gives the mean ± std across runs; a folder of
        seed<k> runs (`hptvsim train fast --out OUT`) counts as its runs. Without, give --env and
        the policies. Trained policies observe the layout they were trained on (extended_obs,
        from the run's config or policies/index.toml): no option needs to say it.
        """
        import json

        from hptvsim.envs.metrics import collision_causes
        from hptvsim.experiments.policies import LayoutError, layout_env, policies_from_specs
        from hptvsim.train.config import ConfigError, check_env_spec
        from hptvsim.train.envs import EnvSpec, make_env_factory
        from hptvsim.train.evaluate import across_seeds, evaluate, markdown_table
        from hptvsim.train.runs import expand_runs, obs_layout, open_run

        over: dict[str, str] = {}
        if pursuers:
            over["pursuer"] = pursuers
        if evaders:
            over["evader"] = evaders
        for item in agent_specs:
            agent_name, sep, agent_spec = item.partition("=")
            if not sep:
                raise click.BadParameter(f"expected NAME=SPEC, got {item!r}", param_hint="--agent")
            over[agent_name] = agent_spec
        user_options = parse_overrides(env_options)
        env_spec = _parse_env(env_text, user_options) if env_text else None
        if env_spec is not None:
            try:
                check_env_spec(env_spec, f"--env {env_spec.label()}")
            except ConfigError as exc:
                raise click.ClickException(str(exc)) from None
        # (label, env, default spec, specs by agent or role, the env is a run's own)
        jobs: list[tuple[str, EnvSpec, str, dict[str, str], bool]] = []
        for arg in run_dirs:
            try:  # a run folder, or a folder of seed<k> runs (`hptvsim train fast --out OUT`): a row each
                runs = [open_run(p) for p in expand_runs(arg)]
            except FileNotFoundError as exc:
                raise click.ClickException(str(exc)) from None
            for run in runs:
                try:  # the stage whose models play (or, with --policy, whose env)
                    st = run.stage(stage) if policy else run.models(stage)[1]
                except FileNotFoundError as exc:
                    raise click.BadParameter(str(exc), param_hint="--stage") from None
                spec = env_spec or st.env
                if env_spec is None and user_options:  # --env-option over the run's own env
                    spec = EnvSpec(
                        kind=spec.kind,
                        scenario=spec.scenario,
                        task=spec.task,
                        options={**spec.options, **user_options},
                    )
                run_over = {**dict(run.fixed), **over}
                default = policy or f"run:{run.folder}" + (f"@{stage}" if stage else "")
                name = run.folder.name if len(runs) == 1 else f"{arg.name}/{run.folder.name}"
                jobs.append((label or name, spec, default, run_over, env_spec is None))
        if not run_dirs:
            if env_spec is None or not (policy or over):
                raise click.UsageError(
                    "give RUN_DIRS, or --env and the policies (--policy/--pursuers/--evaders)"
                )
            jobs.append(
                (
                    label
                    or ", ".join(f"{k}={v}" for k, v in (({"all": policy} if policy else {}) | over).items()),
                    env_spec,
                    policy or "random",
                    over,
                    False,
                )
            )
        for k, (name, spec, default, run_over, own) in enumerate(jobs):
            if obs_layout(spec) is None:  # a game without observation options (3-D, toy)
                continue
            try:  # the policies' own observation layout (extended_obs), from their metadata
                # a run in its own env: its models' layout decides (its fixed policies played
                # in it during training as they will here)
                specs = [default] if own else _used_specs(spec, default, run_over)
                jobs[k] = (
                    name,
                    layout_env(spec, specs, explicit=tuple(user_options)),
                    default,
                    run_over,
                    own,
                )
            except LayoutError as exc:
                raise click.ClickException(str(exc)) from None
            except (KeyError, ValueError, RuntimeError, FileNotFoundError) as exc:
                raise click.ClickException(str(exc.args[0]) if exc.args else repr(exc)) from None
        results = []
        for name, spec, default, run_over, _ in jobs:
            try:
                res = evaluate(
                    make_env_factory(spec),
                    policies_from_specs(default, run_over, required=tuple(over)),
                    episodes=episodes,
                    seed=seed,
                    label=name,
                    progress=True,
                )
            except KeyError as exc:  # str() of a KeyError is the repr of its message
                raise click.ClickException(str(exc.args[0]) if exc.args else repr(exc)) from None
            except (FileNotFoundError, ValueError, RuntimeError) as exc:
                raise click.ClickException(str(exc)) from None
            results.append(res)
        rows = [(r.label, r.summary) for r in results]
        if len(results) > 1:
            rows.append((f"mean over {len(results)} runs", across_seeds(results)))
        table = markdown_table(rows)
        click.echo(table)
        for r in results:  # what collided with what (issue 37): the table has only the rate
            causes = collision_causes(r.episodes)
            if causes:
                hit = sum(1 for e in r.episodes if e.collided_with)
                listed = ", ".join(f"{k} {n}" for k, n in causes.items())
                click.echo(f"collisions, {r.label}: {listed} (in {hit} of {len(r.episodes)} episodes)")
        if json_path is not None:
            data: dict[str, Any] = {
                "runs": [{**r.as_dict(), "collision_causes": collision_causes(r.episodes)} for r in results]
            }
            if len(results) > 1:
                data["across_runs"] = across_seeds(results)
            json_path.parent.mkdir(parents=True, exist_ok=True)
            json_path.write_text(json.dumps(data, indent=2) + "\n")
            click.echo(f"json: {json_path}")
        if md_path is not None:
            md_path.parent.mkdir(parents=True, exist_ok=True)
            with md_path.open("a") as f:
                f.write(table + "\n")
            click.echo(f"markdown: {md_path}")

    @main.command("figures")
    @click.argument(
        "paths", nargs=-1, required=True, type=click.Path(file_okay=False, exists=True, path_type=Path)
    )
    @click.option(
        "--out",
        "out_dir",
        type=click.Path(file_okay=False, path_type=Path),
        default=None,
        help="Folder for the PNGs (default: figures/ in the first path).",
    )
    @click.option("--no-trajectories", is_flag=True, help="Skip the trajectory plots (they run episodes).")
    @click.option(
        "--smooth",
        type=click.IntRange(1, 1000),
        default=None,
        help="Moving-average window of the reward curves, in episodes (default: the sweep's, else 5).",
    )
    def figures_cmd(
        paths: tuple[Path, ...], out_dir: Path | None, no_trajectories: bool, smooth: int | None
    ) -> None:
        """The paper's figures from training runs, sweeps or DT runs (PATHS), as PNG files.

        Training runs and sweeps: reward curves per stage and role with 95 % bands over seeds
        (Figs. 7-10: MAISAC vs IPPO, or per sweep setting), each agent's own reward curve, the
        final rewards' mean and variance per setting (Fig. 11) and one episode's trajectories
        per stage (Figs. 12-13). DT runs (a folder with dt.pt): Figs. 14-17.
        """
        from hptvsim.experiments.figures import RunFileError, WindowError, make_figures

        out = out_dir if out_dir is not None else paths[0] / "figures"
        try:
            written = make_figures(
                list(paths),
                out,
                with_trajectories=not no_trajectories,
                smooth=smooth,
                note=lambda line: click.echo(f"warning: {line}", err=True),
            )
        except (FileNotFoundError, RunFileError, WindowError) as exc:
            raise click.ClickException(str(exc)) from None
        for p in written:
            click.echo(str(p))

    @main.command("sweep")
    @click.argument("sweep_file", type=click.Path(dir_okay=False, exists=True, path_type=Path))
    @click.option(
        "--out",
        "out_dir",
        type=click.Path(file_okay=False, path_type=Path),
        default=None,
        help="Folder of the sweep (default: hptvsim-out/sweeps/<name>).",
    )
    @click.option("--address", default=None, help="Ray cluster address (default: start a local Ray).")
    @click.option("--num-cpus", type=int, default=None, help="CPUs of the local Ray (one job each).")
    @click.option("--serial", is_flag=True, help="No Ray: run the jobs one after another here.")
    def sweep_cmd(
        sweep_file: Path, out_dir: Path | None, address: str | None, num_cpus: int | None, serial: bool
    ) -> None:
        """Run a sweep file: one training job per (setting, seed) on Ray; finished jobs are skipped."""
        from hptvsim.experiments.sweeps import load_sweep, run_sweep
        from hptvsim.train.config import ConfigError

        try:
            spec = load_sweep(sweep_file)
        except ConfigError as exc:
            raise click.ClickException(str(exc)) from None
        out = out_dir if out_dir is not None else Path("hptvsim-out") / "sweeps" / spec.name
        results = run_sweep(spec, out, address=address, num_cpus=num_cpus, serial=serial)
        failed = [r for r in results if r.get("status") == "failed"]
        for r in results:
            click.echo(f"{r['status']:>12}  {r['run_dir']}" + (f"  ({r['error']})" if "error" in r else ""))
        click.echo(f"sweep folder: {out.resolve()}  (figures: hptvsim figures {out})")
        if failed:
            sys.exit(1)

    @main.command("reproduce")
    @click.option(
        "--plan",
        "plan_file",
        default="section5",
        show_default=True,
        help="A plan file, or the name of a shipped one (configs/reproduce/<name>.toml).",
    )
    @click.option(
        "--out",
        "out_dir",
        type=click.Path(file_okay=False, path_type=Path),
        default=None,
        help="Folder of the runs (default: hptvsim-out/reproduce/<plan name>).",
    )
    @click.option(
        "--report",
        type=click.Path(dir_okay=False, path_type=Path),
        default=Path("docs/reproduction.md"),
        show_default=True,
        help="The Markdown report; its figures go to a folder of the same stem beside it.",
    )
    @click.option(
        "--workers", type=click.IntRange(1, 64), default=None, help="Runs side by side (default: the plan's)."
    )
    @click.option(
        "--experiment",
        "experiments",
        multiple=True,
        help="Only this experiment's runs (repeatable); 'dt': the plan's DT steps and the expert runs "
        "they need.",
    )
    @click.option("--seed", "seeds", type=int, multiple=True, help="Only this training seed (repeatable).")
    @click.option("--report-only", is_flag=True, help="Write the report from the runs found; train nothing.")
    @click.option(
        "--status",
        "status_only",
        is_flag=True,
        help="Print each run's state and env steps (run folders and archive), each DT step's state, and the "
        "running sweep's rate and time left; write and train nothing.",
    )
    @click.option("--no-figures", is_flag=True, help="Write the report without figures.")
    @click.option(
        "--address",
        envvar="RAY_ADDRESS",
        default=None,
        help="Run every run and DT step as a Ray task on this cluster (HOST:PORT, ray://HOST:PORT or "
        "auto; default: $RAY_ADDRESS, else local processes); --out and the plan on storage every node "
        "shares. With --status: also the cluster's nodes and which run each trains.",
    )
    def reproduce_cmd(
        plan_file: str,
        out_dir: Path | None,
        report: Path,
        workers: int | None,
        experiments: tuple[str, ...],
        seeds: tuple[int, ...],
        report_only: bool,
        status_only: bool,
        no_figures: bool,
        address: str | None,
    ) -> None:
        """The paper's section-V experiments on the pursuit game, with seeds, intervals and verdicts.

        Trains every (setting, seed) the plan needs (resuming killed runs, skipping finished
        ones), evaluates every stage on fixed seeds, and writes the report with its figures and
        the verdict on each of the paper's claims. Ctrl-C (or SIGTERM to this process) stops
        each run in progress at the end of its episode with a checkpoint, so nothing is lost (a
        second Ctrl-C stops at once); a hard kill loses at most the config's `checkpoint_every` env
        steps per run. Run the same command again to go on.
        """
        from hptvsim.experiments.reproduce import (
            DT_EXPERIMENT,
            archive_dir,
            dt_status,
            load_plan,
            plan_dt_jobs,
            plan_jobs,
            reproduce,
            resolve_plan_path,
            sweep_eta,
            sweep_status,
            workers_warning,
            write_report,
        )
        from hptvsim.train.config import ConfigError

        if report_only and status_only:
            raise click.UsageError("give one of --status and --report-only, not both")
        try:
            if address:  # first: a refused address costs no planning
                from hptvsim.experiments.repro_cluster import check_address

                check_address(address)
            plan = load_plan(resolve_plan_path(plan_file))
            for e in experiments:
                if not (e == DT_EXPERIMENT and plan.dt is not None):
                    plan.experiment(e)
            bad = [s for s in seeds if s not in plan.seeds]
            if bad:
                raise ConfigError(
                    f"--seed {bad[0]} is not a seed of the plan; valid: {', '.join(map(str, plan.seeds))}"
                )
        except ConfigError as exc:
            raise click.ClickException(str(exc)) from None
        except KeyError as exc:
            valid = [e.id for e in plan.experiments] + ([DT_EXPERIMENT] if plan.dt is not None else [])
            raise click.ClickException(
                f"--experiment {exc.args[0]!r} is unknown; valid: {', '.join(valid)}"
            ) from None
        out = out_dir if out_dir is not None else Path("hptvsim-out") / "reproduce" / plan.name
        if status_only:
            rows = sweep_status(plan, out, archive_dir(report, plan))
            width = max(len(j.run_dir) for j, *_ in rows)
            for job, state, done, total in rows:
                click.echo(f"{job.run_dir:<{width}}  {done:>9,} / {total:,} env steps  {state}")
            n_done = sum(1 for _, state, _, _ in rows if state.startswith("finished"))
            steps = sum(min(done, total) for _, _, done, total in rows)
            all_steps = sum(total for *_, total in rows)
            dts = dt_status(plan, out, archive_dir(report, plan))
            for dt_job, state in dts:
                click.echo(f"{dt_job.run_dir:<{width}}  {'DT step':>21}  {state}")
            n_dt = sum(1 for _, state in dts if state.startswith("finished"))
            click.echo(
                f"{n_done} of {len(rows)} runs finished; {steps:,} of {all_steps:,} env steps "
                f"({100.0 * steps / max(all_steps, 1):.1f} %); runs in {out}, "
                f"archive {archive_dir(report, plan)}"
                + (f"; {n_dt} of {len(dts)} DT steps finished" if dts else "")
            )
            click.echo(sweep_eta(out, all_steps - steps))
            if address:
                from hptvsim.experiments.repro_cluster import cluster_status

                try:
                    lines = cluster_status(
                        address, out, [j.run_dir for j, *_ in rows] + [j.run_dir for j, _ in dts]
                    )
                except ConfigError as exc:
                    raise click.ClickException(str(exc)) from None
                for line in lines:
                    click.echo(line)
            return
        if report_only:
            click.echo(str(write_report(plan, out, report, figures=not no_figures)))
            return
        n = len(plan_jobs(plan, experiments=experiments or None, seeds=seeds or None))
        n_dt = len(plan_dt_jobs(plan, experiments=experiments or None, seeds=seeds or None))
        runs = (
            f"{n} run" + ("" if n == 1 else "s") + (f" and {n_dt} DT step{'s' * (n_dt != 1)}" if n_dt else "")
        )
        side = "on the Ray cluster" if address else f"({workers or plan.workers} side by side)"
        click.echo(f"{runs} in {out} {side}; report: {report}")
        note = None if address else workers_warning(workers or plan.workers)
        if note:
            click.echo(note, err=True)
        try:
            statuses = reproduce(
                plan,
                out,
                report,
                workers=workers,
                experiments=experiments or None,
                seeds=seeds or None,
                figures=not no_figures,
                log=click.echo,
                address=address or None,
            )
        except ConfigError as exc:  # the cluster refused: a bad address, a node without the shared folder
            raise click.ClickException(str(exc)) from None
        except KeyboardInterrupt:
            click.echo("interrupted; run the same command to go on", err=True)
            sys.exit(130)
        if any(st.get("status") == "failed" for st in statuses.values()):
            sys.exit(1)


def parse_seeds(text: str) -> tuple[int, ...]:
    """``"0-9"``, ``"0,3,7"`` or ``"4"`` -> the seeds.

    Raises:
        click.BadParameter: Not of that form, a seed below 0 or a range that runs backwards.
    """
    out: list[int] = []
    try:
        for part in text.split(","):
            part = part.strip()
            if "-" in part:
                lo, hi = (int(v) for v in part.split("-", 1))
                if hi < lo:
                    raise ValueError
                out.extend(range(lo, hi + 1))
            else:
                out.append(int(part))
    except ValueError:
        raise click.BadParameter(
            f"{text!r} is not a seed list; valid: 0-9, 0,3,7 or 4", param_hint="--seeds"
        ) from None
    if any(s < 0 for s in out) or len(set(out)) != len(out) or not out:
        raise click.BadParameter(f"{text!r}: seeds must be distinct and >= 0", param_hint="--seeds")
    return tuple(out)


def _train_batched(
    config: str,
    out_dir: Path | None,
    resume: bool,
    seed: int | None,
    seeds: str | None,
    algo: str | None,
    device: str | None,
    sets: dict[str, Any],
    progress: bool,
) -> None:
    """``hptvsim train`` of a batched config (``regime = "fast"``; :mod:`hptvsim.train.batched_run`)."""
    from hptvsim.train.batched_run import batched_config_from_dict
    from hptvsim.train.config import ConfigError, apply_overrides, raw_config, resolve_config_path

    data = apply_overrides(raw_config(config), sets)
    if algo is not None:
        data["algo"] = algo
    if seeds is not None and seed is not None:
        raise click.UsageError("give --seed or --seeds, not both")
    if seed is not None:
        data["seeds"] = [seed]
    if seeds is not None:
        data["seeds"] = list(parse_seeds(seeds))
    if device is not None:
        data["device"] = device
    try:
        cfg = batched_config_from_dict(data, where=str(resolve_config_path(config)))
    except ConfigError as exc:
        raise click.ClickException(str(exc)) from None
    run_dir = out_dir if out_dir is not None else Path("hptvsim-out") / "runs" / cfg.name
    from hptvsim.experiments.policies import zoo_fixed
    from hptvsim.train.batched_run import train_batched

    try:
        result = train_batched(
            cfg,
            None,
            run_dir,
            fixed=zoo_fixed(cfg.fixed) if cfg.fixed else None,
            resume=resume,
            progress=progress,
        )
    except (FileNotFoundError, ValueError) as exc:
        raise click.ClickException(str(exc)) from None
    for folder, cap, reached in zip(result.folders, result.final_capture, result.reached_s, strict=True):
        when = "not reached" if reached is None else f"reached at {reached:.0f} s"
        click.echo(
            f"{folder}: capture {cap:.2f} of {cfg.eval_episodes} fixed episodes; "
            f"{cfg.target_capture:.2f} {when}; models in {folder / 'models'}"
        )
    click.echo(f"{result.game_steps:,} game steps per seed in {result.wall_s:.0f} s")
