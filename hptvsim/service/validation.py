"""Turning an episode request into a job: the checks that need the scenario and the settings.

A client's scenario is data: it is validated by the one scenario schema
(:meth:`hptvsim.world.scenario.Scenario.from_dict`), and before that screened for what the
schema allows a local user but a service must not: terrain files outside the shipped data
folder, and sizes (grid cells, vehicles, sonar beams, integration steps) that would exhaust the
machine. Policies are named, never loaded from a path a client sends; FMUs are the shipped ones.
Every problem is an :class:`ApiError` naming the request field.
"""

from __future__ import annotations

import math
from collections.abc import Collection, Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from hptvsim.service.schemas import EpisodeCreate
from hptvsim.service.settings import Settings

__all__ = [
    "ApiError",
    "Resolved",
    "check_episode_costs",
    "check_policies_fit",
    "refuse_control_characters",
    "resolve_request",
    "scenario_summary",
    "screen_inline",
    "shipped_scenario",
]

MAX_BEAMS = 1024
MAX_RECORD_SAMPLES = 200_000
MAX_SUBSTEPS = 1000  # dt / h_max


class ApiError(Exception):
    """An error answered to the client.

    Args:
        status: HTTP status.
        detail: One line naming the field and what would be valid.
        field: The offending field's dotted path, if one.
        type: The error's type in ``ErrorBody.errors``.
        headers: Headers of the answer (e.g. ``Retry-After``), if any.
    """

    def __init__(
        self,
        status: int,
        detail: str,
        field: str | None = None,
        type: str = "value_error",
        headers: dict[str, str] | None = None,
    ) -> None:
        super().__init__(detail)
        self.status = status
        self.detail = detail
        self.field = field
        self.type = type
        self.headers = headers


@dataclass(frozen=True, kw_only=True)
class Resolved:
    """A validated request, ready to become a job."""

    scenario_ref: str | dict[str, Any]  # shipped name or validated tables
    scenario_label: str
    agents: tuple[str, ...]
    roles: dict[str, str]
    policies: dict[str, str]  # agent -> policy, for the agents the server drives
    control: tuple[str, ...]
    max_steps: int


def shipped_scenario(name: str) -> Any:
    """A shipped scenario by name (:func:`hptvsim.catalog.shipped_scenario`).

    Raises:
        ApiError: 422 naming ``scenario`` when there is no such shipped scenario (lists the names).
    """
    from hptvsim.catalog import CatalogError
    from hptvsim.catalog import shipped_scenario as load

    if isinstance(name, str):
        refuse_control_characters(name, "scenario")
    try:
        return load(name)
    except CatalogError as exc:
        raise ApiError(422, f"scenario: {exc}", "scenario") from None


def scenario_summary(scenario: Any) -> dict[str, Any]:
    """What the scenario list shows about a scenario (with each agent's display colour)."""
    from hptvsim.palette import ROLES, agent_colors
    from hptvsim.zoo import default_policy

    agents = scenario.agents
    return {
        "name": scenario.name,
        "description": scenario.description,
        "task": scenario.task.kind,
        "site_size": (float(scenario.site.size[0]), float(scenario.site.size[1])),
        "agents": [a.name for a in agents],
        "roles": {a.name: a.role for a in agents},
        "colors": agent_colors((a.name, a.role) for a in agents),
        "game": scenario.simulation.game,
        "default_policies": {
            role: default_policy(role, scenario.task.kind, scenario.simulation.game) for role in ROLES
        },
        "max_steps": int(scenario.simulation.max_steps),
        "dt": float(scenario.simulation.dt),
    }


def _number(value: Any) -> float | None:
    if isinstance(value, bool) or not isinstance(value, int | float):
        return None
    return float(value)


def refuse_control_characters(raw: str, field: str) -> None:
    """A 422 naming ``field`` when a string that becomes a path holds a control character (NUL...).

    The file system refuses a NUL byte with an exception (``ValueError: embedded null byte``), and
    no file name the service reads holds a control character.
    """
    bad = next((c for c in raw if ord(c) < 32 or 127 <= ord(c) < 160), None)
    if bad is not None:
        raise ApiError(
            422,
            f"{field}: holds the control character U+{ord(bad):04X}; valid: a file name of printable "
            "characters",
            field,
        )


def _shipped_file(raw: Any, field: str, folder: str, example: str) -> Path:
    """A shipped file named relative to the scenarios folder, inside ``folder``; else a 422.

    Control characters, absolute paths, ``~``, ``..``, backslashes and anything that resolves
    outside the shipped folder are refused before the file system is asked about them.
    """
    from hptvsim.world.scenario import scenario_dir

    if not isinstance(raw, str) or not raw:
        raise ApiError(422, f"{field}: give a shipped file, e.g. {example}", field)
    refuse_control_characters(raw, field)
    p = Path(raw)
    root = scenario_dir().resolve()
    if p.is_absolute() or raw.startswith("~") or ".." in p.parts or "\\" in raw:
        raise ApiError(
            422,
            f"{field}: {raw!r} is not allowed; the service reads only the shipped files, named relative "
            f"to the scenarios folder (e.g. {example})",
            field,
        )
    shipped_root = (root / folder).resolve()
    try:
        resolved = (root / p).resolve()
        shipped_file = resolved.is_relative_to(shipped_root) and resolved.is_file()
    except (OSError, ValueError):  # a name too long for the file system, say
        shipped_file = False
    if not shipped_file:
        shipped = sorted(
            str(f.relative_to(root))
            for f in shipped_root.glob("*")
            if f.is_file() and f.suffix not in (".py", ".md")
        )
        raise ApiError(422, f"{field}: {raw!r} is not a shipped file; valid: {', '.join(shipped)}", field)
    return resolved


def screen_inline(data: Mapping[str, Any], settings: Settings) -> None:
    """Checks on a client's raw scenario tables before the schema builds anything from them."""
    from hptvsim.world.scenario import TERRAIN_KINDS

    terrain = data.get("terrain", {})
    kind = terrain.get("kind", "flat") if isinstance(terrain, Mapping) else None
    # file terrain: only the shipped data files, named relative to the scenarios folder
    if kind == "file" and isinstance(terrain, Mapping):
        _shipped_file(terrain.get("path"), "scenario.terrain.path", "data", "data/salish_sea.tif")
    # vehicle files: only the shipped ones (Fossen parameters; never an FMU: that is native code)
    raw_groups = data.get("vehicles")
    for i, g in enumerate(raw_groups if isinstance(raw_groups, list) else []):
        if isinstance(g, Mapping) and "vehicle_file" in g:
            field = f"scenario.vehicles[{i}].vehicle_file"
            path = _shipped_file(g["vehicle_file"], field, "vehicles", "vehicles/bluerov2_heavy.toml")
            from hptvsim.cosim.vehicles import ExternalVehicleType, VehicleFileError, load_vehicle_file

            try:
                external = isinstance(load_vehicle_file(path), ExternalVehicleType)
            except VehicleFileError:
                external = False  # the scenario's own check reports it
            if external:  # pragma: no cover - no shipped vehicle file brings an FMU
                raise ApiError(422, f"{field}: this service runs no external vehicle FMUs", field)
    # grid size: site / resolution
    site = data.get("site", {})
    size = site.get("size", (400.0, 300.0)) if isinstance(site, Mapping) else None
    cls = TERRAIN_KINDS.get(kind) if isinstance(kind, str) else None
    resolution: float | None = None
    if isinstance(terrain, Mapping) and "resolution" in terrain:
        resolution = _number(terrain["resolution"])
    elif cls is not None:
        default = cls.__dataclass_fields__["resolution"].default
        resolution = _number(default)
    if isinstance(size, list | tuple) and len(size) == 2 and resolution and resolution > 0:
        sx, sy = _number(size[0]), _number(size[1])
        if sx is not None and sy is not None and sx > 0 and sy > 0:
            cells = math.ceil(sx / resolution) * math.ceil(sy / resolution)
            if cells > settings.max_grid_cells:
                raise ApiError(
                    422,
                    f"scenario.terrain.resolution: a {sx:g} m x {sy:g} m site at {resolution:g} m makes "
                    f"{cells} grid cells; this service allows {settings.max_grid_cells} (coarsen the "
                    "resolution or shrink the site)",
                    "scenario.terrain.resolution",
                )
    # vehicles
    groups = data.get("vehicles")
    if isinstance(groups, list):
        total = 0
        for i, g in enumerate(groups):
            count = g.get("count", 1) if isinstance(g, Mapping) else 1
            if isinstance(count, int) and not isinstance(count, bool):
                total += max(count, 0)
            if total > settings.max_agents or i >= settings.max_agents:
                raise ApiError(
                    422,
                    f"scenario.vehicles: more than {settings.max_agents} vehicles; this service's limit is "
                    f"{settings.max_agents}",
                    "scenario.vehicles",
                )


def _check_costs(scenario: Any, settings: Settings) -> None:
    """Checks on a built scenario: vehicles, sonar size, integration steps."""
    agents = scenario.agents
    if len(agents) > settings.max_agents:
        raise ApiError(
            422,
            f"scenario.vehicles: {len(agents)} vehicles; this service's limit is {settings.max_agents}",
            "scenario.vehicles",
        )
    for a in agents:
        if a.sonar.beams > MAX_BEAMS:
            raise ApiError(
                422, f"scenario.sensors.sonar.beams: {a.sonar.beams} beams; valid: <= {MAX_BEAMS}", "scenario"
            )
        if a.sonar.record_samples > MAX_RECORD_SAMPLES:
            raise ApiError(
                422,
                f"scenario.sensors.sonar: a record of {a.sonar.record_samples} samples (2 max_range / c x "
                f"sampling_rate); valid: <= {MAX_RECORD_SAMPLES}",
                "scenario.sensors.sonar",
            )
    sim = scenario.simulation
    if sim.dt / sim.h_max > MAX_SUBSTEPS:
        raise ApiError(
            422,
            f"scenario.simulation.h_max: {sim.h_max:g} s makes {sim.dt / sim.h_max:.0f} integration steps "
            f"per control step; valid: h_max >= dt / {MAX_SUBSTEPS} = {sim.dt / MAX_SUBSTEPS:g} s",
            "scenario.simulation.h_max",
        )


_LIMITS = {
    # resource -> (what, setting, its environment variable, unit)
    "memory": ("memory", "episode_memory_mb", "HPTVSIM_EPISODE_MEMORY_MB", "MiB"),
    "disk": ("disk space", "episode_disk_mb", "HPTVSIM_EPISODE_DISK_MB", "MiB"),
    "cpu": ("CPU time", "episode_cpu_s", "HPTVSIM_EPISODE_CPU_S", "s"),
}


def _amount(value: float, unit: str) -> str:
    if unit == "s":
        return f"{value:.3g} s"
    gib = value / (1 << 30)
    return f"{gib:.3g} GiB" if gib >= 1.0 else f"{value / (1 << 20):.3g} MiB"


def check_episode_costs(
    scenario: Any,
    *,
    max_steps: int,
    record: bool,
    sensor_fidelity: str | None,
    policies: Mapping[str, str],
    settings: Settings,
) -> None:
    """Refuse an episode whose estimated memory, CPU time or disk use exceeds this service's limits.

    The estimate is :func:`hptvsim.service.costs.estimate_costs`; the limits are
    ``episode_memory_mb``, ``episode_cpu_s`` and ``episode_disk_mb``.

    Raises:
        ApiError: 422 naming the field that drives the largest part of the cost (the message
            names the others, the estimate, the limit, and the steps that would fit).
    """
    from hptvsim.service.costs import estimate_costs

    costs = estimate_costs(
        scenario, max_steps=max_steps, record=record, sensor_fidelity=sensor_fidelity, policies=policies
    )
    for resource, (what, setting, env, unit) in _LIMITS.items():
        limit = float(getattr(settings, setting)) * (1.0 if unit == "s" else float(1 << 20))
        total = costs.total(resource)  # type: ignore[arg-type]  # a key of _LIMITS
        if total <= limit:
            continue
        drivers = costs.drivers(resource)  # type: ignore[arg-type]
        field = drivers[0].fields[0]
        parts = "; ".join(f"{t.what}: {_amount(t.amount, unit)} ({', '.join(t.fields)})" for t in drivers)
        fits = costs.steps_within(resource, limit)  # type: ignore[arg-type]
        hint = (
            f"; at most {fits} steps would fit (max_steps)" if fits is not None and fits < max_steps else ""
        )
        raise ApiError(
            422,
            f"{field}: this episode would need about {_amount(total, unit)} of {what}, more than this "
            f"service allows one episode ({getattr(settings, setting):g} {unit}, {env}); most of it: "
            f"{parts}{hint}",
            field,
        )


def check_policies_fit(
    scenario: Any,
    policies: Mapping[str, str],
    req: EpisodeCreate,
    max_steps: int,
    defaulted: Collection[str] = (),
) -> dict[str, str]:
    """Refuse a run whose trained policies do not fit its scenario (another beam count, say).

    Agents in ``defaulted`` were given no policy: where their default does not fit, the game's
    scripted baseline plays instead (:func:`hptvsim.zoo.default_policy_of`), and the returned
    policies say so.

    The check an interactive episode gets when its host opens it (the policies' loaders, through
    :func:`hptvsim.zoo.check_policy_fits`, on the game built from the scenario), made at
    admission: a run would otherwise be accepted and fail in its worker. Only trained policies
    depend on the scenario's layout, so a run of scripted ones builds nothing here; the game is
    built with the batched backend whatever the request's (the observation layout is the same,
    and no FMU is loaded here).

    Raises:
        ApiError: 422 naming ``scenario`` and what does not fit.
    """
    out = dict(policies)
    if not any(not p.startswith("scripted:") for p in policies.values()):
        return out
    from hptvsim.service.engine import client_message
    from hptvsim.zoo import check_policy_fits, default_policy_of

    try:
        if scenario.simulation.game == "3d":
            from hptvsim.envs.game3d import Game3DCore

            core: Any = Game3DCore(scenario, num_envs=1, max_steps=max_steps, seed=0, threads=1)
        else:
            from hptvsim.envs.core import GameCore

            core = GameCore(
                scenario,
                num_envs=1,
                sensor_fidelity=req.sensor_fidelity,
                max_steps=max_steps,
                seed=0,
                threads=1,
            )
        for agent, spec in policies.items():
            if agent in defaulted:
                out[agent] = default_policy_of(core, agent)
            else:
                check_policy_fits(spec, core, agent)
    except ValueError as exc:
        raise ApiError(422, f"scenario: {client_message(exc)}", "scenario") from None
    return out


def resolve_request(req: EpisodeCreate, settings: Settings) -> tuple[Resolved, Any]:
    """Validate a request against the scenario and the settings.

    Returns:
        The resolved job parameters and the scenario object.

    Raises:
        ApiError: The first problem, naming the field (422).
    """
    from hptvsim.world.scenario import Scenario, ScenarioError, scenario_dir

    if isinstance(req.scenario, str):
        scenario = shipped_scenario(req.scenario)
        ref: str | dict[str, Any] = req.scenario
        label = req.scenario
    else:
        screen_inline(req.scenario, settings)
        try:
            scenario = Scenario.from_dict(req.scenario, source="<request>", base_dir=scenario_dir())
        except ScenarioError as exc:
            field = f"scenario.{exc.key}" if exc.key else "scenario"
            raise ApiError(422, f"{field}: {exc.problem}", field) from None
        ref = scenario.to_dict()
        label = f"{scenario.name} (inline)"
    _check_costs(scenario, settings)
    if scenario.simulation.game == "3d":  # what the 3-D game cannot run, at once instead of in a worker
        from hptvsim.envs.game3d import check_agents_3d

        try:
            check_agents_3d(scenario)
        except ValueError as exc:
            raise ApiError(422, f"scenario: {str(exc).split(': ', 1)[-1]}", "scenario") from None
    agents = tuple(a.name for a in scenario.agents)
    roles = {a.name: a.role for a in scenario.agents}
    # step limit
    if req.max_steps is not None and req.max_steps > settings.max_steps:
        raise ApiError(
            422, f"max_steps: {req.max_steps} exceeds this service's limit {settings.max_steps}", "max_steps"
        )
    max_steps = (
        req.max_steps if req.max_steps is not None else min(scenario.simulation.max_steps, settings.max_steps)
    )
    # control
    control = tuple(req.control)
    if req.mode == "run" and control:
        raise ApiError(422, "control: only interactive episodes have client-controlled agents", "control")
    if req.mode == "interactive" and not control:
        raise ApiError(
            422, f"control: name at least one agent to step; agents: {', '.join(agents)}", "control"
        )
    for a in control:
        if a not in agents:
            raise ApiError(422, f"control: unknown agent {a!r}; agents: {', '.join(agents)}", "control")
    if len(set(control)) != len(control):
        raise ApiError(422, "control: an agent is named twice", "control")
    # policies: named ones only (hptvsim.catalog), never a checkpoint path
    from hptvsim.catalog import CatalogError, check_policy
    from hptvsim.zoo import default_policy

    policies: dict[str, str] = {}
    for agent, name in req.policies.items():
        field = f"policies.{agent}"
        if agent not in agents:
            raise ApiError(422, f"{field}: unknown agent {agent!r}; agents: {', '.join(agents)}", field)
        try:
            policies[agent] = check_policy(name, roles[agent], scenario.simulation.game)
        except CatalogError as exc:
            raise ApiError(422, f"{field}: {exc}", field) from None
    defaulted = [a for a in agents if a not in control and a not in policies]
    for agent in defaulted:
        policies[agent] = default_policy(roles[agent], scenario.task.kind, scenario.simulation.game)
    check_episode_costs(
        scenario,
        max_steps=int(max_steps),
        record=bool(req.record),
        sensor_fidelity=req.sensor_fidelity,
        policies=policies,
        settings=settings,
    )
    if not isinstance(req.scenario, str):  # a shipped scenario fits the shipped policies
        policies = check_policies_fit(scenario, policies, req, int(max_steps), defaulted)
    return (
        Resolved(
            scenario_ref=ref,
            scenario_label=label,
            agents=agents,
            roles=roles,
            policies=policies,
            control=control,
            max_steps=int(max_steps),
        ),
        scenario,
    )
