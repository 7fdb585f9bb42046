"""An FMU loaded once (:class:`FmuModel`): model description read, archive extracted, instances made.

:func:`load_model` loads each ``.fmu`` once per process. The capability flags are read: an FMU
that can be instantiated only once per process refuses a second instance with a clear error.
:meth:`FmuModel.instantiate` makes an FMI 2.0 (:class:`~hptvsim.cosim.fmi2.Fmu2Instance`) or FMI
3.0 (:class:`~hptvsim.cosim.fmi3.Fmu3Instance`) instance, so this module sits above both; they
know their model through :class:`~hptvsim.cosim.fmi.LoadedFmu`.
"""

from __future__ import annotations

import os
import shutil
import tempfile
import threading
import weakref
import zipfile
from collections.abc import Iterable
from pathlib import Path
from typing import Any, Final

import fmpy
from fmpy import extract, read_model_description

from hptvsim._process import pid_alive
from hptvsim.cosim.fmi import FmuError, FmuLoadError, FmuVariableError, Variable, _parse_start
from hptvsim.cosim.fmi2 import Fmu2Instance

__all__ = ["FmuModel", "load_model"]


_EXTRACT_PREFIX: Final = "hptvsim-fmu-"
"""Temporary folders of extracted FMUs: ``hptvsim-fmu-<pid namespace>-<pid>-<model identifier>-<random>``."""

_orphans_swept = {"done": False}


def _pid_namespace() -> str:
    """This process's pid namespace (the inode of ``/proc/self/ns/pid``; ``0`` where there is none)."""
    try:
        return str(os.stat("/proc/self/ns/pid").st_ino)
    except OSError:
        return "0"


def _extract_prefix() -> str:
    return f"{_EXTRACT_PREFIX}{_pid_namespace()}-{os.getpid()}-"


def _remove_orphaned_extractions() -> None:
    """Remove (once per process) the extracted FMUs of processes that are gone.

    A process removes its own at exit or when the FMU is collected; one that was killed
    (SIGKILL, a timed-out service worker) cannot, and left about 250 kB each in the
    temporary folder. The owner's pid namespace and pid are in the folder's name: only folders
    of this pid namespace are looked at (a temporary folder shared with a container holds pids
    this process cannot see), and a folder whose pid is alive (maybe reused by another process)
    is left alone. POSIX only.
    """
    if _orphans_swept["done"] or os.name != "posix":
        return
    _orphans_swept["done"] = True
    ours = f"{_EXTRACT_PREFIX}{_pid_namespace()}-"
    for folder in Path(tempfile.gettempdir()).glob(f"{ours}*"):
        pid = folder.name[len(ours) :].split("-", 1)[0]
        if pid.isdigit() and int(pid) != os.getpid() and not pid_alive(int(pid)):
            shutil.rmtree(folder, ignore_errors=True)


def _binary_name(fmi_version: str, identifier: str) -> str:
    """The archive member of the FMU's binary for this platform (FMI 2.0 and 3.0 layouts)."""
    folder = fmpy.platform_tuple if fmi_version == "3.0" else fmpy.platform
    return f"binaries/{folder}/{identifier}{fmpy.sharedLibraryExtension}"


def _read_description(path: Path) -> Any:
    """Read ``path``'s model description, refusing what cannot be run here in one line.

    Raises:
        FmuLoadError: Not a zip archive, no or a malformed ``modelDescription.xml``, not FMI 2.0
            or 3.0 Co-Simulation, or no binary for this platform.
    """
    try:
        with zipfile.ZipFile(path) as zf:
            members = set(zf.namelist())
    except (zipfile.BadZipFile, OSError) as exc:
        raise FmuLoadError(path, f"not an FMU: not a zip archive ({exc})") from None
    if "modelDescription.xml" not in members:
        raise FmuLoadError(path, "not an FMU: no modelDescription.xml at the root of the archive")
    try:
        md = read_model_description(str(path))
    except Exception as exc:  # FMPy and lxml raise many kinds for a broken XML
        raise FmuLoadError(path, f"malformed modelDescription.xml: {exc}") from None
    if md.fmiVersion not in ("2.0", "3.0") or md.coSimulation is None:
        raise FmuLoadError(
            path,
            "an FMI 2.0 or 3.0 Co-Simulation FMU is required "
            f"(got FMI {md.fmiVersion}{'' if md.coSimulation else ' without Co-Simulation'})",
        )
    binary = _binary_name(md.fmiVersion, md.coSimulation.modelIdentifier)
    if binary not in members:
        present = sorted(m for m in members if m.startswith("binaries/") and not m.endswith("/"))
        shown = ", ".join(present[:6]) + (f" and {len(present) - 6} more" if len(present) > 6 else "")
        raise FmuLoadError(
            path, f"no binary for this platform (looked for {binary}; the FMU's binaries: {shown or 'none'})"
        )
    return md


class FmuModel:
    """An FMU loaded once: model description read, archive extracted (removed at exit).

    Args:
        path: The ``.fmu`` file.

    Raises:
        FileNotFoundError: ``path`` does not exist.
        FmuLoadError: The file is not an FMI 2.0 or 3.0 Co-Simulation FMU that runs here: not a
            zip archive, no or a malformed ``modelDescription.xml``, another FMI version or
            interface, or no binary for this platform (one line naming the file and the problem).
    """

    def __init__(self, path: str | Path) -> None:
        self.path = Path(path)
        if not self.path.is_file():
            raise FileNotFoundError(f"FMU not found: {self.path}")
        self.model_description = _read_description(self.path)
        md = self.model_description
        self.fmi_version: str = md.fmiVersion
        cs = md.coSimulation
        self.identifier: str = cs.modelIdentifier
        self.guid: str = md.guid
        self.can_handle_variable_step = bool(cs.canHandleVariableCommunicationStepSize)
        self.once_per_process = bool(cs.canBeInstantiatedOnlyOncePerProcess)
        self.can_get_set_state = bool(cs.canGetAndSetFMUstate)
        self.unit_definitions: dict[str, Any] = {u.name: u for u in md.unitDefinitions}
        self.live: dict[int, str] = {}  # id -> instance name of the instances not yet freed
        _remove_orphaned_extractions()
        self._tmp = tempfile.mkdtemp(prefix=f"{_extract_prefix()}{self.identifier}-")
        self.unzip_dir = Path(extract(str(self.path), unzipdir=self._tmp))
        weakref.finalize(self, shutil.rmtree, self._tmp, True)
        self.variables: dict[str, Variable] = {}
        for v in md.modelVariables:
            dt = v.declaredType
            shape = tuple(int(d) for d in getattr(v, "shape", None) or ())
            self.variables[v.name] = Variable(
                name=v.name,
                value_reference=int(v.valueReference),
                type=v.type,
                causality=v.causality,
                variability=v.variability,
                start=_parse_start(v.type, v.start),
                unit=getattr(v, "unit", None) or (dt.unit if dt is not None else None),
                description=v.description or "",
                display_unit=getattr(v, "displayUnit", None) or (dt.displayUnit if dt is not None else None),
                declared_type=dt.name if dt is not None else None,
                items=tuple((i.name, int(i.value)) for i in (dt.items if dt is not None else []) or []),
                kind=f"{v.type} array" if shape else "",
                dimensions=shape,
            )

    def names(self, causality: str | None = None) -> list[str]:
        """Return variable names, optionally only those of one causality."""
        return [n for n, v in self.variables.items() if causality is None or v.causality == causality]

    def variable(self, name: str, *, causality: Iterable[str] | None = None) -> Variable:
        """Return a variable by name.

        Raises:
            FmuVariableError: Unknown name, or not of one of the given causalities; the
                message lists the valid names.
        """
        allowed = set(causality) if causality is not None else None
        v = self.variables.get(name)
        if v is None or (allowed is not None and v.causality not in allowed):
            valid = [n for n, x in self.variables.items() if allowed is None or x.causality in allowed]
            kinds = "/".join(sorted(allowed)) if allowed else "variable"
            raise FmuVariableError(
                f"{self.identifier} has no {kinds} named {name!r}; valid names: {', '.join(valid)}"
            )
        return v

    def instantiate(self, name: str | None = None, *, logging_on: bool = False) -> Fmu2Instance:
        """Create an instance (see :class:`Fmu2Instance`).

        Raises:
            FmuError: The FMU can be instantiated only once per process and already is, or
                instantiation failed.
            FmuLoadError: Its binary does not load (names the file and why).
        """
        name = name or self.identifier
        if self.once_per_process and self.live:
            other = next(iter(self.live.values()))
            raise FmuError(
                name,
                "fmi2Instantiate",
                3,
                [
                    f"{self.identifier} can be instantiated only once per process "
                    f"(canBeInstantiatedOnlyOncePerProcess) and component '{other}' holds it; "
                    "use one instance of it, or free the other first"
                ],
            )
        if self.fmi_version == "3.0":
            from hptvsim.cosim.fmi3 import Fmu3Instance

            return Fmu3Instance(self, name, logging_on=logging_on)  # type: ignore[return-value]  # same interface
        return Fmu2Instance(self, name, logging_on=logging_on)


_MODEL_CACHE: dict[tuple[str, int, int], FmuModel] = {}
_MODEL_CACHE_LOCK = threading.Lock()


def load_model(path: str | Path) -> FmuModel:
    """Return the :class:`FmuModel` of ``path``, loading (reading, extracting) it once per process.

    The cache key is the resolved path with the file's size and modification time, so an FMU
    rebuilt in place is loaded afresh.

    Raises:
        FileNotFoundError: ``path`` does not exist.
        FmuLoadError: The file cannot be run here (see :class:`FmuModel`).
    """
    resolved = Path(path).resolve()
    if not resolved.is_file():
        raise FileNotFoundError(f"FMU not found: {path}")
    st = resolved.stat()
    key = (str(resolved), st.st_size, st.st_mtime_ns)
    with _MODEL_CACHE_LOCK:
        model = _MODEL_CACHE.get(key)
        if model is None:
            model = FmuModel(resolved)
            _MODEL_CACHE[key] = model
    return model
