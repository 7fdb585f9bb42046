"""Request and response bodies of the API (pydantic v2; requests forbid unknown keys).

:class:`EpisodeCreate` and :class:`StepIn` are the requests' shapes; :func:`request_models`
narrows them to one service's settings and catalog (the shipped scenario and policy names, the
step and agent limits, the inline scenario's JSON Schema) so that the OpenAPI document states
exactly the limits the server enforces. Requests are validated strictly: a number must be a
JSON number, not a string holding one.
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from datetime import datetime
from typing import TYPE_CHECKING, Annotated, Any, Literal

from pydantic import (
    BaseModel,
    BeforeValidator,
    ConfigDict,
    Field,
    StrictBool,
    StrictFloat,
    StrictStr,
    StringConstraints,
    WithJsonSchema,
    create_model,
)

from hptvsim.catalog import MAX_SEED, NAME_PATTERN, POLICY_NAME_PATTERN

if TYPE_CHECKING:
    from hptvsim.service.settings import Settings

__all__ = [
    "AGENT_PATTERN",
    "MAX_SEED",
    "NAME_PATTERN",
    "POLICY_PATTERN",
    "ActionValue",
    "EpisodeCreate",
    "EpisodeList",
    "EpisodeOut",
    "ErrorBody",
    "FieldError",
    "Health",
    "InteractiveState",
    "PolicyOut",
    "RequestModels",
    "ScenarioOut",
    "StepIn",
    "StepOut",
    "request_models",
]

POLICY_PATTERN = POLICY_NAME_PATTERN
AGENT_PATTERN = r"^(pursuer|evader)_[0-9]{1,2}$"
"""Agent names (``pursuer_0``, ``evader_0``): a role and its number within the role."""
AgentName = Annotated[str, StringConstraints(pattern=AGENT_PATTERN)]


NO_OTHER_KEYS: dict[str, Any] = {"additionalProperties": False}
"""A map keyed by agent name states that keys not matching the name pattern are refused (the
server refuses them; pydantic's ``patternProperties`` alone would allow them in the schema)."""

_RUN: dict[str, Any] = {"mode": {"const": "run"}, "control": {"maxItems": 0}}
"""A run episode: the server drives every agent (``mode`` left out means ``run``)."""


def _interactive(agents: list[str]) -> dict[str, Any]:
    """An interactive episode whose client steps some of ``agents``, at least one."""
    return {"mode": {"const": "interactive"}, "control": {"items": {"enum": agents}, "minItems": 1}}


def _json_number(value: Any) -> Any:
    if isinstance(value, str | bytes | bool):
        raise ValueError("expected a JSON number")  # pydantic's lax mode would read "3" or true
    return value


JsonInt = Annotated[int, BeforeValidator(_json_number)]
"""An integer given as a JSON number (``3``, or ``3.0`` as JSON Schema allows), never a string."""


def json_int(ge: int, le: int) -> Any:
    """:data:`JsonInt` in ``[ge, le]`` (the bounds inside the type, so the schema states them)."""
    return Annotated[int, Field(ge=ge, le=le), BeforeValidator(_json_number)]


class Strict(BaseModel):
    """Request bodies: unknown keys are errors; numbers and booleans must be JSON numbers and booleans."""

    model_config = ConfigDict(extra="forbid")


def shipped_scenario_rules(default: str = "source") -> dict[str, Any]:
    """What each shipped scenario allows in ``policies`` and ``control``, in JSON Schema.

    A run episode names no agent in ``control``, an interactive one at least one; a request
    naming a shipped scenario (or none: ``default``) may name only that scenario's agents, and
    give each a policy that drives its role in its game. These rules hold between fields, so
    they are stated as flat ``anyOf`` branches, one per mode and group of alike scenarios (an
    inline scenario, an object, has its own: its agents are known once it is built, and the
    server names the field of any such problem).

    ``policies`` and ``control`` do not constrain each other: a controlled agent given a
    policy follows it in the steps whose actions leave it out. (Before, that pair was refused,
    a rule of one ``anyOf`` branch per set of controlled agents, 36 in all, past what the
    generator schemathesis draws from can expand: ``jsonschema_rs.canonical`` gives up past
    29; issue 33.)
    Loads the shipped scenarios (cached), so it is called when the OpenAPI document is made.
    """
    from hptvsim.catalog import policies, scenario_names, shipped_scenario

    # scenarios with the same agents and policy choices share their branches (a generator's
    # limit on branches is near 50; the shipped ones make 4 groups)
    groups: dict[str, tuple[list[str], list[str], dict[str, Any]]] = {}
    for name in scenario_names():
        scenario = shipped_scenario(name)
        game = scenario.simulation.game
        allowed: dict[str, Any] = {}
        for a in scenario.agents:
            valid = sorted({n for p in policies(a.role, game) for n in (p.name, *p.aliases)})
            allowed[a.name] = {"enum": valid}
        key = json.dumps(allowed, sort_keys=True)
        groups.setdefault(key, ([], [a.name for a in scenario.agents], allowed))[0].append(name)
    branches: list[dict[str, Any]] = [
        {
            "title": "inline; run",
            "properties": {"scenario": {"type": "object"}, **_RUN},
            "required": ["scenario"],
        },
        {
            "title": "inline; interactive",
            "properties": {
                "scenario": {"type": "object"},
                "mode": {"const": "interactive"},
                "control": {"minItems": 1},
            },
            "required": ["scenario", "mode", "control"],
        },
    ]
    for members, names, allowed in groups.values():
        policies_rule = {"properties": allowed, "additionalProperties": False}
        need = ["scenario"] if default not in members else []  # no scenario: the default
        branches.append(
            {
                "title": f"{', '.join(members)}; run",
                "properties": {"scenario": {"enum": members}, "policies": policies_rule, **_RUN},
                "required": need,
            }
        )
        branches.append(
            {
                "title": f"{', '.join(members)}; interactive",
                "properties": {
                    "scenario": {"enum": members},
                    "policies": policies_rule,
                    **_interactive(names),
                },
                "required": [*need, "mode", "control"],
            }
        )
    return {"anyOf": branches}


def _episode_create_schema(schema: dict[str, Any]) -> None:
    schema.update(shipped_scenario_rules())


_NULL_DEFAULT: dict[str, Any] = {"default": None}
"""A field whose default, null, stands for the scenario's own value, stated in the document."""


class EpisodeCreate(Strict):
    """A new episode: every field has a default, so ``{}`` runs the scenario ``source``.

    The OpenAPI document states each default (``scenario``: ``source``, ``mode``: ``run``,
    ``policies``: ``{}``, the roles' default policies, ``seed``, ``max_steps`` and
    ``sensor_fidelity``: null, the scenario's own).
    """

    model_config = ConfigDict(extra="forbid", json_schema_extra=_episode_create_schema)

    scenario: str | dict[str, Any] = Field(
        "source",
        description="a shipped scenario's name (GET /api/v1/scenarios) or a scenario as data (the "
        "tables of a scenario file; see `hptvsim scenario schema`); file terrain may only name the "
        "shipped data files; default: source",
        examples=["source"],
    )
    mode: Literal["run", "interactive"] = Field(
        "run",
        description="run: the server drives every agent to the end; interactive: the client steps "
        "the agents in `control`, the server drives the others",
    )
    policies: dict[AgentName, str] = Field(
        default_factory=dict,
        description="policy name per agent (GET /api/v1/policies); for an agent in `control`, the "
        "policy that acts for it in the steps whose actions leave it out (without one, every step "
        "must give its action); agents neither named nor controlled follow their role's default: "
        "the shipped trained policy (GET /api/v1/policies, default_for), else pure_pursuit for "
        "pursuers and potential_field for evaders",
        max_length=64,
        json_schema_extra={**NO_OTHER_KEYS, "default": {}},
    )
    control: list[AgentName] = Field(
        default_factory=list,
        description="interactive mode: the agents the client steps; one also given a policy "
        "(policies.<agent>) follows it in the steps whose actions leave it out",
        max_length=64,
        json_schema_extra={"uniqueItems": True, "default": []},
    )
    seed: json_int(0, MAX_SEED) | None = Field(  # type: ignore[valid-type]  # an Annotated type
        None,
        description="seed of spawn poses, sensor noise and random policies (default: the scenario's)",
        json_schema_extra=_NULL_DEFAULT,
    )
    max_steps: json_int(1, 10_000_000) | None = Field(  # type: ignore[valid-type]  # an Annotated type
        None,
        description="step limit (default: the scenario's; bounded by the service)",
        json_schema_extra=_NULL_DEFAULT,
    )
    sensor_fidelity: Literal["geometric", "signal"] | None = Field(
        None, description="sonar model (default: the scenario's)", json_schema_extra=_NULL_DEFAULT
    )
    backend: Literal["batched", "fmu"] = Field(
        "batched", description="batched: the compiled dynamics; fmu: one FMI 2.0 FMU instance per vehicle"
    )
    record: StrictBool = Field(True, description="write a rerun recording (.rrd)")
    label: StrictStr = Field("", max_length=200, description="free text shown in the episode list")


class FieldError(BaseModel):
    """One problem with a request."""

    field: str = Field(description="dotted path of the offending field, e.g. max_steps or scenario.site.size")
    message: str
    type: str = "value_error"


class ErrorBody(BaseModel):
    """Every error response."""

    status: int
    detail: str = Field(description="one line naming the field and what would be valid")
    errors: list[FieldError] = Field(default_factory=list)


class EpisodeOut(BaseModel):
    """An episode as stored."""

    id: str
    mode: str
    status: Literal["queued", "running", "finished", "failed", "cancelled", "interrupted"]
    label: str
    scenario: str
    seed: int
    max_steps: int
    backend: str
    sensor_fidelity: str | None
    agents: list[str]
    policies: dict[str, str]
    control: list[str]
    steps: int
    summary: dict[str, Any] | None = Field(
        description="how it ended (the frame schema's EpisodeSummary: status, outcome, steps, sim_time, "
        "wall_time, metrics)"
    )
    error: str | None
    versions: dict[str, str]
    has_recording: bool
    has_trajectory: bool
    created_at: datetime
    started_at: datetime | None
    finished_at: datetime | None
    updated_at: datetime | None = Field(None, description="when the row last changed")
    links: dict[str, str] = Field(default_factory=dict)


class EpisodeList(BaseModel):
    """A page of episodes, newest first."""

    total: int
    limit: int
    offset: int
    items: list[EpisodeOut]


class ScenarioOut(BaseModel):
    """A shipped scenario."""

    name: str
    description: str
    task: str
    site_size: tuple[float, float]
    agents: list[str]
    roles: dict[str, str]
    colors: dict[str, str] = Field(
        description="each agent's display colour `#rrggbb` (hptvsim.palette: the same in every view)"
    )
    game: Literal["planar", "3d"] = Field(
        "planar", description="the game episodes play: planar (the paper's) or 3d (vehicles that dive)"
    )
    default_policies: dict[str, str] = Field(
        description="the policy each role follows when a request names none (hptvsim.zoo.default_policy)"
    )
    max_steps: int
    dt: float


class PolicyOut(BaseModel):
    """A named policy."""

    name: str
    kind: str
    roles: list[str]
    games: list[str] = Field(description="games it plays: planar, 3d")
    description: str


ActionValue = tuple[StrictFloat, StrictFloat] | tuple[StrictFloat, StrictFloat, StrictFloat]


class StepIn(Strict):
    """Actions of the controlled agents for one step."""

    actions: dict[AgentName, ActionValue] = Field(
        default_factory=dict,
        description="[v, omega] per controlled agent (m/s, rad/s; clipped to the vehicle's limits); "
        "in the 3-D game [v, omega, w_z] (w_z: vertical speed, m/s, positive down); "
        "an agent left out follows its policy if the episode gave it one (policies.<agent>); "
        "every other active controlled agent must act",
        max_length=64,
        json_schema_extra=NO_OTHER_KEYS,
    )


class StepOut(BaseModel):
    """What one interactive step produced for the controlled agents."""

    step: int
    t: float
    observations: dict[str, list[float]]
    rewards: dict[str, float]
    terminated: dict[str, bool]
    truncated: dict[str, bool]
    infos: dict[str, dict[str, Any]]
    done: bool


class InteractiveState(BaseModel):
    """An interactive episode's agents, spaces and current observations."""

    id: str
    agents: list[str]
    control: list[str]
    step: int
    done: bool
    observations: dict[str, list[float]]
    spaces: dict[str, Any]


class Health(BaseModel):
    """Liveness, load, disk, and whether the database and the data folder take writes."""

    status: Literal["ok", "degraded"] = Field(
        description="``degraded`` (answered with HTTP 503) when a check failed; ``problems`` says which"
    )
    version: str
    executor: str
    workers: int
    busy: int
    queued: int
    interactive: int
    database: str
    problems: list[str] = Field(
        default_factory=list,
        description="what failed, one line each: the database's write check, the data folder's, "
        "episode ends the database has not stored yet",
    )
    disk_used_mb: float = Field(
        0.0, description="disk the stored episodes use [MiB] (running ones: their estimate)"
    )
    disk_quota_mb: float = Field(
        0.0, description="most disk the stored episodes may use [MiB]; beyond it new episodes get 507"
    )
    retention_days: float = Field(0.0, description="ended episodes older than this are deleted [days]")


@dataclass(frozen=True)
class RequestModels:
    """One service's request models (see :func:`request_models`).

    Attributes:
        episode_create: :class:`EpisodeCreate` with the service's names and limits.
        step_in: :class:`StepIn` with the service's agent limit.
        scenario_name: The type of a shipped scenario's name (an enum in OpenAPI).
        scenarios: The shipped scenarios' names.
    """

    episode_create: type[EpisodeCreate]
    step_in: type[StepIn]
    scenario_name: Any
    scenarios: tuple[str, ...]


def request_models(settings: Settings) -> RequestModels:
    """:class:`EpisodeCreate` and :class:`StepIn` narrowed to ``settings`` and the catalog.

    The shipped scenario names and the policy names become enums, ``max_steps`` and the
    number of agents get the service's limits, and an inline scenario is described by the one
    scenario schema (:func:`hptvsim.world.scenario.scenario_json_schema`), so a request that
    the OpenAPI document allows is one the server takes, except for rules between fields that
    JSON Schema cannot state (an agent the scenario does not have, a policy for another role,
    a spawn region outside the site), which are answered 422 naming the field.
    """
    from hptvsim.catalog import policies, scenario_names
    from hptvsim.world.scenario import scenario_json_schema

    names = tuple(scenario_names())
    scenario_name: Any = Literal[names]  # built from the catalog
    accepted = sorted({n for p in policies() for n in (p.name, *p.aliases)})
    # the document lists every name (each shipped scenario's branch of the body's anyOf, the
    # names of its agents' roles and game); the server checks a name against the scenario's
    # game and the agent's role (validation.resolve_request), so a refusal lists the names
    # that fit, as the command line's does, never the other game's
    policy_name: Any = Annotated[
        str,
        StringConstraints(max_length=200),  # bounded; any other name is refused by the catalog
        WithJsonSchema({"type": "string", "enum": accepted}),
    ]
    inline = Annotated[dict[str, Any], WithJsonSchema(scenario_json_schema(standalone=False))]
    fields = EpisodeCreate.model_fields
    episode_create = create_model(
        "EpisodeCreate",
        __base__=EpisodeCreate,
        scenario=(
            scenario_name | inline,
            Field(
                fields["scenario"].default,
                description=fields["scenario"].description,
                examples=[fields["scenario"].default],
            ),
        ),
        policies=(
            dict[AgentName, policy_name],
            Field(
                default_factory=dict,
                description=fields["policies"].description,
                max_length=settings.max_agents,
                json_schema_extra={**NO_OTHER_KEYS, "default": {}},
            ),
        ),
        control=(
            list[AgentName],
            Field(
                default_factory=list,
                description=fields["control"].description,
                max_length=settings.max_agents,
                json_schema_extra={"uniqueItems": True, "default": []},
            ),
        ),
        max_steps=(
            json_int(1, settings.max_steps) | None,
            Field(
                None,
                description="step limit (default: the scenario's, at most this service's limit)",
                json_schema_extra=_NULL_DEFAULT,
            ),
        ),
    )
    step_in = create_model(
        "StepIn",
        __base__=StepIn,
        actions=(
            dict[AgentName, ActionValue],
            Field(
                default_factory=dict,
                description=StepIn.model_fields["actions"].description,
                max_length=settings.max_agents,
                json_schema_extra=NO_OTHER_KEYS,
            ),
        ),
    )
    return RequestModels(episode_create, step_in, scenario_name, names)
