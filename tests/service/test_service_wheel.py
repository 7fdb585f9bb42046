"""The service as users install it: ``pip install "hptvsim[service]"`` from the built wheel.

One test, end to end and over real HTTP: build the wheel from this checkout, install it with the
``service`` extra into a fresh virtual environment outside the repository (torch must be the exact
CPU build the extra pins, taken from pip's find-links), start ``hptvsim serve`` from an empty
directory with nothing of the checkout reachable, and use it: the dashboard and its files, the
shipped scenarios and trained policies, the live view, a map, and episodes with scripted and
with the shipped MAISAC (torch) policies. Then a graceful stop, and what the installed copy left
behind: only ``hptvsim`` at the top of site-packages, nothing written into the package or the
working directory, compiled C kernels in the user's cache.

It is one test function rather than several sharing a fixture: under pytest-xdist tests of a
module may land on different workers, and each would build and install again. It is slow (the
install alone, which fetches and unpacks torch and the rest of the extra, takes over 2 minutes on
2 idle cores; the whole test took 5.5 to 8.5 minutes beside other test runs), so it runs with
``make test-slow``. pip's cache is left on (no ``--no-cache-dir``); where the package index
answers without cache headers pip downloads the wheels again all the same.
"""

from __future__ import annotations

import contextlib
import csv
import io
import json
import os
import re
import shutil
import signal
import subprocess
import sys
import time
import zipfile
from pathlib import Path, PurePosixPath
from typing import Any

import httpx
import pytest
from service_helpers import ROOT

TOP_LEVEL = {"hptvsim"}
TRAINED_POLICIES = {"maisac-pursuers", "ippo-pursuers", "maisac-evader", "dt-pursuers"}
FINAL = ("finished", "failed", "cancelled", "interrupted")
# environment variables that would let the installed copy see the checkout or another setup
_FOREIGN_ENV = ("PYTHONPATH", "PYTHONHOME", "PYTHONSTARTUP", "VIRTUAL_ENV", "DATABASE_URL", "RAY_ADDRESS")


def _clean_env(**extra: str) -> dict[str, str]:
    env = {
        k: v
        for k, v in os.environ.items()
        if k not in _FOREIGN_ENV and not k.startswith("HPTVSIM_") and not k.startswith("PYTEST_")
    }
    env.update(extra)
    return env


def _run(cmd: list[str], what: str, *, cwd: Path, log: Path, timeout: float, env: dict[str, str]) -> str:
    """Run a command into ``log``; on failure (or time-out) fail with the tail of its output."""
    with log.open("w") as fh:
        try:
            proc = subprocess.run(
                cmd, cwd=cwd, env=env, stdout=fh, stderr=subprocess.STDOUT, timeout=timeout, check=False
            )
        except subprocess.TimeoutExpired:
            pytest.fail(f"{what} took over {timeout:.0f} s:\n{log.read_text(errors='replace')[-4000:]}")
    out = log.read_text(errors="replace")
    if proc.returncode != 0:
        pytest.fail(f"{what} failed (exit {proc.returncode}): {' '.join(cmd)}\n{out[-4000:]}")
    return out


def _build_wheel(dist: Path, logs: Path) -> Path:
    _run(
        [sys.executable, "-m", "pip", "wheel", "--no-deps", "-w", str(dist), str(ROOT)],
        "building the wheel",
        cwd=dist,
        log=logs / "wheel.log",
        timeout=600,
        env=_clean_env(),
    )
    wheels = sorted(dist.glob("hptvsim-*.whl"))
    assert len(wheels) == 1, wheels
    return wheels[0]


def _check_wheel(wheel: Path) -> set[str]:
    """Only ``hptvsim`` at the top; the shipped data inside. Returns the wheel's file names."""
    with zipfile.ZipFile(wheel) as zf:
        names = set(zf.namelist())
        info = next(n.split("/")[0] for n in names if n.endswith(".dist-info/RECORD"))
        record = zf.read(f"{info}/RECORD").decode()
        entry_points = zf.read(f"{info}/entry_points.txt").decode()
        top_level = (
            zf.read(f"{info}/top_level.txt").decode().split() if f"{info}/top_level.txt" in names else []
        )
    recorded = {row[0] for row in csv.reader(io.StringIO(record)) if row}
    assert recorded == names, f"RECORD and the archive differ: {sorted(recorded ^ names)}"
    tops = {PurePosixPath(n).parts[0] for n in recorded} - {info}
    assert tops == TOP_LEVEL, f"the wheel puts {sorted(tops - TOP_LEVEL)} at the top of site-packages"
    assert set(top_level) <= TOP_LEVEL, top_level
    assert re.search(r"^hptvsim\s*=\s*hptvsim\.cli:main$", entry_points, re.MULTILINE), entry_points
    data = "hptvsim/_data"
    expected = {
        f"{data}/web/index.html",
        f"{data}/policies/index.toml",
        *(f"{data}/{p.relative_to(ROOT).as_posix()}" for p in (ROOT / "web").rglob("*") if p.is_file()),
        *(f"{data}/{p.relative_to(ROOT).as_posix()}" for p in (ROOT / "fmus").glob("*.fmu")),
        *(f"{data}/{p.relative_to(ROOT).as_posix()}" for p in (ROOT / "scenarios").rglob("*.toml")),
        *(f"{data}/scenarios/data/{p.name}" for p in (ROOT / "scenarios" / "data").glob("salish_sea.*")),
        *(f"{data}/{p.relative_to(ROOT).as_posix()}" for p in (ROOT / "policies").iterdir() if p.is_file()),
        *(f"{data}/{p.relative_to(ROOT).as_posix()}" for p in (ROOT / "configs").rglob("*.toml")),
    }
    missing = sorted(expected - names)
    assert not missing, f"the wheel lacks shipped files: {missing}"
    assert any(n.startswith(f"{data}/fmus/") and n.endswith(".fmu") for n in names)
    # the C sources compiled at first use ship inside the package; nothing compiled does
    assert any(n.endswith("_kernel.c") for n in names)
    compiled = sorted(n for n in names if n.endswith((".so", ".o", ".pyc", ".dll", ".dylib")))
    assert not compiled, f"the wheel carries build products: {compiled}"
    return names


def _install(venv: Path, wheel: Path, work: Path, logs: Path) -> Path:
    """A fresh venv with ``<wheel>[service]``; returns its site-packages."""
    _run(
        [sys.executable, "-m", "venv", str(venv)],
        "creating the venv",
        cwd=work,
        log=logs / "venv.log",
        timeout=300,
        env=_clean_env(),
    )
    py = venv / "bin" / "python"
    sp_out = subprocess.run(
        [str(py), "-c", "import site, sys; print(site.getsitepackages()[0]); print(sys.prefix)"],
        capture_output=True,
        text=True,
        check=True,
        cwd=work,
        env=_clean_env(),
    ).stdout.split("\n")
    site_packages = Path(sp_out[0])
    assert Path(sp_out[1]).resolve() == venv.resolve(), sp_out
    assert not (site_packages / "hptvsim").exists(), "the fresh venv sees hptvsim already"
    out = _run(
        [str(py), "-m", "pip", "install", f"{wheel}[service]"],
        'pip install "hptvsim[service]"',
        cwd=work,
        log=logs / "install.log",
        timeout=1200,
        env=_clean_env(),
    )
    # torch is the CPU build the extra pins exactly, a local file (pip's find-links), no CUDA
    assert re.search(r"Processing \S*/torch-2\.13\.0\+cpu-\S+\.whl", out), (
        "pip did not take torch 2.13.0+cpu from a local wheel (find-links):\n"
        + "\n".join(line for line in out.splitlines() if "torch" in line)
    )
    installed = re.findall(r"^Successfully installed (.*)$", out, re.MULTILINE)
    assert installed, out[-4000:]
    assert not re.search(r"\bnvidia-|\btriton-", installed[-1]), installed[-1]
    _run(
        [str(py), "-m", "pip", "check"],
        "pip check",
        cwd=work,
        log=logs / "pip-check.log",
        timeout=300,
        env=_clean_env(),
    )
    return site_packages


def _check_site_packages(site_packages: Path, py: Path, work: Path) -> None:
    """hptvsim's distribution puts only ``hptvsim`` at the top; the data is inside the package."""
    script = (
        "import json, importlib.metadata as m\n"
        "d = m.distribution('hptvsim')\n"
        "print(json.dumps({'version': d.version, 'torch': m.version('torch'),"
        " 'files': [str(f) for f in d.files or []]}))\n"
    )
    res = subprocess.run(
        [str(py), "-c", script], capture_output=True, text=True, check=False, cwd=work, env=_clean_env()
    )
    assert res.returncode == 0, res.stderr
    meta = json.loads(res.stdout)
    assert meta["torch"].startswith("2.13.0"), meta["torch"]
    tops = {PurePosixPath(f).parts[0] for f in meta["files"]}
    tops = {t for t in tops if not t.endswith(".dist-info") and t != ".."}  # ../../bin/hptvsim
    assert tops == TOP_LEVEL, f"hptvsim installs {sorted(tops - TOP_LEVEL)} at the top of site-packages"
    data = site_packages / "hptvsim" / "_data"
    assert (data / "web" / "index.html").is_file()
    assert sorted(p.name for p in (data / "scenarios").glob("*.toml")) == sorted(
        p.name for p in (ROOT / "scenarios").glob("*.toml")
    )
    assert (data / "policies" / "index.toml").is_file() and any((data / "policies").glob("*.zip"))
    assert sorted(p.name for p in (data / "fmus").glob("*.fmu")) == sorted(
        p.name for p in (ROOT / "fmus").glob("*.fmu")
    )
    # the shipped-folder names a checkout keeps at its top must not be what the copy finds
    for name in ("scenarios", "policies", "configs", "web", "fmus", "tests", "services", "service"):
        assert not (site_packages / name).exists(), f"site-packages holds a top-level {name!r}"


def _package_files(site_packages: Path) -> set[str]:
    root = site_packages / "hptvsim"
    return {
        p.relative_to(root).as_posix()
        for p in root.rglob("*")
        if p.is_file() and "__pycache__" not in p.parts and p.suffix != ".pyc"
    }


class _Serve:
    """``<venv>/bin/hptvsim serve`` started from an empty directory."""

    def __init__(self, venv: Path, cwd: Path, env: dict[str, str], log: Path) -> None:
        self.log = log
        self._fh = log.open("w")
        self.process = subprocess.Popen(
            [str(venv / "bin" / "hptvsim"), "serve", "--port", "0", "--viser-port", "0"],
            cwd=cwd,
            env=env,
            stdout=self._fh,
            stderr=subprocess.STDOUT,
            start_new_session=True,  # its own process group, so its workers can be found and ended
        )
        self.pgid = self.process.pid

    def output(self) -> str:
        return self.log.read_text(errors="replace")

    def urls(self, timeout: float) -> dict[str, str]:
        """Wait until it prints its URLs and ``/healthz`` answers; the printed URLs by label."""
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            if self.process.poll() is not None:
                pytest.fail(f"hptvsim serve exited with {self.process.returncode}:\n{self.output()[-4000:]}")
            out = self.output()
            found = dict(
                re.findall(r"^\s+(dashboard|API|health|live view):\s+(http://\S+)", out, re.MULTILINE)
            )
            if {"dashboard", "API", "health", "live view"} <= found.keys():
                urls = {k: v.replace("//localhost:", "//127.0.0.1:") for k, v in found.items()}
                with contextlib.suppress(httpx.HTTPError):
                    if httpx.get(urls["health"], timeout=5.0).status_code == 200:
                        return urls
            time.sleep(0.2)
        pytest.fail(f"hptvsim serve did not answer in {timeout:.0f} s:\n{self.output()[-4000:]}")

    def terminate(self, timeout: float) -> float:
        """SIGTERM; the seconds until it exited (fails if it did not within ``timeout``)."""
        t0 = time.monotonic()
        self.process.send_signal(signal.SIGTERM)
        try:
            self.process.wait(timeout)
        except subprocess.TimeoutExpired:
            pytest.fail(f"hptvsim serve still runs {timeout:.0f} s after SIGTERM:\n{self.output()[-4000:]}")
        return time.monotonic() - t0

    def group_alive(self) -> bool:
        try:
            os.killpg(self.pgid, 0)
        except ProcessLookupError:
            return False
        return True

    def cleanup(self) -> None:
        """Whatever of it still runs (after a failure): SIGKILL its process group."""
        if self.process.poll() is None or self.group_alive():
            with contextlib.suppress(ProcessLookupError):
                os.killpg(self.pgid, signal.SIGKILL)
            with contextlib.suppress(subprocess.TimeoutExpired):
                self.process.wait(10)
        self._fh.close()


def _check_dashboard(http: httpx.Client, url: str) -> None:
    page = http.get(url)
    assert page.status_code == 200 and "text/html" in page.headers["content-type"], page.text[:500]
    assert "<title>hptvsim dashboard</title>" in page.text, page.text[:500]
    refs = re.findall(r"""(?:href|src)=["']([^"':#]+\.(?:js|css))["']""", page.text)
    assert any(r.endswith(".js") for r in refs) and any(r.endswith(".css") for r in refs), refs
    todo, seen = [str(httpx.URL(url).join(r)) for r in refs], set()
    while todo:  # the files the page references, and the ES modules they import
        file_url = todo.pop()
        if file_url in seen:
            continue
        seen.add(file_url)
        res = http.get(file_url)
        assert res.status_code == 200 and res.content, f"{file_url}: {res.status_code}"
        if file_url.endswith(".js"):
            assert "javascript" in res.headers["content-type"], (file_url, res.headers["content-type"])
            for ref in re.findall(r"""\bfrom\s+["'](\.{1,2}/[^"']+)["']""", res.text):
                todo.append(str(httpx.URL(file_url).join(ref)))
        else:
            assert "text/css" in res.headers["content-type"], (file_url, res.headers["content-type"])
    assert len(seen) >= 3, seen


def _run_episode(api: httpx.Client, body: dict[str, Any], timeout: float) -> dict[str, Any]:
    res = api.post("/episodes", json=body)
    assert res.status_code == 201, res.text
    episode_id = res.json()["id"]
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        ep: dict[str, Any] = api.get(f"/episodes/{episode_id}").json()
        if ep["status"] in FINAL:
            assert ep["status"] == "finished", ep
            assert isinstance(ep["summary"], dict) and ep["summary"], ep
            assert 0 < ep["steps"] <= body["max_steps"], ep
            return ep
        time.sleep(0.25)
    pytest.fail(f"episode {body} did not end in {timeout:.0f} s: {api.get(f'/episodes/{episode_id}').text}")


@pytest.mark.slow
@pytest.mark.timeout(1800)
def test_installed_wheel_serves_an_episode(tmp_path: Path) -> None:
    t0 = time.monotonic()
    assert ROOT not in tmp_path.resolve().parents and tmp_path.resolve() != ROOT
    logs = tmp_path / "logs"
    dist, work, data, cache = (tmp_path / n for n in ("dist", "cwd", "data", "cache"))
    for d in (logs, dist, work, cache):
        d.mkdir()
    venv = tmp_path / "venv"

    wheel = _build_wheel(dist, logs)
    _check_wheel(wheel)
    t_built = time.monotonic() - t0
    site_packages = _install(venv, wheel, work, logs)
    assert ROOT not in site_packages.resolve().parents
    _check_site_packages(site_packages, venv / "bin" / "python", work)
    before = _package_files(site_packages)
    t_installed = time.monotonic() - t0

    env = _clean_env(HPTVSIM_DATA_DIR=str(data), XDG_CACHE_HOME=str(cache))
    server = _Serve(venv, work, env, logs / "serve.log")
    try:
        urls = server.urls(timeout=180)
        t_up = time.monotonic() - t0
        with httpx.Client(timeout=60.0) as http, httpx.Client(base_url=urls["API"], timeout=60.0) as api:
            _check_dashboard(http, urls["dashboard"])

            scenarios = {s["name"] for s in api.get("/scenarios").json()}
            shipped = {p.stem for p in (ROOT / "scenarios").glob("*.toml")}
            assert shipped <= scenarios, f"missing scenarios: {sorted(shipped - scenarios)}"
            policies = {p["name"] for p in api.get("/policies").json()}
            assert policies >= TRAINED_POLICIES, f"missing policies: {sorted(TRAINED_POLICIES - policies)}"

            live = http.get(urls["live view"])
            assert live.status_code == 200 and "<title>Viser</title>" in live.text, live.text[:500]

            png = api.get("/scenarios/salish_sea/map.png")  # a GeoTIFF read by rasterio, drawn by matplotlib
            assert png.status_code == 200 and png.content.startswith(b"\x89PNG"), png.text[:500]

            tiny = _run_episode(api, {"scenario": "goto_tiny", "max_steps": 20}, timeout=300)
            csv_rows = api.get(f"/episodes/{tiny['id']}/trajectory", params={"format": "csv"})
            assert csv_rows.status_code == 200 and csv_rows.text.count("\n") > 1, csv_rows.text[:500]
            parquet = api.get(f"/episodes/{tiny['id']}/trajectory", params={"format": "parquet"})
            assert parquet.status_code == 200 and parquet.content[:4] == b"PAR1", parquet.text[:500]
            if tiny["has_recording"]:
                rrd = api.get(f"/episodes/{tiny['id']}/recording")
                assert rrd.status_code == 200 and rrd.content, rrd.text[:500]

            # the default policies on "source": the shipped MAISAC networks, run by torch and SB3
            source = _run_episode(api, {"scenario": "source", "max_steps": 20}, timeout=600)
            assert set(source["policies"].values()) & {"maisac-pursuers", "maisac-evader"}, source
        took = server.terminate(timeout=20)
        deadline = time.monotonic() + 10
        while server.group_alive() and time.monotonic() < deadline:
            time.sleep(0.1)
        assert not server.group_alive(), "worker processes outlived the service"
    finally:
        server.cleanup()
    out = server.output()
    assert server.process.returncode in (0, -signal.SIGTERM), out[-4000:]
    assert "Traceback" not in out, out[-8000:]
    assert took < 20

    # nothing written into the installed package (C kernels go to the user's cache) or the cwd
    written = sorted(_package_files(site_packages) - before)
    assert not written, f"the service wrote into site-packages/hptvsim: {written}"
    assert not any(work.iterdir()), f"the service wrote into its working directory: {list(work.iterdir())}"
    kernels = sorted(p.name for p in (cache / "hptvsim").glob("*.so")) if (cache / "hptvsim").is_dir() else []
    assert kernels, f"no C kernel compiled into $XDG_CACHE_HOME/hptvsim ({cache})"
    shutil.rmtree(venv, ignore_errors=True)  # 1.5 GB; pytest keeps its last three tmp folders
    print(
        f"\n{wheel.name}: built at {t_built:.0f} s, installed at {t_installed:.0f} s, serving at "
        f"{t_up:.0f} s, done at {time.monotonic() - t0:.0f} s; stopped in {took:.1f} s after SIGTERM; "
        f"C kernels in the user cache: {kernels}"
    )
