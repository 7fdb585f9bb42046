"""Request and response bodies of the API (pydantic v2; requests forbid unknown keys).

Bounds that depend on the service's settings (the step limit, the number of agents) are
checked by the handlers and answered with the same structured 422 as schema violations.
"""

from __future__ import annotations

from datetime import datetime
from typing import Any, Literal

from pydantic import BaseModel, ConfigDict, Field

__all__ = [
    "ActionValue",
    "EpisodeCreate",
    "EpisodeList",
    "EpisodeOut",
    "ErrorBody",
    "FieldError",
    "Health",
    "InteractiveState",
    "PolicyOut",
    "ScenarioOut",
    "StepIn",
    "StepOut",
]

NAME_PATTERN = r"^[A-Za-z0-9_\-]{1,64}$"
POLICY_PATTERN = r"^[A-Za-z0-9_\-:\.]{1,100}$"
MAX_SEED = 2**31 - 1


class Strict(BaseModel):
    """Request bodies: unknown keys are errors."""

    model_config = ConfigDict(extra="forbid")


class EpisodeCreate(Strict):
    """A new episode."""

    scenario: str | dict[str, Any] = Field(
        "source",
        description="a shipped scenario's name (GET /api/v1/scenarios) or a scenario as data (the "
        "tables of a scenario file; see `hptvsim scenario schema`); file terrain may only name the "
        "shipped data files",
        examples=["source"],
    )
    mode: Literal["run", "interactive"] = Field(
        "run",
        description="run: the server drives every agent to the end; interactive: the client steps "
        "the agents in `control`, the server drives the others",
    )
    policies: dict[str, str] = Field(
        default_factory=dict,
        description="policy name per agent (GET /api/v1/policies); agents not named follow their "
        "role's default: the shipped trained policy (GET /api/v1/policies, default_for), else "
        "pure_pursuit for pursuers and potential_field for evaders",
        max_length=64,
    )
    control: list[str] = Field(
        default_factory=list,
        description="interactive mode: the agents the client steps",
        max_length=64,
    )
    seed: int | None = Field(
        None,
        ge=0,
        le=MAX_SEED,
        description="seed of spawn poses, sensor noise and random policies (default: the scenario's)",
    )
    max_steps: int | None = Field(
        None, ge=1, le=10_000_000, description="step limit (default: the scenario's; bounded by the service)"
    )
    sensor_fidelity: Literal["geometric", "signal"] | None = Field(
        None, description="sonar model (default: the scenario's)"
    )
    backend: Literal["batched", "fmu"] = Field(
        "batched", description="batched: the compiled dynamics; fmu: one FMI 2.0 FMU instance per vehicle"
    )
    record: bool = Field(True, description="write a rerun recording (.rrd)")
    label: str = Field("", max_length=200, description="free text shown in the episode list")


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
    max_steps: int
    dt: float


class PolicyOut(BaseModel):
    """A named policy."""

    name: str
    kind: str
    roles: list[str]
    description: str


ActionValue = tuple[float, float]


class StepIn(Strict):
    """Actions of the controlled agents for one step."""

    actions: dict[str, ActionValue] = Field(
        default_factory=dict,
        description="[v, omega] per controlled agent (m/s, rad/s; clipped to the vehicle's limits); "
        "agents left out keep still",
        max_length=64,
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
    """Liveness and load."""

    status: Literal["ok"]
    version: str
    executor: str
    workers: int
    busy: int
    queued: int
    interactive: int
    database: str
