"""SSP 1.0 export and import (``hptvsim.cosim.ssp``), checked against our master and OSP libcosim."""

from __future__ import annotations

import dataclasses
import json
import shutil
import subprocess
import sys
import zipfile
from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner
from cosim_fixtures import lowpass_fmu, lowpass_step
from typed_fmus import build_typed_fmu

from hptvsim.cli import main
from hptvsim.cosim.graph import (
    Component,
    Connection,
    ExternalInput,
    ExternalOutput,
    Graph,
    GraphError,
    Port,
    load_graph,
)
from hptvsim.cosim.orchestrator import Orchestrator
from hptvsim.cosim.ssp import export_ssp, load_ssp

__all__ = ["lowpass_fmu"]

GRAPH = """
name = "shaped-uuv"
step_size = 0.5
algorithm = "gauss-seidel"
retry_rejected_steps = true

[[components]]
name = "shaper"
fmu = "LowPass.fmu"
parameters = { T = 1.5, K = 2.0, y_0 = 0.25 }

[[components]]
name = "uuv"
fmu = "vehicle:spherical"
parameters = { m = 30.0 }

[[connections]]
from = "shaper.y"
to = "uuv.v_cmd"

[[inputs]]
name = "demand"
to = "shaper.u"
start = 1.5

[[inputs]]
name = "turn"
to = ["uuv.omega_cmd"]
start = 0.2

[[outputs]]
name = "cmd"
from = "shaper.y"

[[outputs]]
name = "x"
from = "uuv.x"

[[outputs]]
name = "psi"
from = "uuv.psi"
"""


def _graph(tmp_path: Path, lowpass: Path, text: str = GRAPH) -> Path:
    shutil.copy(lowpass, tmp_path / "LowPass.fmu")
    (tmp_path / "g.toml").write_text(text)
    return tmp_path / "g.toml"


def _same(a: Graph, b: Graph) -> None:
    """Equal up to the FMU paths (which point into the extracted SSP)."""
    assert [c.name for c in a.components] == [c.name for c in b.components]
    for ca, cb in zip(a.components, b.components, strict=True):
        assert dict(ca.parameters) == dict(cb.parameters)
        assert {k: type(v) for k, v in ca.parameters.items()} == {
            k: type(v) for k, v in cb.parameters.items()
        }
    assert dataclasses.replace(a, components=b.components, base_dir=None) == dataclasses.replace(
        b, base_dir=None
    )


def test_round_trip_and_same_csv(tmp_path: Path, lowpass_fmu: Path) -> None:
    toml = _graph(tmp_path, lowpass_fmu)
    graph = load_graph(toml)
    ssp = export_ssp(graph, tmp_path / "g.ssp")
    with zipfile.ZipFile(ssp) as zf:
        assert sorted(zf.namelist()) == [
            "SystemStructure.ssd",
            "resources/LowPass.fmu",
            "resources/SphericalUUV.fmu",
        ]
        ssd = zf.read("SystemStructure.ssd").decode()
    assert 'xmlns:ssd="http://ssp-standard.org/SSP1/SystemStructureDescription"' in ssd
    assert '<osp:FixedStepAlgorithm baseStepSize="0.5"' in ssd
    assert '<ssd:Connection startConnector="demand" endElement="shaper" endConnector="u"' in ssd
    back = load_ssp(ssp, extract_to=tmp_path / "x")
    _same(graph, back)
    assert back.component("shaper").fmu == "resources/LowPass.fmu"
    assert (tmp_path / "x" / "resources" / "LowPass.fmu").is_file()
    # the libcosim form reads back the same (wiring from the hptvsim annotation)
    _same(graph, load_ssp(export_ssp(graph, tmp_path / "l.ssp", libcosim=True)))

    runner = CliRunner()
    res = runner.invoke(main, ["cosim", "export-ssp", str(toml), "--out", str(tmp_path / "cli.ssp")])
    assert res.exit_code == 0, res.output
    for src, out in ((toml, "a.csv"), (tmp_path / "cli.ssp", "b.csv")):
        res = runner.invoke(
            main, ["cosim", "run", str(src), "--stop-time", "5", "--out", str(tmp_path / out)]
        )
        assert res.exit_code == 0, res.output
    a, b = (tmp_path / "a.csv").read_text(), (tmp_path / "b.csv").read_text()
    assert a == b
    assert a.splitlines()[0] == "time,cmd,x,psi"
    assert len(a.splitlines()) == 12
    bad = runner.invoke(main, ["cosim", "run", str(toml), "--step-size", "0.1"])
    assert bad.exit_code != 0
    assert "only for an .ssp" in bad.output


def test_exported_ssp_runs_in_libcosim_with_our_numbers(tmp_path: Path, lowpass_fmu: Path) -> None:
    libcosim = pytest.importorskip("libcosimpy.CosimExecution")
    from libcosimpy.CosimObserver import CosimObserver

    graph = dataclasses.replace(load_graph(_graph(tmp_path, lowpass_fmu)), algorithm="jacobi")
    ssp = export_ssp(graph, tmp_path / "g.ssp", libcosim=True)
    execution = libcosim.CosimExecution.from_ssp_file(str(ssp))
    observer = CosimObserver.create_last_value()
    execution.add_observer(observer)
    assert execution.simulate_until(int(5e9))  # ns
    theirs = []
    for out in graph.outputs:
        index = execution.slave_index_from_instance_name(out.source.component)
        refs = {v.name.decode(): v.reference for v in execution.slave_variables(index)}
        theirs += observer.last_real_values(index, [refs[out.source.variable]])
    with Orchestrator(graph) as orch:
        orch.run(10)
        ours = [float(v) for v in orch.output_values()]
    assert ours[1] > 1.0  # the sphere moved
    np.testing.assert_allclose(theirs, ours, rtol=0.0, atol=1e-12)


HAND_SSD = """<?xml version="1.0" encoding="UTF-8"?>
<ssd:SystemStructureDescription version="1.0" name="hand"
    xmlns:ssd="http://ssp-standard.org/SSP1/SystemStructureDescription"
    xmlns:ssc="http://ssp-standard.org/SSP1/SystemStructureCommon"
    xmlns:ssv="http://ssp-standard.org/SSP1/SystemStructureParameterValues"
    xmlns:osp="http://opensimulationplatform.com/SSP/OSPAnnotations">
  <ssd:System name="filter-only">
    <ssd:Connectors>
      <ssd:Connector name="demand" kind="input"><ssc:Real/></ssd:Connector>
      <ssd:Connector name="smooth" kind="output"><ssc:Real/></ssd:Connector>
    </ssd:Connectors>
    <ssd:Elements>
      <ssd:Component name="filter" source="resources/LowPass.fmu" type="application/x-fmu-sharedlibrary">
        <ssd:Connectors>
          <ssd:Connector name="u" kind="input"><ssc:Real/></ssd:Connector>
          <ssd:Connector name="y" kind="output"><ssc:Real/></ssd:Connector>
        </ssd:Connectors>
        <ssd:ParameterBindings>
          <ssd:ParameterBinding source="SSV_PATH"/>
        </ssd:ParameterBindings>
      </ssd:Component>
    </ssd:Elements>
    <ssd:Connections>
      <ssd:Connection startConnector="demand" endElement="ELEMENT" endConnector="u"/>
      <ssd:Connection startElement="filter" startConnector="y" endConnector="smooth"/>
    </ssd:Connections>
  </ssd:System>
  <ssd:DefaultExperiment startTime="0">
    <ssd:Annotations>
      <ssc:Annotation type="com.opensimulationplatform">
        <osp:Algorithm><osp:FixedStepAlgorithm baseStepSize="0.25"/></osp:Algorithm>
      </ssc:Annotation>
    </ssd:Annotations>
  </ssd:DefaultExperiment>
</ssd:SystemStructureDescription>
"""

HAND_SSV = """<?xml version="1.0" encoding="UTF-8"?>
<ssv:ParameterSet version="1.0" name="tuning"
    xmlns:ssv="http://ssp-standard.org/SSP1/SystemStructureParameterValues">
  <ssv:Parameters>
    <ssv:Parameter name="T"><ssv:Real value="0.5"/></ssv:Parameter>
    <ssv:Parameter name="K"><ssv:Real value="3"/></ssv:Parameter>
    <ssv:Parameter name="u"><ssv:Real value="2.0"/></ssv:Parameter>
  </ssv:Parameters>
</ssv:ParameterSet>
"""


def _hand_ssp(
    path: Path,
    lowpass: Path,
    *,
    ssv_path: str = "params/filter.ssv",
    element: str = "filter",
    ssd: bool = True,
) -> Path:
    with zipfile.ZipFile(path, "w") as zf:
        if ssd:
            zf.writestr(
                "SystemStructure.ssd", HAND_SSD.replace("SSV_PATH", ssv_path).replace("ELEMENT", element)
            )
        zf.writestr("params/filter.ssv", HAND_SSV)
        zf.write(lowpass, "resources/LowPass.fmu")
    return path


def test_a_hand_written_ssp_runs_in_ours(
    tmp_path: Path, lowpass_fmu: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    ssp = _hand_ssp(tmp_path / "hand.ssp", lowpass_fmu)
    graph = load_ssp(ssp)
    assert graph.name == "filter-only"
    assert graph.step_size == 0.25
    assert dict(graph.component("filter").parameters) == {"T": 0.5, "K": 3.0}
    assert graph.inputs[0].start == 2.0  # the binding of the input it drives
    monkeypatch.chdir(tmp_path)
    res = CliRunner().invoke(main, ["cosim", "run", str(ssp), "--stop-time", "2"])
    assert res.exit_code == 0, res.output
    rows = np.loadtxt(tmp_path / "hptvsim-out" / "cosim" / "hand.csv", delimiter=",", skiprows=1)
    assert rows.shape == (9, 2)
    y = 0.0
    for k in range(1, 9):
        y = lowpass_step(y, 2.0, T=0.5, K=3.0, h=0.25)
        assert rows[k, 1] == y


def test_step_size_from_the_caller_when_the_ssp_states_none(
    tmp_path: Path, lowpass_fmu: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    text = HAND_SSD.replace("SSV_PATH", "params/filter.ssv").replace("ELEMENT", "filter")
    text = text.replace('<osp:FixedStepAlgorithm baseStepSize="0.25"/>', "")
    ssp = tmp_path / "nostep.ssp"
    with zipfile.ZipFile(ssp, "w") as zf:
        zf.writestr("SystemStructure.ssd", text)
        zf.writestr("params/filter.ssv", HAND_SSV)
        zf.write(lowpass_fmu, "resources/LowPass.fmu")
    with pytest.raises(GraphError, match="states no step size"):
        load_ssp(ssp)
    assert load_ssp(ssp, step_size=0.125).step_size == 0.125
    monkeypatch.chdir(tmp_path)  # the outputs go to ./hptvsim-out/cosim/
    runner = CliRunner()
    bad = runner.invoke(main, ["cosim", "run", str(ssp)])
    assert bad.exit_code != 0
    assert "states no step size" in bad.output
    assert "Traceback" not in bad.output
    ok = runner.invoke(main, ["cosim", "run", str(ssp), "--step-size", "0.5", "--stop-time", "1"])
    assert ok.exit_code == 0, ok.output


@pytest.mark.parametrize(
    ("kwargs", "message"),
    [
        ({"ssd": False}, "no SystemStructure.ssd"),
        ({"element": "filtre"}, "no element named 'filtre' (elements: filter"),
        ({"ssv_path": "../filter.ssv"}, "leaves the SSP"),
        ({"ssv_path": "params/../../filter.ssv"}, "leaves the SSP"),
        ({"ssv_path": "/etc/filter.ssv"}, "is absolute"),
        ({"ssv_path": "params/missing.ssv"}, "'params/missing.ssv' is not in the SSP"),
    ],
)
def test_bad_ssps_name_the_problem(
    tmp_path: Path, lowpass_fmu: Path, kwargs: dict[str, object], message: str
) -> None:
    ssp = _hand_ssp(tmp_path / "bad.ssp", lowpass_fmu, **kwargs)  # type: ignore[arg-type]
    with pytest.raises(GraphError, match=message.replace("(", r"\(").replace(".", r"\.")):
        load_ssp(ssp)
    res = CliRunner().invoke(main, ["cosim", "run", str(ssp)])
    assert res.exit_code != 0
    assert message in res.output
    assert "Traceback" not in res.output


def test_not_a_zip(tmp_path: Path) -> None:
    bad = tmp_path / "x.ssp"
    bad.write_text("hello")
    with pytest.raises(GraphError, match="not an SSP archive"):
        load_ssp(bad)


# --- the libcosim flavour and Enumeration variables ------------------------------------------------

_LIBCOSIM_RUN = """
import json, sys
from libcosimpy.CosimExecution import CosimExecution
from libcosimpy.CosimObserver import CosimObserver

ssp, stop_ns, wanted = sys.argv[1], int(sys.argv[2]), json.loads(sys.argv[3])
execution = CosimExecution.from_ssp_file(ssp)
observer = CosimObserver.create_last_value()
execution.add_observer(observer)
assert execution.simulate_until(stop_ns)
values = []
for component, variable, kind in wanted:
    index = execution.slave_index_from_instance_name(component)
    refs = {v.name.decode(): v.reference for v in execution.slave_variables(index)}
    read = getattr(observer, f"last_{kind}_values")
    values += read(index, [refs[variable]])
print("VALUES", json.dumps(values))  # libcosim logs to stdout as well
"""


def _in_libcosim(ssp: Path, stop_time: float, wanted: list[tuple[str, str, str]]) -> list[object]:
    """Run ``ssp`` in OSP libcosim (libcosimpy) in a child process, which libcosim may abort.

    Returns:
        The last values of ``wanted`` (component, variable, ``real``/``integer``/``boolean``).
    """
    pytest.importorskip("libcosimpy.CosimExecution")
    args = [sys.executable, "-c", _LIBCOSIM_RUN, str(ssp), str(round(stop_time * 1e9)), json.dumps(wanted)]
    run = subprocess.run(args, capture_output=True, text=True, timeout=120, check=False)
    assert run.returncode == 0, run.stderr[-2000:]
    (line,) = [ln for ln in run.stdout.splitlines() if ln.startswith("VALUES ")]
    return list(json.loads(line.removeprefix("VALUES ")))


@pytest.fixture(scope="module")
def types_fmu(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """The Types test FMU (every FMI 2.0 type; ``e_in``, ``e_out`` are Enumerations)."""
    return build_typed_fmu("Types", tmp_path_factory.mktemp("types"))


def _types_and_filter(types: Path, lowpass: Path) -> Graph:
    """Types (its Enumerations unused) feeding LowPass; Real, Integer and Boolean outputs."""
    return Graph(
        components=(
            Component(name="t", fmu=str(types), parameters={"gain": 3.0, "offset": -4, "invert": True}),
            Component(name="shaper", fmu=str(lowpass), parameters={"T": 0.5}),
        ),
        connections=(Connection(source=Port.parse("t.r_out"), target=Port.parse("shaper.u")),),
        inputs=(ExternalInput(name="r", targets=(Port.parse("t.r_in"),), start=1.5),),
        outputs=tuple(
            ExternalOutput(name=p.replace(".", "_"), source=Port.parse(p))
            for p in ("t.r_out", "t.i_out", "t.b_out", "shaper.y")
        ),
        step_size=0.1,
    )


def test_the_libcosim_export_has_no_enumeration_connectors_and_runs_there(
    tmp_path: Path, lowpass_fmu: Path, types_fmu: Path
) -> None:
    graph = _types_and_filter(types_fmu, lowpass_fmu)
    ssp = export_ssp(graph, tmp_path / "lc.ssp", libcosim=True)
    wanted = [
        ("t", "r_out", "real"),
        ("t", "i_out", "integer"),
        ("t", "b_out", "boolean"),
        ("shaper", "y", "real"),
    ]
    theirs = _in_libcosim(ssp, 0.5, wanted)  # libcosim aborts on an ssc:Enumeration connector
    with Orchestrator(graph) as orch:
        orch.run(5)
        ours = orch.output_values()
    # after k = 5 steps: gain * r_in + t, i_in + offset + k, b_in XOR invert XOR (k odd)
    assert ours[:3] == [3.0 * 1.5 + 0.5, 0 - 4 + 5, False]
    assert theirs[:3] == ours[:3]
    # libcosim keeps time in integer nanoseconds: from the third step on, the step size it passes
    # to fmi2DoStep differs from 0.1 in the last bits (the filter's y and u still agree before
    # that step), which the filter's exp(-h / T) shows
    y_theirs, y_ours = theirs[3], ours[3]
    assert isinstance(y_theirs, float) and isinstance(y_ours, float)
    assert y_ours > 2.0  # the filter moved towards r_out
    assert abs(y_theirs - y_ours) <= 1e-14 * y_ours
    with zipfile.ZipFile(ssp) as zf:
        ssd = zf.read("SystemStructure.ssd").decode()
    assert "Enumeration" not in ssd
    assert '<ssd:Connector name="i_out" kind="output">' in ssd
    _same(graph, load_ssp(ssp))
    # the standard flavour keeps them
    with zipfile.ZipFile(export_ssp(graph, tmp_path / "std.ssp")) as zf:
        assert zf.read("SystemStructure.ssd").decode().count('<ssc:Enumeration name="Mode" />') == 2


def test_the_libcosim_export_refuses_enumerations_in_use(
    tmp_path: Path, lowpass_fmu: Path, types_fmu: Path
) -> None:
    base = _types_and_filter(types_fmu, lowpass_fmu)
    t, shaper = base.components
    connected = dataclasses.replace(
        base,
        components=(t, shaper, Component(name="t2", fmu=str(types_fmu))),
        connections=(Connection(source=Port.parse("t.e_out"), target=Port.parse("t2.e_in")),),
    )
    driven = dataclasses.replace(
        base, inputs=(ExternalInput(name="mode", targets=(Port.parse("t.e_in"),), start=2),)
    )
    set_ = dataclasses.replace(base, components=(dataclasses.replace(t, parameters={"e_in": 3}), shaper))
    for graph, message in (
        (connected, "connection source t.e_out: 'e_out' is an Enumeration variable, which OSP libcosim"),
        (driven, "external input 'mode' target t.e_in: 'e_in' is an Enumeration variable"),
        (set_, "parameter t.e_in: 'e_in' is an Enumeration variable"),
    ):
        with pytest.raises(GraphError, match=message.replace(".", r"\.")):
            export_ssp(graph, tmp_path / "x.ssp", libcosim=True)
        export_ssp(graph, tmp_path / "std.ssp")  # the standard flavour writes them
        path = tmp_path / "g.json"
        path.write_text(graph.to_json())
        res = CliRunner().invoke(main, ["cosim", "export-ssp", str(path), "--libcosim"])
        assert res.exit_code == 1 and "Traceback" not in res.output
        (line,) = res.output.strip().splitlines()
        assert line.startswith(f"Error: {message}")
        assert line.endswith("export without --libcosim (libcosim=False)")
