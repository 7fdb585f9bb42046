"""``hptvsim demo``: the vehicles through their FMUs, then one pursuit-evasion episode; plots.

1. A work-class UUV runs a lawnmower pattern and a spherical UUV a figure of eight, both in a
   0.3 m/s north-easterly current, stepped at the paper's 0.25 s through the lean FMI path
   (``trajectories.png``: tracks, north up and east right, and commanded versus achieved surge
   speed and yaw rate).
2. One episode of the game on the target scenario on the FMU backend, every agent with its
   default policy (:func:`hptvsim.zoo.default_policy`: the shipped trained ones where there are
   some) (``episode.png``: the tracks over the seabed, and the pursuer-evader distances).
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import numpy.typing as npt

from hptvsim.cosim import FmuModel
from hptvsim.dynamics import vehicle_parameters
from hptvsim.fmu import fmu_path
from hptvsim.fmu.build import DEFAULT_STEP

__all__ = ["run_demo", "simulate_manoeuvre"]

_CURRENT = (0.3 * math.cos(math.pi / 4), 0.3 * math.sin(math.pi / 4))  # m/s, {n}


def _lawnmower(t: float, v_max: float, omega_max: float) -> tuple[float, float]:
    """Straight legs of 25 s joined by half turns at 0.4 omega_max."""
    turn = math.pi / (0.4 * omega_max)  # s, duration of a half turn
    period = 25.0 + turn
    k, phase = divmod(t, period)
    if phase < 25.0:
        return 0.8 * v_max, 0.0
    return 0.5 * v_max, 0.4 * omega_max * (1.0 if int(k) % 2 == 0 else -1.0)


def _figure_eight(t: float, v_max: float, omega_max: float) -> tuple[float, float]:
    """Alternate full circles left and right at 0.3 omega_max."""
    circle = 2.0 * math.pi / (0.3 * omega_max)  # s
    k = int(t // circle)
    return 0.7 * v_max, 0.3 * omega_max * (1.0 if k % 2 == 0 else -1.0)


def simulate_manoeuvre(vehicle_type: str, duration: float) -> dict[str, npt.NDArray[np.float64]]:
    """Step one vehicle's FMU through its demo manoeuvre.

    Returns:
        Arrays ``t`` [s], ``x``, ``y`` [m], ``psi`` [rad], ``u`` [m/s], ``r`` [rad/s],
        ``v_cmd`` [m/s], ``omega_cmd`` [rad/s].
    """
    params = vehicle_parameters(vehicle_type)
    pattern = _lawnmower if vehicle_type == "work_class" else _figure_eight
    inst = FmuModel(fmu_path(vehicle_type)).instantiate(vehicle_type)
    inst.initialize({"x_0": 0.0, "y_0": 0.0, "psi_0": 0.0})
    cmd = inst.bind_inputs(["v_cmd", "omega_cmd", "current_x", "current_y"])
    out = inst.bind_outputs(["x", "y", "psi", "u", "r"])
    n = round(duration / DEFAULT_STEP)
    log = np.zeros((n + 1, 8))
    log[0, 1:6] = inst.read_outputs()
    for k in range(n):
        t = k * DEFAULT_STEP
        v, om = pattern(t, params.v_max, params.omega_max)
        cmd[:] = (v, om, *_CURRENT)
        inst.step(DEFAULT_STEP)
        log[k + 1, 0] = t + DEFAULT_STEP
        log[k + 1, 1:6] = out
        log[k + 1, 6:8] = (v, om)
    inst.free()
    names = ("t", "x", "y", "psi", "u", "r", "v_cmd", "omega_cmd")
    return {name: log[:, i] for i, name in enumerate(names)}


def plot_episode(out_dir: Path, *, scenario: str = "target", seed: int = 0, max_steps: int = 1200) -> Path:
    """Play one episode with the default policies on the FMU backend; write ``episode.png``."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from hptvsim.viz.episode import run_episode
    from hptvsim.world.scenario import load_scenario

    result = run_episode(scenario, {}, seed=seed, max_steps=max_steps, backend="fmu")
    world = load_scenario(scenario).build_world()
    traj = result.trajectories
    fig, (ax_map, ax_d) = plt.subplots(1, 2, figsize=(13, 6), layout="constrained", width_ratios=(1, 1.3))
    x0, x1, y0, y1 = world.obstacles.geometry.extent
    ax_map.imshow(-world.heightmap.depth, origin="lower", extent=(y0, y1, x0, x1), cmap="Blues_r", alpha=0.8)
    ax_map.contour(
        world.obstacles.occupied.astype(float), levels=[0.5], colors="saddlebrown", origin="lower",
        extent=(y0, y1, x0, x1),
    )  # fmt: skip
    for agent in traj.agents:
        color = "tab:red" if agent.name.startswith("pursuer") else "tab:blue"
        ax_map.plot(agent.y, agent.x, color=color, lw=1.2, label=agent.name)
        ax_map.plot(agent.y[-1], agent.x[-1], marker="o", color=color)
        if agent.name.startswith("pursuer"):
            ax_d.plot(
                traj.time, agent.distance, color=color, lw=1.0, alpha=0.8, label=f"{agent.name} to evader"
            )
    ax_map.set_xlabel("east y [m]")
    ax_map.set_ylabel("north x [m]")
    ax_map.set_aspect("equal")
    ax_map.legend(loc="upper right", fontsize=8)
    outcome = result.summary.outcome
    ax_map.set_title(f"{scenario}: {outcome} after {result.summary.sim_time:.0f} s")
    ax_d.axhline(25.0, color="k", ls="--", lw=0.8, label="target distance 25 m (capture)")
    ax_d.set_xlabel("time [s]")
    ax_d.set_ylabel("distance [m]")
    ax_d.grid(alpha=0.3)
    ax_d.legend(fontsize=8)
    out_dir.mkdir(parents=True, exist_ok=True)
    path = out_dir / "episode.png"
    fig.savefig(path, dpi=100)
    plt.close(fig)
    return path


def run_demo(out_dir: Path, *, duration: float = 120.0) -> Path:
    """Run both manoeuvres and write ``trajectories.png`` into ``out_dir``; returns its path."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    runs = {vt: simulate_manoeuvre(vt, duration) for vt in ("work_class", "spherical")}
    fig = plt.figure(figsize=(13, 7), layout="constrained")
    grid = fig.add_gridspec(2, 3)
    ax_map = fig.add_subplot(grid[:, 0:2])
    colors = {"work_class": "tab:blue", "spherical": "tab:orange"}
    labels = {"work_class": "work-class UUV (lawnmower)", "spherical": "spherical UUV (figure of eight)"}
    for vt, run in runs.items():
        ax_map.plot(run["y"], run["x"], color=colors[vt], label=labels[vt])
        ax_map.plot(run["y"][-1], run["x"][-1], marker="o", color=colors[vt])
    ax_map.set_xlabel("east y [m]")
    ax_map.set_ylabel("north x [m]")
    ax_map.set_aspect("equal")
    ax_map.grid(alpha=0.3)
    ax_map.set_title(f"Tracks over {duration:g} s in a 0.3 m/s NE current")
    ax_map.legend(loc="best")
    ax_u = fig.add_subplot(grid[0, 2])
    ax_r = fig.add_subplot(grid[1, 2])
    for vt, run in runs.items():
        ax_u.plot(run["t"], run["u"], color=colors[vt])
        ax_u.plot(run["t"][1:], run["v_cmd"][1:], color=colors[vt], ls="--", lw=0.8)
        ax_r.plot(run["t"], run["r"], color=colors[vt])
        ax_r.plot(run["t"][1:], run["omega_cmd"][1:], color=colors[vt], ls="--", lw=0.8)
    ax_u.set_ylabel("surge u [m/s] (dashed: command)")
    ax_r.set_ylabel("yaw rate r [rad/s] (dashed: command)")
    ax_r.set_xlabel("time [s]")
    for ax in (ax_u, ax_r):
        ax.grid(alpha=0.3)
    out_dir.mkdir(parents=True, exist_ok=True)
    path = out_dir / "trajectories.png"
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path
