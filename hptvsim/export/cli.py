"""``hptvsim policy ...``: policies out of Python (``hptvsim policy export``)."""

from __future__ import annotations

from pathlib import Path

import click

__all__ = ["register"]


@click.group("policy")
def policy() -> None:
    """Trained policies out of Python: export to ONNX for a companion computer."""


@policy.command("export")
@click.argument("spec")
@click.option(
    "--out",
    "out_dir",
    type=click.Path(file_okay=False, path_type=Path),
    required=True,
    help="Folder for <agent>.onnx (made if missing).",
)
@click.option(
    "--scenario",
    default=None,
    help="Scenario whose observation layout the metadata describes (default: the one it was trained on).",
)
@click.option(
    "--agent", "agents", multiple=True, help="Only this agent (repeatable; names a lone file's agent)."
)
def export_cmd(spec: str, out_dir: Path, scenario: str | None, agents: tuple[str, ...]) -> None:
    """Write DIR/<agent>.onnx for each agent SPEC drives (SPEC: zoo name, run:DIR[@STAGE], zip:PATH).

    Input ``obs`` [batch, n_obs] float32, output ``action`` [batch, n_act] float32 (the
    deterministic action in the game's step units), metadata in the file; each export is checked
    against SB3's predict on real and sampled observations before it is written. A Decision
    Transformer (dt-pursuers, dt:PATH) takes its context as inputs instead (hptvsim.export.dt).
    """
    from hptvsim.export.build import ExportError, export_policy

    try:
        done = export_policy(spec, out_dir, scenario=scenario, agents=agents)
    except ExportError as exc:
        raise click.ClickException(str(exc)) from None
    for e in done:
        click.echo(
            f"wrote {e.path} (obs {e.n_obs}, action {e.n_act}; max |onnxruntime - {e.reference}| "
            f"{e.max_abs_diff:.2g} over {e.checked} observations)"
        )


def register(main: click.Group) -> None:
    """Add the ``policy`` group to ``hptvsim``."""
    main.add_command(policy)
