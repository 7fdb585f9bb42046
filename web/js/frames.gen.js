// Generated from hptvsim/episodes/frames.py by `hptvsim viz schema`; do not edit.
// A test (tests/viz/test_viz_frames.py) fails when this file is out of date.

/**
 * What does not change during an episode; sent once, before its frames.
 * @typedef {Object} EpisodeStatic
 * @property {string} [schema] Schema version (`SCHEMA_VERSION`).
 * @property {string} scenario Scenario name.
 * @property {string} description Scenario description.
 * @property {("pursuit" | "goto")} task `pursuit` or `goto`.
 * @property {number} seed Seed of spawn poses, sensor noise and stochastic policies.
 * @property {number} dt Control step [s].
 * @property {number} max_steps Step limit of the episode.
 * @property {string} backend Simulation backend (`batched` or `fmu`).
 * @property {string} sensor_fidelity Sonar fidelity (`geometric` or `signal`).
 * @property {number} capture_distance Pursuit: a pursuer this close to an evader captures it [m].
 * @property {number} safe_distance Sonar returns closer than this are penalised (Eq. 17) [m].
 * @property {SiteInfo} site The site.
 * @property {TerrainMesh} terrain The seabed mesh.
 * @property {ObstacleSummary} obstacles The obstacle map summary.
 * @property {Array<AgentInfo>} agents The agents, in the order of every frame's `agents`.
 * @property {FrameOptions} options What the frames carry.
 * @property {("planar" | "3d")} [game] `planar` or `3d` (see the module docstring).
 */

/**
 * The site.
 * @typedef {Object} SiteInfo
 * @property {[number, number]} size `(L_x, L_y)` extent north x east [m].
 * @property {[number, number]} origin South-west corner `(x, y)` [m].
 * @property {number} operating_depth Depth of the plane the vehicles move in [m], positive down.
 */

/**
 * The seabed as a triangle mesh on a regular vertex grid (decimated from the height map).
 * @typedef {Object} TerrainMesh
 * @property {[number, number]} shape `(mx, my)` vertices along north and east; vertex `(i, j)` has index `i * my + j`.
 * @property {Array<[number, number, number]>} vertices `(x, y, z)` per vertex [m], NED: `z` is the seabed depth (positive down).
 * @property {Array<[number, number, number]>} triangles Vertex indices of each triangle (two per grid cell).
 * @property {[number, number]} depth_range Smallest and largest depth [m].
 */

/**
 * The obstacle map at the operating depth, coarsened for drawing.
 * @typedef {Object} ObstacleSummary
 * @property {number} resolution Cell size of the simulation's obstacle map [m].
 * @property {[number, number]} shape `(nx, ny)` cells of the simulation's obstacle map.
 * @property {number} occupied_fraction Fraction of its cells that are solid.
 * @property {boolean} fence Whether the site's edge is a wall the sonar sees (not drawn in `rows`).
 * @property {[number, number, number, number]} extent `(x_min, x_max, y_min, y_max)` [m] that `rows` cover.
 * @property {number} coarse_resolution Cell size of `rows` [m].
 * @property {Array<string>} rows One string per coarse row, south (small `x`) first; character `j` (east) is `#` where any fine cell in the coarse cell is solid, else `.`.
 */

/**
 * One agent.
 * @typedef {Object} AgentInfo
 * @property {string} name Agent name (`pursuer_0`, `evader_0`, ...).
 * @property {("pursuer" | "evader")} role `pursuer` or `evader`.
 * @property {string} vehicle_type `work_class`, `spherical`, or the name of a vehicle file's type.
 * @property {string} policy The policy that drives it (a zoo spec, or `external` when actions come from outside).
 * @property {string} color Display colour `#rrggbb` (the same in every view).
 * @property {number} radius Collision radius [m].
 * @property {number} v_min Smallest commanded surge speed [m/s] (Eq. 15).
 * @property {number} v_max Largest commanded surge speed [m/s] (Eq. 15).
 * @property {number} omega_max Largest commanded yaw rate [rad/s] (Eq. 15).
 * @property {Array<number>} beam_angles Sonar beam angles relative to the bow [rad], clockwise positive (3-D game: each beam's azimuth).
 * @property {number} max_range Sonar maximum range [m].
 * @property {([number, number] | [number, number, number] | null)} [goal] Goto task: the goal point `(x, y)` [m] (3-D game: `(x, y, z)`), else None.
 * @property {(number | null)} [goal_radius] Goto task: distance within which the goal counts as reached [m], else None.
 * @property {(number | null)} [w_z_max] 3-D game: largest commanded vertical speed [m/s], else None.
 * @property {(Array<number> | null)} [beam_elevations] 3-D game: each beam's elevation [rad], positive down, else None.
 */

/**
 * What frames carry beyond poses and scalars.
 * @typedef {Object} FrameOptions
 * @property {number} [sonar_every] Steps between frames that carry sonar ranges and hit points (1: every frame; 0: none). Other frames carry `None` there (the minimum range always).
 * @property {boolean} [hits] Whether sonar frames carry hit points (beams that returned an echo) besides ranges.
 * @property {boolean} [obs] Whether frames carry each agent's observation vector (Eq. 14; for remote stepping).
 * @property {number} [terrain_cells] Most terrain mesh cells along the site's longer side.
 * @property {number} [obstacle_cells] Most cells along the longer side of the obstacle map summary.
 */

/**
 * The state of an episode after one control step (step 0: after reset).
 * @typedef {Object} Frame
 * @property {number} step Steps taken.
 * @property {number} time Simulated time [s] (`step * dt`).
 * @property {Array<AgentState>} agents Every agent, in `EpisodeStatic.agents` order.
 * @property {boolean} [captured] Pursuit: a pursuer is within the capture distance of an evader.
 * @property {boolean} [truncated] The step limit was reached.
 * @property {boolean} [done] The episode is over after this step.
 * @property {("captured" | "collision" | "out_of_site" | "reached" | "truncated" | "cancelled" | "running")} [outcome] Why it ended (`running` until it does).
 */

/**
 * One agent after a step.
 * @typedef {Object} AgentState
 * @property {string} name Agent name.
 * @property {number} x North position [m].
 * @property {number} y East position [m].
 * @property {number} psi Yaw [rad], clockwise from north, in `[-pi, pi)`.
 * @property {number} u Surge speed [m/s].
 * @property {number} v Sway speed [m/s].
 * @property {number} r Yaw rate [rad/s].
 * @property {([number, number] | [number, number, number])} action The command applied during the step `[v, omega]` [m/s, rad/s] (Eq. 16, clipped to Eq. 15's box; zero once the agent is done and in the reset frame); 3-D game: `[v, omega, w_z]` [m/s, rad/s, m/s], `w_z` the vertical speed (positive down).
 * @property {number} reward Reward of the step (Eq. 20: `delta_C r_C + delta_E1 r_E1 + delta_E2 r_E2`).
 * @property {number} episode_return Sum of rewards so far.
 * @property {number} distance Distance to the target [m] (pursuer: the evader; evader: the nearest pursuer; goto: the goal).
 * @property {number} min_range Smallest sonar range [m].
 * @property {number} [r_C] The step's obstacle term (Eq. 17), before its weight `delta_C`.
 * @property {number} [r_E1] The step's approach term (Eq. 18), before its weight `delta_E1`.
 * @property {number} [r_E2] The step's capture term (Eq. 19), before its weight `delta_E2`.
 * @property {(Array<number> | null)} [ranges] Sonar ranges per beam [m] (None in frames without sonar, see `FrameOptions`).
 * @property {(Array<([number, number] | [number, number, number])> | null)} [hits] Points `(x, y)` [m] where beams returned an echo (3-D game: `(x, y, z)`; None without sonar or hits).
 * @property {(Array<number> | null)} [obs] The observation vector (Eq. 14; None unless `FrameOptions.obs`).
 * @property {boolean} [active] Whether the agent is still in the episode after this step.
 * @property {boolean} [terminated] The agent's episode ended by a task rule at this step.
 * @property {boolean} [truncated] The agent's episode hit the step limit at this step.
 * @property {boolean} [collision] The agent touches terrain or another vehicle.
 * @property {(string | null)} [collided_with] What it touches when `collision` (the game's `hptvsim.envs.protocol.Game.collided_with`: `seabed`, `surface`, `obstacle`, `site edge` or other agents' names, joined by `", "`), else None.
 * @property {boolean} [out_of_site] The agent's centre left the site.
 * @property {boolean} [reached] Goto: the agent is within its goal's radius.
 * @property {(number | null)} [z] 3-D game: depth [m], positive down, else None (the site's operating depth).
 * @property {(number | null)} [phi] 3-D game: roll [rad], else None.
 * @property {(number | null)} [theta] 3-D game: pitch [rad], positive nose up, else None.
 * @property {(number | null)} [w] 3-D game: heave speed in the body frame [m/s], else None.
 * @property {(number | null)} [altitude] 3-D game: height above the seabed [m], else None.
 */

/**
 * How an episode ended.
 * @typedef {Object} EpisodeSummary
 * @property {("finished" | "cancelled")} status `finished` (ended by a task rule or the step limit) or `cancelled`.
 * @property {("captured" | "collision" | "out_of_site" | "reached" | "truncated" | "cancelled" | "running")} outcome Why it ended.
 * @property {number} steps Steps taken.
 * @property {number} sim_time Simulated time [s].
 * @property {number} wall_time Wall-clock time the episode took [s].
 * @property {EpisodeMetrics} metrics The evaluation metrics of the episode.
 * @property {(string | null)} [recording] Path of its rerun recording, or None.
 * @property {Array<CollisionEvent>} [collisions] Each agent's first collision, in the order they happened.
 */

/**
 * What one evaluation episode measured.
 * @typedef {Object} EpisodeMetrics
 * @property {number} seed
 * @property {number} length
 * @property {boolean} captured
 * @property {(number | null)} time_to_capture_steps
 * @property {(number | null)} time_to_capture_s
 * @property {boolean} collision
 * @property {(number | null)} min_distance
 * @property {(number | null)} final_distance
 * @property {(number | null)} success_rate
 * @property {Object<string, number>} returns
 * @property {Object<string, string>} collided_with
 */

/**
 * An agent's first collision in an episode: who, with what, when and where.
 * @typedef {Object} CollisionEvent
 * @property {string} agent The agent that collided.
 * @property {string} collided_with What it touched (as `AgentState.collided_with`).
 * @property {number} step The step at whose end it touched [steps].
 * @property {number} time Simulated time then [s].
 * @property {number} x North position of its centre [m].
 * @property {number} y East position of its centre [m].
 * @property {(number | null)} [z] Depth of its centre [m], positive down (3-D game; None in the planar game).
 */

/**
 * Every agent's trajectory as columns.
 * @typedef {Object} Trajectories
 * @property {Array<number>} step Step of each row (0: after reset).
 * @property {Array<number>} time Simulated time of each row [s].
 * @property {Array<AgentTrajectory>} agents One trajectory per agent, in `EpisodeStatic.agents` order.
 */

/**
 * One agent's values at every recorded step (same length as :attr:`Trajectories.step`).
 * @typedef {Object} AgentTrajectory
 * @property {string} name Agent name.
 * @property {Array<number>} x North position [m].
 * @property {Array<number>} y East position [m].
 * @property {Array<number>} psi Yaw [rad].
 * @property {Array<number>} u Surge speed [m/s].
 * @property {Array<number>} v Sway speed [m/s].
 * @property {Array<number>} r Yaw rate [rad/s].
 * @property {Array<number>} v_cmd Commanded surge speed [m/s].
 * @property {Array<number>} omega_cmd Commanded yaw rate [rad/s].
 * @property {Array<number>} reward Reward of the step (Eq. 20).
 * @property {Array<number>} distance Distance to the target [m].
 * @property {Array<number>} min_range Smallest sonar range [m].
 * @property {(Array<number> | null)} [r_C] Obstacle term of each step (Eq. 17, unweighted; None in trajectories stored before the terms were).
 * @property {(Array<number> | null)} [r_E1] Approach term of each step (Eq. 18, unweighted; None likewise).
 * @property {(Array<number> | null)} [r_E2] Capture term of each step (Eq. 19, unweighted; None likewise).
 * @property {(Array<number> | null)} [z] 3-D game: depth [m], positive down (None in the planar game).
 * @property {(Array<number> | null)} [phi] 3-D game: roll [rad] (None in the planar game).
 * @property {(Array<number> | null)} [theta] 3-D game: pitch [rad] (None in the planar game).
 * @property {(Array<number> | null)} [w] 3-D game: heave speed [m/s] (None in the planar game).
 * @property {(Array<number> | null)} [w_cmd] 3-D game: commanded vertical speed [m/s], positive down (None in the planar game).
 * @property {(Array<number> | null)} [altitude] 3-D game: height above the seabed [m] (None in the planar game).
 * @property {(Array<Array<number>> | null)} [ranges] Sonar ranges per beam [m] of each step; an empty tuple at steps whose frame carried no sonar (`FrameOptions.sonar_every`); None when not stored at all.
 */

export const SCHEMA_VERSION = "hptvsim-frames/2";

export const FRAME_SCHEMA = {
  "$schema": "https://json-schema.org/draft/2020-12/schema",
  "$id": "https://hptvsim.dev/schema/frames.schema.json",
  "title": "hptvsim frames",
  "description": "hptvsim-frames/2: the episode frame schema shared by recordings, the API, viser and the dashboard. Generated from hptvsim/episodes/frames.py by `hptvsim viz schema`; do not edit.",
  "version": "hptvsim-frames/2",
  "anyOf": [
    {
      "$ref": "#/$defs/EpisodeStatic"
    },
    {
      "$ref": "#/$defs/Frame"
    },
    {
      "$ref": "#/$defs/EpisodeSummary"
    },
    {
      "$ref": "#/$defs/Trajectories"
    }
  ],
  "$defs": {
    "EpisodeStatic": {
      "type": "object",
      "description": "What does not change during an episode; sent once, before its frames.",
      "properties": {
        "schema": {
          "description": "Schema version (`SCHEMA_VERSION`).",
          "type": "string",
          "default": "hptvsim-frames/2"
        },
        "scenario": {
          "description": "Scenario name.",
          "type": "string"
        },
        "description": {
          "description": "Scenario description.",
          "type": "string"
        },
        "task": {
          "description": "`pursuit` or `goto`.",
          "enum": [
            "pursuit",
            "goto"
          ]
        },
        "seed": {
          "description": "Seed of spawn poses, sensor noise and stochastic policies.",
          "type": "integer"
        },
        "dt": {
          "description": "Control step [s].",
          "type": "number"
        },
        "max_steps": {
          "description": "Step limit of the episode.",
          "type": "integer"
        },
        "backend": {
          "description": "Simulation backend (`batched` or `fmu`).",
          "type": "string"
        },
        "sensor_fidelity": {
          "description": "Sonar fidelity (`geometric` or `signal`).",
          "type": "string"
        },
        "capture_distance": {
          "description": "Pursuit: a pursuer this close to an evader captures it [m].",
          "type": "number"
        },
        "safe_distance": {
          "description": "Sonar returns closer than this are penalised (Eq. 17) [m].",
          "type": "number"
        },
        "site": {
          "description": "The site.",
          "$ref": "#/$defs/SiteInfo"
        },
        "terrain": {
          "description": "The seabed mesh.",
          "$ref": "#/$defs/TerrainMesh"
        },
        "obstacles": {
          "description": "The obstacle map summary.",
          "$ref": "#/$defs/ObstacleSummary"
        },
        "agents": {
          "description": "The agents, in the order of every frame's `agents`.",
          "type": "array",
          "items": {
            "$ref": "#/$defs/AgentInfo"
          }
        },
        "options": {
          "description": "What the frames carry.",
          "$ref": "#/$defs/FrameOptions"
        },
        "game": {
          "description": "`planar` or `3d` (see the module docstring).",
          "enum": [
            "planar",
            "3d"
          ],
          "default": "planar"
        }
      },
      "required": [
        "scenario",
        "description",
        "task",
        "seed",
        "dt",
        "max_steps",
        "backend",
        "sensor_fidelity",
        "capture_distance",
        "safe_distance",
        "site",
        "terrain",
        "obstacles",
        "agents",
        "options"
      ],
      "additionalProperties": false
    },
    "SiteInfo": {
      "type": "object",
      "description": "The site.",
      "properties": {
        "size": {
          "description": "`(L_x, L_y)` extent north x east [m].",
          "type": "array",
          "prefixItems": [
            {
              "type": "number"
            },
            {
              "type": "number"
            }
          ],
          "minItems": 2,
          "maxItems": 2
        },
        "origin": {
          "description": "South-west corner `(x, y)` [m].",
          "type": "array",
          "prefixItems": [
            {
              "type": "number"
            },
            {
              "type": "number"
            }
          ],
          "minItems": 2,
          "maxItems": 2
        },
        "operating_depth": {
          "description": "Depth of the plane the vehicles move in [m], positive down.",
          "type": "number"
        }
      },
      "required": [
        "size",
        "origin",
        "operating_depth"
      ],
      "additionalProperties": false
    },
    "TerrainMesh": {
      "type": "object",
      "description": "The seabed as a triangle mesh on a regular vertex grid (decimated from the height map).",
      "properties": {
        "shape": {
          "description": "`(mx, my)` vertices along north and east; vertex `(i, j)` has index `i * my + j`.",
          "type": "array",
          "prefixItems": [
            {
              "type": "integer"
            },
            {
              "type": "integer"
            }
          ],
          "minItems": 2,
          "maxItems": 2
        },
        "vertices": {
          "description": "`(x, y, z)` per vertex [m], NED: `z` is the seabed depth (positive down).",
          "type": "array",
          "items": {
            "type": "array",
            "prefixItems": [
              {
                "type": "number"
              },
              {
                "type": "number"
              },
              {
                "type": "number"
              }
            ],
            "minItems": 3,
            "maxItems": 3
          }
        },
        "triangles": {
          "description": "Vertex indices of each triangle (two per grid cell).",
          "type": "array",
          "items": {
            "type": "array",
            "prefixItems": [
              {
                "type": "integer"
              },
              {
                "type": "integer"
              },
              {
                "type": "integer"
              }
            ],
            "minItems": 3,
            "maxItems": 3
          }
        },
        "depth_range": {
          "description": "Smallest and largest depth [m].",
          "type": "array",
          "prefixItems": [
            {
              "type": "number"
            },
            {
              "type": "number"
            }
          ],
          "minItems": 2,
          "maxItems": 2
        }
      },
      "required": [
        "shape",
        "vertices",
        "triangles",
        "depth_range"
      ],
      "additionalProperties": false
    },
    "ObstacleSummary": {
      "type": "object",
      "description": "The obstacle map at the operating depth, coarsened for drawing.",
      "properties": {
        "resolution": {
          "description": "Cell size of the simulation's obstacle map [m].",
          "type": "number"
        },
        "shape": {
          "description": "`(nx, ny)` cells of the simulation's obstacle map.",
          "type": "array",
          "prefixItems": [
            {
              "type": "integer"
            },
            {
              "type": "integer"
            }
          ],
          "minItems": 2,
          "maxItems": 2
        },
        "occupied_fraction": {
          "description": "Fraction of its cells that are solid.",
          "type": "number"
        },
        "fence": {
          "description": "Whether the site's edge is a wall the sonar sees (not drawn in `rows`).",
          "type": "boolean"
        },
        "extent": {
          "description": "`(x_min, x_max, y_min, y_max)` [m] that `rows` cover.",
          "type": "array",
          "prefixItems": [
            {
              "type": "number"
            },
            {
              "type": "number"
            },
            {
              "type": "number"
            },
            {
              "type": "number"
            }
          ],
          "minItems": 4,
          "maxItems": 4
        },
        "coarse_resolution": {
          "description": "Cell size of `rows` [m].",
          "type": "number"
        },
        "rows": {
          "description": "One string per coarse row, south (small `x`) first; character `j` (east) is `#` where any fine cell in the coarse cell is solid, else `.`.",
          "type": "array",
          "items": {
            "type": "string"
          }
        }
      },
      "required": [
        "resolution",
        "shape",
        "occupied_fraction",
        "fence",
        "extent",
        "coarse_resolution",
        "rows"
      ],
      "additionalProperties": false
    },
    "AgentInfo": {
      "type": "object",
      "description": "One agent.",
      "properties": {
        "name": {
          "description": "Agent name (`pursuer_0`, `evader_0`, ...).",
          "type": "string"
        },
        "role": {
          "description": "`pursuer` or `evader`.",
          "enum": [
            "pursuer",
            "evader"
          ]
        },
        "vehicle_type": {
          "description": "`work_class`, `spherical`, or the name of a vehicle file's type.",
          "type": "string"
        },
        "policy": {
          "description": "The policy that drives it (a zoo spec, or `external` when actions come from outside).",
          "type": "string"
        },
        "color": {
          "description": "Display colour `#rrggbb` (the same in every view).",
          "type": "string"
        },
        "radius": {
          "description": "Collision radius [m].",
          "type": "number"
        },
        "v_min": {
          "description": "Smallest commanded surge speed [m/s] (Eq. 15).",
          "type": "number"
        },
        "v_max": {
          "description": "Largest commanded surge speed [m/s] (Eq. 15).",
          "type": "number"
        },
        "omega_max": {
          "description": "Largest commanded yaw rate [rad/s] (Eq. 15).",
          "type": "number"
        },
        "beam_angles": {
          "description": "Sonar beam angles relative to the bow [rad], clockwise positive (3-D game: each beam's azimuth).",
          "type": "array",
          "items": {
            "type": "number"
          }
        },
        "max_range": {
          "description": "Sonar maximum range [m].",
          "type": "number"
        },
        "goal": {
          "description": "Goto task: the goal point `(x, y)` [m] (3-D game: `(x, y, z)`), else None.",
          "anyOf": [
            {
              "type": "array",
              "prefixItems": [
                {
                  "type": "number"
                },
                {
                  "type": "number"
                }
              ],
              "minItems": 2,
              "maxItems": 2
            },
            {
              "type": "array",
              "prefixItems": [
                {
                  "type": "number"
                },
                {
                  "type": "number"
                },
                {
                  "type": "number"
                }
              ],
              "minItems": 3,
              "maxItems": 3
            },
            {
              "type": "null"
            }
          ],
          "default": null
        },
        "goal_radius": {
          "description": "Goto task: distance within which the goal counts as reached [m], else None.",
          "anyOf": [
            {
              "type": "number"
            },
            {
              "type": "null"
            }
          ],
          "default": null
        },
        "w_z_max": {
          "description": "3-D game: largest commanded vertical speed [m/s], else None.",
          "anyOf": [
            {
              "type": "number"
            },
            {
              "type": "null"
            }
          ],
          "default": null
        },
        "beam_elevations": {
          "description": "3-D game: each beam's elevation [rad], positive down, else None.",
          "anyOf": [
            {
              "type": "array",
              "items": {
                "type": "number"
              }
            },
            {
              "type": "null"
            }
          ],
          "default": null
        }
      },
      "required": [
        "name",
        "role",
        "vehicle_type",
        "policy",
        "color",
        "radius",
        "v_min",
        "v_max",
        "omega_max",
        "beam_angles",
        "max_range"
      ],
      "additionalProperties": false
    },
    "FrameOptions": {
      "type": "object",
      "description": "What frames carry beyond poses and scalars.",
      "properties": {
        "sonar_every": {
          "description": "Steps between frames that carry sonar ranges and hit points (1: every frame; 0: none). Other frames carry `None` there (the minimum range always).",
          "type": "integer",
          "default": 1
        },
        "hits": {
          "description": "Whether sonar frames carry hit points (beams that returned an echo) besides ranges.",
          "type": "boolean",
          "default": true
        },
        "obs": {
          "description": "Whether frames carry each agent's observation vector (Eq. 14; for remote stepping).",
          "type": "boolean",
          "default": false
        },
        "terrain_cells": {
          "description": "Most terrain mesh cells along the site's longer side.",
          "type": "integer",
          "default": 96
        },
        "obstacle_cells": {
          "description": "Most cells along the longer side of the obstacle map summary.",
          "type": "integer",
          "default": 120
        }
      },
      "required": [],
      "additionalProperties": false
    },
    "Frame": {
      "type": "object",
      "description": "The state of an episode after one control step (step 0: after reset).",
      "properties": {
        "step": {
          "description": "Steps taken.",
          "type": "integer"
        },
        "time": {
          "description": "Simulated time [s] (`step * dt`).",
          "type": "number"
        },
        "agents": {
          "description": "Every agent, in `EpisodeStatic.agents` order.",
          "type": "array",
          "items": {
            "$ref": "#/$defs/AgentState"
          }
        },
        "captured": {
          "description": "Pursuit: a pursuer is within the capture distance of an evader.",
          "type": "boolean",
          "default": false
        },
        "truncated": {
          "description": "The step limit was reached.",
          "type": "boolean",
          "default": false
        },
        "done": {
          "description": "The episode is over after this step.",
          "type": "boolean",
          "default": false
        },
        "outcome": {
          "description": "Why it ended (`running` until it does).",
          "enum": [
            "captured",
            "collision",
            "out_of_site",
            "reached",
            "truncated",
            "cancelled",
            "running"
          ],
          "default": "running"
        }
      },
      "required": [
        "step",
        "time",
        "agents"
      ],
      "additionalProperties": false
    },
    "AgentState": {
      "type": "object",
      "description": "One agent after a step.",
      "properties": {
        "name": {
          "description": "Agent name.",
          "type": "string"
        },
        "x": {
          "description": "North position [m].",
          "type": "number"
        },
        "y": {
          "description": "East position [m].",
          "type": "number"
        },
        "psi": {
          "description": "Yaw [rad], clockwise from north, in `[-pi, pi)`.",
          "type": "number"
        },
        "u": {
          "description": "Surge speed [m/s].",
          "type": "number"
        },
        "v": {
          "description": "Sway speed [m/s].",
          "type": "number"
        },
        "r": {
          "description": "Yaw rate [rad/s].",
          "type": "number"
        },
        "action": {
          "description": "The command applied during the step `[v, omega]` [m/s, rad/s] (Eq. 16, clipped to Eq. 15's box; zero once the agent is done and in the reset frame); 3-D game: `[v, omega, w_z]` [m/s, rad/s, m/s], `w_z` the vertical speed (positive down).",
          "anyOf": [
            {
              "type": "array",
              "prefixItems": [
                {
                  "type": "number"
                },
                {
                  "type": "number"
                }
              ],
              "minItems": 2,
              "maxItems": 2
            },
            {
              "type": "array",
              "prefixItems": [
                {
                  "type": "number"
                },
                {
                  "type": "number"
                },
                {
                  "type": "number"
                }
              ],
              "minItems": 3,
              "maxItems": 3
            }
          ]
        },
        "reward": {
          "description": "Reward of the step (Eq. 20: `delta_C r_C + delta_E1 r_E1 + delta_E2 r_E2`).",
          "type": "number"
        },
        "episode_return": {
          "description": "Sum of rewards so far.",
          "type": "number"
        },
        "distance": {
          "description": "Distance to the target [m] (pursuer: the evader; evader: the nearest pursuer; goto: the goal).",
          "type": "number"
        },
        "min_range": {
          "description": "Smallest sonar range [m].",
          "type": "number"
        },
        "r_C": {
          "description": "The step's obstacle term (Eq. 17), before its weight `delta_C`.",
          "type": "number",
          "default": 0.0
        },
        "r_E1": {
          "description": "The step's approach term (Eq. 18), before its weight `delta_E1`.",
          "type": "number",
          "default": 0.0
        },
        "r_E2": {
          "description": "The step's capture term (Eq. 19), before its weight `delta_E2`.",
          "type": "number",
          "default": 0.0
        },
        "ranges": {
          "description": "Sonar ranges per beam [m] (None in frames without sonar, see `FrameOptions`).",
          "anyOf": [
            {
              "type": "array",
              "items": {
                "type": "number"
              }
            },
            {
              "type": "null"
            }
          ],
          "default": null
        },
        "hits": {
          "description": "Points `(x, y)` [m] where beams returned an echo (3-D game: `(x, y, z)`; None without sonar or hits).",
          "anyOf": [
            {
              "type": "array",
              "items": {
                "anyOf": [
                  {
                    "type": "array",
                    "prefixItems": [
                      {
                        "type": "number"
                      },
                      {
                        "type": "number"
                      }
                    ],
                    "minItems": 2,
                    "maxItems": 2
                  },
                  {
                    "type": "array",
                    "prefixItems": [
                      {
                        "type": "number"
                      },
                      {
                        "type": "number"
                      },
                      {
                        "type": "number"
                      }
                    ],
                    "minItems": 3,
                    "maxItems": 3
                  }
                ]
              }
            },
            {
              "type": "null"
            }
          ],
          "default": null
        },
        "obs": {
          "description": "The observation vector (Eq. 14; None unless `FrameOptions.obs`).",
          "anyOf": [
            {
              "type": "array",
              "items": {
                "type": "number"
              }
            },
            {
              "type": "null"
            }
          ],
          "default": null
        },
        "active": {
          "description": "Whether the agent is still in the episode after this step.",
          "type": "boolean",
          "default": true
        },
        "terminated": {
          "description": "The agent's episode ended by a task rule at this step.",
          "type": "boolean",
          "default": false
        },
        "truncated": {
          "description": "The agent's episode hit the step limit at this step.",
          "type": "boolean",
          "default": false
        },
        "collision": {
          "description": "The agent touches terrain or another vehicle.",
          "type": "boolean",
          "default": false
        },
        "collided_with": {
          "description": "What it touches when `collision` (the game's `hptvsim.envs.protocol.Game.collided_with`: `seabed`, `surface`, `obstacle`, `site edge` or other agents' names, joined by `\", \"`), else None.",
          "anyOf": [
            {
              "type": "string"
            },
            {
              "type": "null"
            }
          ],
          "default": null
        },
        "out_of_site": {
          "description": "The agent's centre left the site.",
          "type": "boolean",
          "default": false
        },
        "reached": {
          "description": "Goto: the agent is within its goal's radius.",
          "type": "boolean",
          "default": false
        },
        "z": {
          "description": "3-D game: depth [m], positive down, else None (the site's operating depth).",
          "anyOf": [
            {
              "type": "number"
            },
            {
              "type": "null"
            }
          ],
          "default": null
        },
        "phi": {
          "description": "3-D game: roll [rad], else None.",
          "anyOf": [
            {
              "type": "number"
            },
            {
              "type": "null"
            }
          ],
          "default": null
        },
        "theta": {
          "description": "3-D game: pitch [rad], positive nose up, else None.",
          "anyOf": [
            {
              "type": "number"
            },
            {
              "type": "null"
            }
          ],
          "default": null
        },
        "w": {
          "description": "3-D game: heave speed in the body frame [m/s], else None.",
          "anyOf": [
            {
              "type": "number"
            },
            {
              "type": "null"
            }
          ],
          "default": null
        },
        "altitude": {
          "description": "3-D game: height above the seabed [m], else None.",
          "anyOf": [
            {
              "type": "number"
            },
            {
              "type": "null"
            }
          ],
          "default": null
        }
      },
      "required": [
        "name",
        "x",
        "y",
        "psi",
        "u",
        "v",
        "r",
        "action",
        "reward",
        "episode_return",
        "distance",
        "min_range"
      ],
      "additionalProperties": false
    },
    "EpisodeSummary": {
      "type": "object",
      "description": "How an episode ended.",
      "properties": {
        "status": {
          "description": "`finished` (ended by a task rule or the step limit) or `cancelled`.",
          "enum": [
            "finished",
            "cancelled"
          ]
        },
        "outcome": {
          "description": "Why it ended.",
          "enum": [
            "captured",
            "collision",
            "out_of_site",
            "reached",
            "truncated",
            "cancelled",
            "running"
          ]
        },
        "steps": {
          "description": "Steps taken.",
          "type": "integer"
        },
        "sim_time": {
          "description": "Simulated time [s].",
          "type": "number"
        },
        "wall_time": {
          "description": "Wall-clock time the episode took [s].",
          "type": "number"
        },
        "metrics": {
          "description": "The evaluation metrics of the episode.",
          "$ref": "#/$defs/EpisodeMetrics"
        },
        "recording": {
          "description": "Path of its rerun recording, or None.",
          "anyOf": [
            {
              "type": "string"
            },
            {
              "type": "null"
            }
          ],
          "default": null
        },
        "collisions": {
          "description": "Each agent's first collision, in the order they happened.",
          "type": "array",
          "items": {
            "$ref": "#/$defs/CollisionEvent"
          },
          "default": []
        }
      },
      "required": [
        "status",
        "outcome",
        "steps",
        "sim_time",
        "wall_time",
        "metrics"
      ],
      "additionalProperties": false
    },
    "EpisodeMetrics": {
      "type": "object",
      "description": "What one evaluation episode measured.",
      "properties": {
        "seed": {
          "type": "integer"
        },
        "length": {
          "type": "integer"
        },
        "captured": {
          "type": "boolean"
        },
        "time_to_capture_steps": {
          "anyOf": [
            {
              "type": "integer"
            },
            {
              "type": "null"
            }
          ]
        },
        "time_to_capture_s": {
          "anyOf": [
            {
              "type": "number"
            },
            {
              "type": "null"
            }
          ]
        },
        "collision": {
          "type": "boolean"
        },
        "min_distance": {
          "anyOf": [
            {
              "type": "number"
            },
            {
              "type": "null"
            }
          ]
        },
        "final_distance": {
          "anyOf": [
            {
              "type": "number"
            },
            {
              "type": "null"
            }
          ]
        },
        "success_rate": {
          "anyOf": [
            {
              "type": "number"
            },
            {
              "type": "null"
            }
          ]
        },
        "returns": {
          "type": "object",
          "additionalProperties": {
            "type": "number"
          }
        },
        "collided_with": {
          "type": "object",
          "additionalProperties": {
            "type": "string"
          }
        }
      },
      "required": [
        "seed",
        "length",
        "captured",
        "time_to_capture_steps",
        "time_to_capture_s",
        "collision",
        "min_distance",
        "final_distance",
        "success_rate",
        "returns",
        "collided_with"
      ],
      "additionalProperties": false
    },
    "CollisionEvent": {
      "type": "object",
      "description": "An agent's first collision in an episode: who, with what, when and where.",
      "properties": {
        "agent": {
          "description": "The agent that collided.",
          "type": "string"
        },
        "collided_with": {
          "description": "What it touched (as `AgentState.collided_with`).",
          "type": "string"
        },
        "step": {
          "description": "The step at whose end it touched [steps].",
          "type": "integer"
        },
        "time": {
          "description": "Simulated time then [s].",
          "type": "number"
        },
        "x": {
          "description": "North position of its centre [m].",
          "type": "number"
        },
        "y": {
          "description": "East position of its centre [m].",
          "type": "number"
        },
        "z": {
          "description": "Depth of its centre [m], positive down (3-D game; None in the planar game).",
          "anyOf": [
            {
              "type": "number"
            },
            {
              "type": "null"
            }
          ],
          "default": null
        }
      },
      "required": [
        "agent",
        "collided_with",
        "step",
        "time",
        "x",
        "y"
      ],
      "additionalProperties": false
    },
    "Trajectories": {
      "type": "object",
      "description": "Every agent's trajectory as columns.",
      "properties": {
        "step": {
          "description": "Step of each row (0: after reset).",
          "type": "array",
          "items": {
            "type": "integer"
          }
        },
        "time": {
          "description": "Simulated time of each row [s].",
          "type": "array",
          "items": {
            "type": "number"
          }
        },
        "agents": {
          "description": "One trajectory per agent, in `EpisodeStatic.agents` order.",
          "type": "array",
          "items": {
            "$ref": "#/$defs/AgentTrajectory"
          }
        }
      },
      "required": [
        "step",
        "time",
        "agents"
      ],
      "additionalProperties": false
    },
    "AgentTrajectory": {
      "type": "object",
      "description": "One agent's values at every recorded step (same length as :attr:`Trajectories.step`).",
      "properties": {
        "name": {
          "description": "Agent name.",
          "type": "string"
        },
        "x": {
          "description": "North position [m].",
          "type": "array",
          "items": {
            "type": "number"
          }
        },
        "y": {
          "description": "East position [m].",
          "type": "array",
          "items": {
            "type": "number"
          }
        },
        "psi": {
          "description": "Yaw [rad].",
          "type": "array",
          "items": {
            "type": "number"
          }
        },
        "u": {
          "description": "Surge speed [m/s].",
          "type": "array",
          "items": {
            "type": "number"
          }
        },
        "v": {
          "description": "Sway speed [m/s].",
          "type": "array",
          "items": {
            "type": "number"
          }
        },
        "r": {
          "description": "Yaw rate [rad/s].",
          "type": "array",
          "items": {
            "type": "number"
          }
        },
        "v_cmd": {
          "description": "Commanded surge speed [m/s].",
          "type": "array",
          "items": {
            "type": "number"
          }
        },
        "omega_cmd": {
          "description": "Commanded yaw rate [rad/s].",
          "type": "array",
          "items": {
            "type": "number"
          }
        },
        "reward": {
          "description": "Reward of the step (Eq. 20).",
          "type": "array",
          "items": {
            "type": "number"
          }
        },
        "distance": {
          "description": "Distance to the target [m].",
          "type": "array",
          "items": {
            "type": "number"
          }
        },
        "min_range": {
          "description": "Smallest sonar range [m].",
          "type": "array",
          "items": {
            "type": "number"
          }
        },
        "r_C": {
          "description": "Obstacle term of each step (Eq. 17, unweighted; None in trajectories stored before the terms were).",
          "anyOf": [
            {
              "type": "array",
              "items": {
                "type": "number"
              }
            },
            {
              "type": "null"
            }
          ],
          "default": null
        },
        "r_E1": {
          "description": "Approach term of each step (Eq. 18, unweighted; None likewise).",
          "anyOf": [
            {
              "type": "array",
              "items": {
                "type": "number"
              }
            },
            {
              "type": "null"
            }
          ],
          "default": null
        },
        "r_E2": {
          "description": "Capture term of each step (Eq. 19, unweighted; None likewise).",
          "anyOf": [
            {
              "type": "array",
              "items": {
                "type": "number"
              }
            },
            {
              "type": "null"
            }
          ],
          "default": null
        },
        "z": {
          "description": "3-D game: depth [m], positive down (None in the planar game).",
          "anyOf": [
            {
              "type": "array",
              "items": {
                "type": "number"
              }
            },
            {
              "type": "null"
            }
          ],
          "default": null
        },
        "phi": {
          "description": "3-D game: roll [rad] (None in the planar game).",
          "anyOf": [
            {
              "type": "array",
              "items": {
                "type": "number"
              }
            },
            {
              "type": "null"
            }
          ],
          "default": null
        },
        "theta": {
          "description": "3-D game: pitch [rad] (None in the planar game).",
          "anyOf": [
            {
              "type": "array",
              "items": {
                "type": "number"
              }
            },
            {
              "type": "null"
            }
          ],
          "default": null
        },
        "w": {
          "description": "3-D game: heave speed [m/s] (None in the planar game).",
          "anyOf": [
            {
              "type": "array",
              "items": {
                "type": "number"
              }
            },
            {
              "type": "null"
            }
          ],
          "default": null
        },
        "w_cmd": {
          "description": "3-D game: commanded vertical speed [m/s], positive down (None in the planar game).",
          "anyOf": [
            {
              "type": "array",
              "items": {
                "type": "number"
              }
            },
            {
              "type": "null"
            }
          ],
          "default": null
        },
        "altitude": {
          "description": "3-D game: height above the seabed [m] (None in the planar game).",
          "anyOf": [
            {
              "type": "array",
              "items": {
                "type": "number"
              }
            },
            {
              "type": "null"
            }
          ],
          "default": null
        },
        "ranges": {
          "description": "Sonar ranges per beam [m] of each step; an empty tuple at steps whose frame carried no sonar (`FrameOptions.sonar_every`); None when not stored at all.",
          "anyOf": [
            {
              "type": "array",
              "items": {
                "type": "array",
                "items": {
                  "type": "number"
                }
              }
            },
            {
              "type": "null"
            }
          ],
          "default": null
        }
      },
      "required": [
        "name",
        "x",
        "y",
        "psi",
        "u",
        "v",
        "r",
        "v_cmd",
        "omega_cmd",
        "reward",
        "distance",
        "min_range"
      ],
      "additionalProperties": false
    }
  }
};

/** The display colours of every view (hptvsim/palette.py). */
export const DISPLAY = {"pursuer_colors": ["#e8203a", "#a970ff", "#3fcf6f", "#ff5ec8", "#ff7a1a", "#ff9e9e"], "evader_colors": ["#f2b400", "#9be22d", "#f2f2f2", "#ffe4a0"], "sonar_hit_color": "#1ee6ff", "sonar_range_stops": [[0.0, [30, 230, 255]], [0.5, [110, 200, 255]], [1.0, [165, 225, 255]]], "depth_stops": [[0.0, [222, 196, 140]], [0.35, [120, 170, 150]], [0.7, [50, 110, 150]], [1.0, [20, 40, 90]]], "obstacle_color": "#7a5c3a", "land_color": "#d9c79a"};
