"""Commands of the visualisation layer.

``hptvsim episode``, ``replay``, ``view``, ``viz schema``.
"""

from __future__ import annotations

import json
import sys
from pathlib import Path
from typing import Any

import click

__all__ = ["register"]


def _repo_web() -> Path:
    from hptvsim._paths import checkout_dir

    top = checkout_dir()
    if top is None:
        raise click.UsageError("this is an installed copy, not a checkout: give the output folder with --out")
    return top / "web"


def _report_episode(result: Any, record: Path | None, json_out: Path | None, *, note: str = "") -> None:
    """Print an episode's outcome and metrics and write its JSON (``note``: what part of it ran)."""
    s = result.summary
    click.echo(
        f"{result.static.scenario}: {s.outcome} after {s.steps} steps ({s.sim_time:.1f} s simulated, "
        f"{s.wall_time:.2f} s wall)"
    )
    for c in s.collisions:
        where = f"({c.x:.1f}, {c.y:.1f}" + (f", {c.z:.1f}" if c.z is not None else "") + ") m"
        when = f"t = {c.time:.1f} s (step {c.step})"
        click.echo(f"collision: {c.agent} with {c.collided_with} at {where}, {when}")
    click.echo(json.dumps(s.to_dict()["metrics"], indent=2))
    kept = f" ({note})" if note else ""
    if record is not None:
        click.echo(f"recording{kept}: {record.resolve()}  (open it with `hptvsim replay {record}`)")
    if json_out is not None:
        json_out.parent.mkdir(parents=True, exist_ok=True)
        json_out.write_text(json.dumps(result.to_dict()))
        click.echo(f"episode JSON{kept}: {json_out.resolve()}")


def _policy_options(policy: tuple[str, ...]) -> dict[str, str]:
    out: dict[str, str] = {}
    for item in policy:
        agent, sep, spec = item.partition("=")
        if not sep or not agent or not spec:
            raise click.BadParameter(f"{item!r} is not AGENT=SPEC (e.g. pursuer_0=scripted:pure_pursuit)")
        out[agent] = spec
    return out


# --- argument checks of the visualisation layer's commands -----------------------------------------


def check_scenario_arg(scenario: str, **_: Any) -> None:
    """``--scenario`` must be a shipped scenario's name or a valid scenario file.

    Raises:
        click.BadParameter: It is neither (the message lists the shipped names).
    """
    from hptvsim.world.scenario import ScenarioError, load_scenario

    try:
        load_scenario(scenario)
    except ScenarioError as exc:
        raise click.BadParameter(str(exc), param_hint="--scenario") from None


def _check_policy_args(
    agents: Any, scenario: str, policy: tuple[str, ...], *, allow_paths: bool, game: str = "planar"
) -> None:
    """Each ``--policy AGENT=SPEC`` names an agent of the scenario and a policy for its role and game."""
    from hptvsim.zoo import check_policy_spec

    roles = {a.name: a.role for a in agents}
    for item in policy:
        agent, sep, spec = item.partition("=")
        if not sep or not agent or not spec:
            continue  # the command itself says what AGENT=SPEC looks like
        if agent not in roles:
            raise click.BadParameter(
                f"unknown agent {agent!r} in {item!r}; agents of {scenario}: {', '.join(roles)}",
                param_hint="--policy",
            )
        try:
            check_policy_spec(spec, roles[agent], allow_paths=allow_paths, agent=agent, game=game)
        except ValueError as exc:
            raise click.BadParameter(str(exc), param_hint="--policy") from None


def _check_seed(seed: int | None) -> None:
    if seed is not None and seed < 0:
        raise click.BadParameter(f"{seed} is invalid; valid: an integer >= 0", param_hint="--seed")


def check_episode_args(
    scenario: str,
    policy: tuple[str, ...],
    seed: int | None,
    max_steps: int | None,
    record: Path | None,
    json_out: Path | None,
    **_: Any,
) -> None:
    """The arguments of ``hptvsim episode``, checked before it builds anything.

    Raises:
        click.BadParameter: An unknown or invalid scenario, an agent the scenario does not have,
            a policy unknown or made for another role or game (the same rule as the service's), a
            negative seed, a step limit below 1, or an output folder that cannot be made.
    """
    from hptvsim.episodes.scenarios import resolve_scenario
    from hptvsim.world.scenario import ScenarioError

    try:
        sc = resolve_scenario(scenario, allow_paths=True)
    except ScenarioError as exc:
        raise click.BadParameter(str(exc), param_hint="--scenario") from None
    _check_policy_args(sc.agents, scenario, policy, allow_paths=True, game=sc.simulation.game)
    _check_seed(seed)
    if max_steps is not None and max_steps < 1:
        raise click.BadParameter(f"{max_steps} is invalid; valid: an integer >= 1", param_hint="--max-steps")
    for path, hint in ((record, "--record"), (json_out, "--json")):
        if path is not None:
            try:
                path.parent.mkdir(parents=True, exist_ok=True)
            except OSError as exc:
                raise click.BadParameter(f"cannot write {path}: {exc.strerror}", param_hint=hint) from None


def check_view_args(
    scenario: str, policy: tuple[str, ...], seed: int, port: int, speed: float, **_: Any
) -> None:
    """The arguments of ``hptvsim view``: shipped names only, as for the service's clients.

    Raises:
        click.BadParameter: Not a shipped scenario, an unknown agent or policy, a policy for
            another role or game, a seed out of range, a port out of range, or a speed that is not positive.
    """
    from hptvsim.catalog import CatalogError, check_scenario, check_seed, shipped_scenario

    try:
        sc = shipped_scenario(check_scenario(scenario))
    except CatalogError as exc:
        raise click.BadParameter(str(exc), param_hint="--scenario") from None
    _check_policy_args(sc.agents, scenario, policy, allow_paths=False, game=sc.simulation.game)
    try:
        check_seed(seed)
    except CatalogError as exc:
        raise click.BadParameter(str(exc), param_hint="--seed") from None
    if not 0 <= port <= 65535:
        raise click.BadParameter(f"{port} is invalid; valid: 0..65535", param_hint="--port")
    if not speed > 0:
        raise click.BadParameter(
            f"{speed} is invalid; valid: a number > 0 (x real time)", param_hint="--speed"
        )


def check_web_out(out_dir: Path | None, check: bool, **_: Any) -> None:
    """``hptvsim viz schema --out DIR``: DIR must be a folder that can be made (unless ``--check``).

    Raises:
        click.BadParameter: It cannot.
    """
    if out_dir is not None and not check:
        try:
            out_dir.mkdir(parents=True, exist_ok=True)
        except OSError as exc:
            raise click.BadParameter(f"cannot make {out_dir}: {exc.strerror}", param_hint="--out") from None


def register(main: click.Group) -> None:
    """Add the visualisation commands to ``main``."""

    @main.group("viz")
    def viz() -> None:
        """The frame schema shared by recordings, the API, viser and the dashboard."""

    @viz.command("schema")
    @click.option(
        "--out",
        "out_dir",
        type=click.Path(file_okay=False, path_type=Path),
        default=None,
        help="The web folder to write into (default: the checkout's web/).",
    )
    @click.option(
        "--check", is_flag=True, help="Fail if the written files differ from what would be generated."
    )
    def viz_schema(out_dir: Path | None, check: bool) -> None:
        """Write web/schema/frames.schema.json and web/js/frames.gen.js from hptvsim/episodes/frames.py."""
        check_web_out(out_dir, check)
        from hptvsim.episodes.frames import json_schema, schema_js

        web = out_dir if out_dir is not None else _repo_web()
        schema = json_schema()
        files = {
            web / "schema" / "frames.schema.json": json.dumps(schema, indent=2) + "\n",
            web / "js" / "frames.gen.js": schema_js(schema),
        }
        stale = []
        for path, text in files.items():
            if check:
                if not path.is_file() or path.read_text() != text:
                    stale.append(str(path))
                continue
            path.parent.mkdir(parents=True, exist_ok=True)
            path.write_text(text)
            click.echo(f"wrote {path}")
        if stale:
            click.echo(f"out of date: {', '.join(stale)} (run `hptvsim viz schema`)", err=True)
            sys.exit(1)

    @main.command("episode")
    @click.option(
        "--scenario", default="target", show_default=True, help="Shipped scenario name or TOML path."
    )
    @click.option(
        "--policy",
        multiple=True,
        metavar="AGENT=SPEC",
        help="A zoo policy for an agent (repeatable); others follow their role's default "
        "(the shipped trained one).",
    )
    @click.option("--seed", type=int, default=None, help="Episode seed (default: the scenario's).")
    @click.option("--max-steps", type=int, default=None, help="Step limit (default: the scenario's).")
    @click.option("--sensor-fidelity", type=click.Choice(["geometric", "signal"]), default=None)
    @click.option("--backend", type=click.Choice(["batched", "fmu"]), default="batched", show_default=True)
    @click.option(
        "--record",
        "record",
        type=click.Path(dir_okay=False, path_type=Path),
        default=None,
        help="Write the rerun recording here (.rrd).",
    )
    @click.option(
        "--json",
        "json_out",
        type=click.Path(dir_okay=False, path_type=Path),
        default=None,
        help="Write the summary, static part and trajectories here as JSON.",
    )
    def episode_cmd(
        scenario: str,
        policy: tuple[str, ...],
        seed: int | None,
        max_steps: int | None,
        sensor_fidelity: str | None,
        backend: str,
        record: Path | None,
        json_out: Path | None,
    ) -> None:
        """Run one episode, print its outcome and metrics, optionally record it.

        Ctrl-C stops it at the next step and still writes what ran (a second Ctrl-C quits at
        once); so does a simulation that fails part-way, which then exits with status 1.
        """
        check_episode_args(scenario, policy, seed, max_steps, record, json_out)
        import signal
        import threading

        from hptvsim.episodes.runner import run_episode
        from hptvsim.episodes.stepper import SimulationError
        from hptvsim.viz.recording import recorder

        stop = threading.Event()

        def on_interrupt(signum: int, frame: Any) -> None:
            stop.set()  # the episode ends as "cancelled" after this step, with its files
            signal.signal(signal.SIGINT, signal.default_int_handler)

        previous = signal.signal(signal.SIGINT, on_interrupt)
        try:
            result = run_episode(
                scenario,
                _policy_options(policy),
                seed=seed,
                max_steps=max_steps,
                sensor_fidelity=sensor_fidelity,  # type: ignore[arg-type]  # click.Choice checked it
                backend=backend,  # type: ignore[arg-type]  # click.Choice checked it
                cancel=stop,
                recorder=recorder(record, None),
                progress=True,
                allow_paths=True,
            )
        except SimulationError as exc:
            if exc.partial is not None:
                _report_episode(exc.partial, record, json_out, note="up to the failure")
            raise click.ClickException(f"the simulation failed: {exc}") from None
        except (OSError, ValueError) as exc:  # a model that does not fit the scenario, or unreadable
            raise click.ClickException(str(exc)) from None
        finally:
            signal.signal(signal.SIGINT, previous)
        _report_episode(result, record, json_out, note="up to Ctrl-C" if stop.is_set() else "")
        if stop.is_set():
            sys.exit(130)  # the shell's code for a run stopped by SIGINT

    @main.command("replay")
    @click.argument("file", type=click.Path(exists=True, dir_okay=False, path_type=Path))
    @click.option("--web", is_flag=True, help="Serve the rerun web viewer (offline, from the pip install).")
    @click.option(
        "--host",
        default="127.0.0.1",
        show_default=True,
        help="Address the web viewer listens on (--web); 0.0.0.0 lets other machines connect.",
    )
    @click.option(
        "--port",
        type=click.IntRange(0, 65535),
        default=9090,
        show_default=True,
        help="Web viewer port (--web).",
    )
    @click.option(
        "--grpc-port",
        type=click.IntRange(0, 65535),
        default=9876,
        show_default=True,
        help="Data port (--web).",
    )
    @click.option("--no-browser", is_flag=True, help="Do not open a browser (--web).")
    def replay(file: Path, web: bool, host: str, port: int, grpc_port: int, no_browser: bool) -> None:
        """Open a recording (.rrd) in the rerun viewer (the native one, or --web).

        With --web it serves until Ctrl-C, on this machine only unless --host says otherwise.
        """
        from hptvsim.viz.replay import replay_native, replay_web

        try:
            if web:
                code = replay_web(
                    file, web_port=port, grpc_port=grpc_port, host=host, open_browser=not no_browser
                )
            else:
                code = replay_native(file)
        except (OSError, ValueError, RuntimeError) as exc:
            raise click.ClickException(str(exc)) from None
        if code != 0:
            raise click.ClickException(f"the rerun viewer stopped with exit code {code}")

    @main.command("view")
    @click.option("--scenario", default="target", show_default=True, help="Shipped scenario name.")
    @click.option(
        "--policy", multiple=True, metavar="AGENT=SPEC", help="A zoo policy for an agent (repeatable)."
    )
    @click.option("--seed", type=int, default=0, show_default=True)
    @click.option("--host", default="127.0.0.1", show_default=True)
    @click.option("--port", type=int, default=8080, show_default=True)
    @click.option("--speed", type=float, default=4.0, show_default=True, help="x real time.")
    def view(scenario: str, policy: tuple[str, ...], seed: int, host: str, port: int, speed: float) -> None:
        """Live 3D view (viser) of episodes, with play/pause, speed, reset and pickers."""
        check_view_args(scenario, policy, seed, port, speed)
        import time

        from hptvsim.viz.viser_view import LiveView

        live = LiveView(
            host=host, port=port, scenario=scenario, policies=_policy_options(policy), seed=seed, speed=speed
        )
        live.start()
        click.echo(f"viser view: http://{host}:{live.port}  (Ctrl-C to stop)")
        try:
            while True:
                time.sleep(1.0)
        except KeyboardInterrupt:
            pass
        finally:
            live.stop()
