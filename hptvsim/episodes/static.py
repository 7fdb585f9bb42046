"""The static part of an episode's frames, from the game protocol (:class:`~hptvsim.envs.protocol.Scene`).

Whatever the game, :func:`build_static` reads the same members: the scenario (site, seabed,
vehicle types), the game's agents and roles, its :meth:`~hptvsim.envs.protocol.Game.scene`
(radii, command limits, sonar beams, obstacles, goals) and its command fields. The frame flavour
(``planar`` or ``3d``, see :mod:`hptvsim.episodes.frames`) is the scene's
:attr:`~hptvsim.envs.protocol.Scene.vertical`.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Literal

import numpy as np

from hptvsim.envs.protocol import Game, Scene
from hptvsim.episodes.frames import (
    AgentInfo,
    EpisodeStatic,
    FrameOptions,
    Point,
    SiteInfo,
    agent_color,
    obstacle_summary,
    terrain_mesh,
)
from hptvsim.zoo import default_policy_of

__all__ = ["build_static", "default_policy", "flavour", "policy_specs"]


def flavour(scene: Scene) -> Literal["planar", "3d"]:
    """The frame flavour of a game's episodes: ``3d`` where the vehicles move in depth."""
    return "3d" if scene.vertical else "planar"


def default_policy(game: Game, agent: str) -> str:
    """The zoo spec an agent follows when none is given (:func:`hptvsim.zoo.default_policy_of`)."""
    return default_policy_of(game, agent)


def policy_specs(game: Game, policies: Mapping[str, str] | None) -> dict[str, str]:
    """Every agent's zoo spec: the given ones, the defaults for the rest.

    Raises:
        ValueError: Policies given for unknown agents, or a spec that is not a non-empty string.
    """
    given = dict(policies or {})
    unknown = sorted(set(given) - set(game.agents))
    if unknown:
        raise ValueError(f"policies given for unknown agent(s) {unknown}; agents: {', '.join(game.agents)}")
    for agent, spec in given.items():
        if not isinstance(spec, str) or not spec:
            raise ValueError(f"the policy of {agent} must be a zoo spec (a non-empty string); got {spec!r}")
    return {a: given.get(a, default_policy(game, a)) for a in game.agents}


def build_static(
    game: Game,
    policies: Mapping[str, str],
    *,
    options: FrameOptions | None = None,
    seed: int | None = None,
    scene: Scene | None = None,
) -> EpisodeStatic:
    """The static part of the frames of an episode of ``game``'s first environment.

    Args:
        game: The game.
        policies: ``{agent: zoo spec}`` of every agent.
        options: What the frames carry.
        seed: The episode's seed (default: the game's).
        scene: ``game.scene(0)`` if already at hand.
    """
    opts = options if options is not None else FrameOptions()
    sc = game.scenario
    scene = scene if scene is not None else game.scene(0)
    vertical = scene.vertical
    fields = game.command_fields
    v, omega = fields.index("v"), fields.index("omega")
    w_z = fields.index("w_z") if "w_z" in fields else None
    hm = sc.heightmap  # the seabed the game plays over (its scenario's)
    grid = scene.obstacles
    counters: dict[str, int] = {}
    agents: list[AgentInfo] = []
    vehicle_types = {a.name: a.vehicle_type for a in sc.agents}
    for i, name in enumerate(game.agents):
        role: Literal["pursuer", "evader"] = "pursuer" if game.pursuer[i] else "evader"
        k = counters.get(role, 0)
        counters[role] = k + 1
        goal: Point | None = None
        goal_radius = None
        if game.goto and scene.goals is not None and scene.goal_radius is not None:
            g = [float(c) for c in scene.goals[i]]
            goal = (g[0], g[1], g[2]) if vertical else (g[0], g[1])
            goal_radius = float(scene.goal_radius[i])
        agents.append(
            AgentInfo(
                name=name,
                role=role,
                # the scenario's vehicles; a game's own agents are named by the game's kind
                vehicle_type=vehicle_types.get(name, game.kind),
                policy=policies[name],
                color=agent_color(role, k),
                radius=float(scene.radii[i]),
                v_min=float(scene.command_low[i, v]),
                v_max=float(scene.command_high[i, v]),
                omega_max=float(scene.command_high[i, omega]),
                beam_angles=tuple(float(a) for a in scene.beam_azimuth),
                max_range=float(scene.max_range),
                goal=goal,
                goal_radius=goal_radius,
                w_z_max=float(scene.command_high[i, w_z]) if w_z is not None else None,
                beam_elevations=(
                    tuple(float(e) for e in scene.beam_elevation)
                    if scene.beam_elevation is not None
                    else None
                ),
            )
        )
    return EpisodeStatic(
        scenario=sc.name,
        description=sc.description,
        task="goto" if game.goto else "pursuit",
        seed=int(game.seed if seed is None else seed),
        dt=float(game.dt),
        max_steps=int(game.max_steps),
        backend=game.backend,
        sensor_fidelity=sc.sensors.sonar.fidelity,
        capture_distance=float(sc.task.target_distance),
        safe_distance=float(sc.task.safe_distance),
        site=SiteInfo(
            size=(float(sc.site.size[0]), float(sc.site.size[1])),
            origin=(float(sc.site.origin[0]), float(sc.site.origin[1])),
            operating_depth=float(sc.site.operating_depth),
        ),
        terrain=terrain_mesh(hm.depth, hm.geometry.extent, max_cells=opts.terrain_cells),
        obstacles=obstacle_summary(
            np.asarray(grid.occupied),
            resolution=grid.geometry.resolution,
            extent=grid.geometry.extent,
            fence=scene.fence,
            max_cells=opts.obstacle_cells,
        ),
        agents=tuple(agents),
        options=opts,
        game=flavour(scene),
    )
