"""The orchestrator: vehicle and non-vehicle FMUs through one code path, bit for bit.

A reference for "each FMU stepped alone" is FMPy's own high-level API (``FMU2Slave``:
``setReal``, ``doStep``, ``getReal``), an importer independent of the orchestrator's calls.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from cosim_fixtures import lowpass_fmu, lowpass_step
from fmpy.fmi2 import FMU2Slave
from fmpy.validation import validate_fmu

from hptvsim.cosim import FmuError
from hptvsim.cosim.fmu_model import load_model
from hptvsim.cosim.graph import Component, Connection, ExternalInput, ExternalOutput, Graph, GraphError, Port
from hptvsim.cosim.orchestrator import Orchestrator, SimulationFailedError, SimulationPausedError
from hptvsim.fmu import fmu_path

__all__ = ["lowpass_fmu"]  # the fixture, imported for pytest

P = Port.parse
H = 0.25  # s, macro step
OUTS = ("x", "y", "psi", "u", "v", "r", "tau_X", "tau_Y", "tau_N")

# 3 work-class UUVs and 1 spherical UUV, each with its own parameters and initial pose.
FLEET = {
    "uuv_a": ("work_class", {"x_0": 5.0, "y_0": -3.0, "psi_0": 0.4, "v_max": 2.5}),
    "uuv_b": ("work_class", {"x_0": -8.0, "y_0": 2.0, "psi_0": -2.0, "m": 2000.0, "K_p_u": 2.5}),
    "uuv_c": ("work_class", {"x_0": 0.0, "y_0": 10.0, "psi_0": 3.0, "omega_max": 1.2}),
    "sphere": ("spherical", {"x_0": 1.0, "y_0": 1.0, "psi_0": 0.0, "v_max": 1.8, "h_max": 0.05}),
}


def fleet_graph(*, algorithm: str = "jacobi") -> Graph:
    components = [Component(name=n, fmu=f"vehicle:{t}", parameters=p) for n, (t, p) in FLEET.items()]
    inputs = [ExternalInput(name="current_x", targets=tuple(P(f"{n}.current_x") for n in FLEET))]
    inputs.append(
        ExternalInput(name="current_y", targets=tuple(P(f"{n}.current_y") for n in FLEET), start=0.1)
    )
    for n in FLEET:
        inputs.append(ExternalInput(name=f"{n}.v_cmd", targets=(P(f"{n}.v_cmd"),)))
        inputs.append(ExternalInput(name=f"{n}.omega_cmd", targets=(P(f"{n}.omega_cmd"),)))
    outputs = [ExternalOutput(name=f"{n}.{o}", source=P(f"{n}.{o}")) for n in FLEET for o in OUTS]
    return Graph(
        name="fleet",
        components=tuple(components),
        inputs=tuple(inputs),
        outputs=tuple(outputs),
        step_size=H,
        algorithm=algorithm,
    )


def command_sequence(steps: int, seed: int = 1) -> np.ndarray:
    """Per step: current_x, current_y, then v_cmd, omega_cmd per vehicle (piecewise constant)."""
    rng = np.random.default_rng(seed)
    seq = np.empty((steps, 2 + 2 * len(FLEET)))
    for k in range(0, steps, 20):
        seq[k : k + 20, 0:2] = rng.uniform(-0.4, 0.4, 2)
        seq[k : k + 20, 2::2] = rng.uniform(-0.5, 3.5, len(FLEET))
        seq[k : k + 20, 3::2] = rng.uniform(-3.5, 3.5, len(FLEET))
    return seq


def run_alone(name: str, seq: np.ndarray) -> np.ndarray:
    """Step one vehicle FMU by itself with FMPy's high-level calls."""
    vtype, params = FLEET[name]
    model = load_model(fmu_path(vtype))
    slave = FMU2Slave(
        guid=model.guid,
        unzipDirectory=str(model.unzip_dir),
        modelIdentifier=model.identifier,
        instanceName=name,
    )
    slave.instantiate()
    slave.setupExperiment(startTime=0.0)
    slave.enterInitializationMode()
    slave.setReal([model.variable(k).value_reference for k in params], list(params.values()))
    slave.exitInitializationMode()
    k = list(FLEET).index(name)
    vr_in = [model.variable(n).value_reference for n in ("current_x", "current_y", "v_cmd", "omega_cmd")]
    vr_out = [model.variable(n).value_reference for n in OUTS]
    out = np.empty((len(seq), len(OUTS)))
    t = 0.0
    for i, row in enumerate(seq):
        slave.setReal(vr_in, [row[0], row[1], row[2 + 2 * k], row[3 + 2 * k]])
        slave.doStep(currentCommunicationPoint=t, communicationStepSize=H)
        t += H
        out[i] = slave.getReal(vr_out)
    slave.terminate()
    slave.freeInstance()
    return out


def run_graph(orch: Orchestrator, seq: np.ndarray) -> np.ndarray:
    out = np.empty((len(seq), len(orch.outputs)))
    for i, row in enumerate(seq):
        orch.inputs[:] = row
        out[i] = orch.step()
    return out


@pytest.mark.parametrize("algorithm", ["jacobi", "gauss-seidel"])
def test_four_vehicle_fmus_reproduce_each_fmu_alone_bit_for_bit(algorithm: str) -> None:
    seq = command_sequence(1000)
    with Orchestrator(fleet_graph(algorithm=algorithm)) as orch:
        assert orch.input_names[:2] == ("current_x", "current_y")
        got = run_graph(orch, seq).reshape(len(seq), len(FLEET), len(OUTS))
    for k, name in enumerate(FLEET):
        alone = run_alone(name, seq)
        assert np.array_equal(got[:, k], alone), f"{name} differs from the FMU stepped alone"
    # the vehicles moved and reacted to their own commands: not a trivial match
    assert np.ptp(got[:, :, 0], axis=0).min() > 5.0
    assert np.unique(got[-1, :, 0]).size == len(FLEET)


def test_reset_reruns_the_episode_exactly_without_reloading() -> None:
    seq = command_sequence(200, seed=7)
    with Orchestrator(fleet_graph()) as orch:
        instances = [orch.instance(n) for n in FLEET]
        first = run_graph(orch, seq)
        orch.reset()
        assert orch.time == 0.0
        assert [orch.instance(n) for n in FLEET] == instances  # same instances: no reload
        assert np.array_equal(run_graph(orch, seq), first)
        # per-episode values (a new initial pose) apply on reset and only to that episode
        orch.reset(parameters={"uuv_a": {"x_0": 100.0}})
        assert orch.output("uuv_a.x") == 100.0
        orch.reset()
        assert orch.output("uuv_a.x") == 5.0


def test_snapshot_run_restore_run_is_identical(tmp_path: Path) -> None:
    seq = command_sequence(300, seed=3)
    graph = fleet_graph()
    with Orchestrator(graph) as orch:
        run_graph(orch, seq[:100])
        snap = orch.snapshot()
        t_snap = orch.time
        first = run_graph(orch, seq[100:])
        orch.restore(snap)
        assert orch.time == t_snap
        second = run_graph(orch, seq[100:])
        assert np.array_equal(first, second)
        data = orch.serialize(snap)
        snap.release()
    (tmp_path / "snap.bin").write_bytes(data)
    with Orchestrator(graph) as fresh:  # another orchestrator, as after a restart
        fresh.restore(fresh.deserialize((tmp_path / "snap.bin").read_bytes()))
        assert fresh.time == t_snap
        assert np.array_equal(run_graph(fresh, seq[100:]), first)


def test_pause_holds_time_and_resume_continues() -> None:
    seq = command_sequence(40, seed=5)
    with Orchestrator(fleet_graph()) as ref:
        expected = run_graph(ref, seq)
    with Orchestrator(fleet_graph()) as orch:
        run_graph(orch, seq[:20])
        orch.pause()
        assert orch.paused
        with pytest.raises(SimulationPausedError, match="resume"):
            orch.step()
        assert orch.time == 20 * H
        snap = orch.snapshot()  # allowed while paused
        orch.restore(snap)
        orch.resume()
        assert np.array_equal(run_graph(orch, seq[20:]), expected[20:])


def test_non_vehicle_fmu_chain_jacobi_and_gauss_seidel_exact(lowpass_fmu: Path) -> None:
    assert validate_fmu(str(lowpass_fmu)) == []
    T1, T2, K2, u = 0.5, 2.0, 3.0, 1.0

    def graph(algorithm: str) -> Graph:
        return Graph(
            components=(
                Component(name="f1", fmu=str(lowpass_fmu), parameters={"T": T1}),
                Component(name="f2", fmu=str(lowpass_fmu), parameters={"T": T2, "K": K2, "y_0": 0.5}),
            ),
            connections=(Connection(source=P("f1.y"), target=P("f2.u")),),
            inputs=(ExternalInput(name="u", targets=(P("f1.u"),), start=u),),
            outputs=(
                ExternalOutput(name="y1", source=P("f1.y")),
                ExternalOutput(name="y2", source=P("f2.y")),
            ),
            step_size=H,
            algorithm=algorithm,
        )

    for algorithm in ("jacobi", "gauss-seidel"):
        with Orchestrator(graph(algorithm)) as orch:
            got = orch.run(40)
        y1, y2 = 0.0, 0.5
        expected = [(y1, y2)]
        for _ in range(40):
            y1_next = lowpass_step(y1, u, T=T1, h=H)
            # Jacobi: f2 sees f1's output of the previous communication point; Gauss-Seidel: the new one
            y2 = lowpass_step(y2, y1 if algorithm == "jacobi" else y1_next, T=T2, K=K2, h=H)
            y1 = y1_next
            expected.append((y1, y2))
        assert np.array_equal(got, np.array(expected)), algorithm


def test_vehicle_and_non_vehicle_fmus_in_one_loop(lowpass_fmu: Path) -> None:
    """A filter shapes the UUV's speed command; a second filter smooths the UUV's surge speed."""
    graph = Graph(
        components=(
            Component(name="shaper", fmu=str(lowpass_fmu), parameters={"T": 1.5}),
            Component(name="uuv", fmu="vehicle:work_class", parameters={"h_max": 0.05}),
            Component(name="meter", fmu=str(lowpass_fmu), parameters={"T": 0.75}),
        ),
        connections=(
            Connection(source=P("shaper.y"), target=P("uuv.v_cmd")),
            Connection(source=P("uuv.u"), target=P("meter.u")),
        ),
        inputs=(ExternalInput(name="demand", targets=(P("shaper.u"),), start=2.0),),
        outputs=(
            ExternalOutput(name="cmd", source=P("shaper.y")),
            ExternalOutput(name="u", source=P("uuv.u")),
            ExternalOutput(name="u_smooth", source=P("meter.y")),
        ),
        step_size=H,
    )
    with Orchestrator(graph) as orch:
        got = orch.run(120)
    # the same by hand: the vehicle FMU alone (FMPy) and the filter's formula, Jacobi exchange
    model = load_model(fmu_path("work_class"))
    slave = FMU2Slave(guid=model.guid, unzipDirectory=str(model.unzip_dir), modelIdentifier=model.identifier)
    slave.instantiate()
    slave.setupExperiment(startTime=0.0)
    slave.enterInitializationMode()
    slave.setReal([model.variable("h_max").value_reference], [0.05])
    slave.exitInitializationMode()
    vr_v, vr_u = model.variable("v_cmd").value_reference, model.variable("u").value_reference
    cmd, speed, smooth = 0.0, 0.0, 0.0
    rows = [(cmd, speed, smooth)]
    for k in range(120):
        slave.setReal([vr_v], [cmd])
        slave.doStep(currentCommunicationPoint=k * H, communicationStepSize=H)
        new_cmd = lowpass_step(cmd, 2.0, T=1.5, h=H)
        smooth = lowpass_step(smooth, speed, T=0.75, h=H)
        cmd, speed = new_cmd, slave.getReal([vr_u])[0]
        rows.append((cmd, speed, smooth))
    slave.freeInstance()
    assert np.array_equal(got, np.array(rows))
    assert got[-1, 1] == pytest.approx(2.0, abs=0.05)  # the UUV follows the shaped command


def test_component_error_mid_run_names_it_and_the_next_episode_runs(lowpass_fmu: Path) -> None:
    graph = Graph(
        components=(
            Component(name="uuv", fmu="vehicle:work_class"),
            Component(name="flaky", fmu=str(lowpass_fmu), parameters={"fail_time": 2.0}),
        ),
        connections=(Connection(source=P("flaky.y"), target=P("uuv.v_cmd")),),
        inputs=(ExternalInput(name="u", targets=(P("flaky.u"),), start=1.5),),
        outputs=(ExternalOutput(name="x", source=P("uuv.x")),),
        step_size=H,
    )
    with Orchestrator(graph) as orch:
        orch.run(8)  # to t = 2.0
        with pytest.raises(FmuError) as info:
            orch.step()
        err = info.value
        assert err.component == "flaky"
        assert err.call == "fmi2DoStep"
        assert "fail_time = 2 reached" in str(err)
        assert "component 'flaky'" in str(err)
        with pytest.raises(SimulationFailedError, match="reset"):
            orch.step()
        # the next episode runs, and without the fault it matches a fresh orchestrator's run
        orch.reset(parameters={"flaky": {"fail_time": -1.0}})
        again = orch.run(40)
        # the fault comes back in an episode that keeps it
        orch.reset()
        orch.run(8)
        with pytest.raises(FmuError, match="flaky"):
            orch.step()
    healthy = Graph(
        components=(graph.components[0], Component(name="flaky", fmu=str(lowpass_fmu))),
        connections=graph.connections,
        inputs=graph.inputs,
        outputs=graph.outputs,
        step_size=H,
    )
    with Orchestrator(healthy) as fresh:
        assert np.array_equal(fresh.run(40), again)


def test_vehicle_fmu_error_mid_run_then_reset() -> None:
    """A parameter change that makes M singular is caught by the FMU's fmi2DoStep."""
    seq = command_sequence(30, seed=11)
    with Orchestrator(fleet_graph()) as orch:
        first = run_graph(orch, seq)
        orch.reset()
        run_graph(orch, seq[:10])
        orch.set_parameters("uuv_b", {"X_udot": 1.0e5})  # M_11 = m - X_udot < 0
        with pytest.raises(FmuError) as info:
            orch.step()
        assert info.value.component == "uuv_b"
        assert info.value.call == "fmi2DoStep"
        assert "positive definite" in str(info.value)
        with pytest.raises(SimulationFailedError):
            orch.snapshot()
        orch.reset()
        assert np.array_equal(run_graph(orch, seq), first)


def test_bad_inputs_and_ports_are_named() -> None:
    with Orchestrator(fleet_graph()) as orch:
        orch.set_input("uuv_a.v_cmd", float("nan"))
        with pytest.raises(FmuError, match=r"uuv_a.*fmi2SetReal.*v_cmd.*not finite"):
            orch.step()
        with pytest.raises(KeyError, match="inputs: current_x"):
            orch.set_input("nope", 1.0)
        with pytest.raises(KeyError, match=r"outputs: uuv_a\.x"):
            orch.output("nope")
        with pytest.raises(KeyError, match="components: uuv_a"):
            orch.reset(["nope"])
    base = fleet_graph()
    bad_graphs = {
        "has no output named 'speed'": Connection(source=P("uuv_a.speed"), target=P("uuv_b.v_cmd")),
        "has no input/parameter named 'x'": Connection(source=P("uuv_a.u"), target=P("uuv_b.x")),
        r"units differ \(m vs N\)": Connection(source=P("uuv_a.x"), target=P("uuv_c.tau_X_cmd")),
    }
    for message, conn in bad_graphs.items():
        conn_target = conn.target
        inputs = tuple(i for i in base.inputs if conn_target not in i.targets)
        graph = Graph(components=base.components, connections=(conn,), inputs=inputs, step_size=H)
        with pytest.raises(GraphError, match=message):
            Orchestrator(graph)


def test_orchestrator_knows_nothing_vehicle_specific() -> None:
    import hptvsim.cosim.orchestrator as mod

    source = Path(mod.__file__).read_text()
    for word in ("vehicle", "v_cmd", "psi", "hptvsim.dynamics", "hptvsim.fmu"):
        assert word not in source.replace("Nothing here is specific to the vehicle FMUs.", ""), word


def test_extracted_fmus_of_killed_processes_are_removed(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """An FMU is extracted into ``hptvsim-fmu-<pid namespace>-<pid>-...``; a process killed before
    it could clean up leaves its folder, which the next process to open an FMU removes (pid
    gone), while a living process's folder, and one of another pid namespace, stay."""
    import os
    import subprocess
    import sys
    import tempfile

    from hptvsim.cosim import fmu_model

    monkeypatch.setattr(tempfile, "tempdir", str(tmp_path))
    monkeypatch.setitem(fmu_model._orphans_swept, "done", False)
    gone = subprocess.Popen([sys.executable, "-c", "pass"])
    gone.wait()
    ns = fmu_model._pid_namespace()
    orphan = tmp_path / f"hptvsim-fmu-{ns}-{gone.pid}-WorkClassUUV-abc"
    living = tmp_path / f"hptvsim-fmu-{ns}-{os.getppid()}-WorkClassUUV-def"
    elsewhere = tmp_path / f"hptvsim-fmu-{ns}1-{gone.pid}-WorkClassUUV-jkl"  # another pid namespace
    other = tmp_path / f"hptvsim-fmu-{ns}-notapid-x"
    for folder in (orphan, living, elsewhere, other):
        (folder / "binaries").mkdir(parents=True)
    model = fmu_model.FmuModel(fmu_path("work_class"))
    assert not orphan.exists() and living.exists() and elsewhere.exists() and other.exists()
    assert model.unzip_dir.parent == tmp_path
    assert model.unzip_dir.name.startswith(f"hptvsim-fmu-{ns}-{os.getpid()}-WorkClassUUV-")
    # once per process: a later orphan waits for the next process
    later = tmp_path / f"hptvsim-fmu-{ns}-{gone.pid}-SphericalUUV-ghi"
    later.mkdir()
    fmu_model.FmuModel(fmu_path("work_class"))
    assert later.exists()
