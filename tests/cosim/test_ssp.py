"""SSP 1.0 export and import (``hptvsim.cosim.ssp``), checked against our master and OSP libcosim."""

from __future__ import annotations

import dataclasses
import shutil
import zipfile
from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner
from cosim_fixtures import lowpass_fmu, lowpass_step

from hptvsim.cli import main
from hptvsim.cosim.graph import Graph, GraphError, load_graph
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


def test_a_hand_written_ssp_runs_in_ours(tmp_path: Path, lowpass_fmu: Path) -> None:
    ssp = _hand_ssp(tmp_path / "hand.ssp", lowpass_fmu)
    graph = load_ssp(ssp)
    assert graph.name == "filter-only"
    assert graph.step_size == 0.25
    assert dict(graph.component("filter").parameters) == {"T": 0.5, "K": 3.0}
    assert graph.inputs[0].start == 2.0  # the binding of the input it drives
    res = CliRunner().invoke(main, ["cosim", "run", str(ssp), "--stop-time", "2"])
    assert res.exit_code == 0, res.output
    rows = np.loadtxt(tmp_path / "hand.csv", delimiter=",", skiprows=1)
    assert rows.shape == (9, 2)
    y = 0.0
    for k in range(1, 9):
        y = lowpass_step(y, 2.0, T=0.5, K=3.0, h=0.25)
        assert rows[k, 1] == y


def test_step_size_from_the_caller_when_the_ssp_states_none(tmp_path: Path, lowpass_fmu: Path) -> None:
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
