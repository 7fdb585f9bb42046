"""The batched backend: B sub-environments x N vehicles stepped by the FMU binaries' batch entries.

The vehicle FMUs' shared libraries export, besides FMI 2.0, ``hptvsim_advance_batch`` and
``hptvsim_output_batch`` (``hptvsim/fmu/templates/fmi2_cs.c``): the very functions that
``fmi2DoStep`` and ``fmi2GetReal`` run for one instance (RK4 in ``ceil(H / h_max)`` equal
sub-steps with the inputs held, then the output function), looped over arrays of vehicles.
So this backend computes exactly what the FMUs compute, bit for bit, from the same binary,
without one FMI call per vehicle. Vehicles are grouped by type: one call per type per step
(per thread).

Layout: per type, row-major arrays ``x (B, n, 8)``, ``w (B, n, 7)``, ``p (B, n, 35)``,
``y (B, n, 9)`` with ``n`` the vehicles of that type per sub-environment. With one vehicle
type the caller's :attr:`~hptvsim.cosim.interface.VehicleSystem.inputs` and
:attr:`~hptvsim.cosim.interface.VehicleSystem.outputs` *are* ``w`` and ``y`` (no copies);
with several types one gather and one scatter per type and step move the values.

Threads: big batches are split into row ranges stepped in parallel (``ctypes`` releases the
GIL during the foreign call). Each vehicle's numbers depend only on its own row, so the split
does not change results.

Where the time goes (``hptvsim bench cosim``, ``h_max = 0.05`` s): at B = 1024 the C step is
about 95 % of a step's cost, and about half of the C step is libm calls (per RK4 step 12
``tanh`` and 11 ``sin``/``cos``). A structure-of-arrays variant of the generated step (GCC
vector extensions, 2, 4 or 8 lanes, libm called lane by lane to stay bit-identical) was
measured at 0.88-1.08x of the scalar step, since every libm call clobbers the vector
registers; it is therefore not used. Two threads give about 1.9x at B = 1024.

Errors: non-finite inputs, poses or parameters are rejected before anything changes (the
message names the sub-environment, the vehicle and the value); parameter sets are checked by
the FMU's own check (bounds, ``v_min <= v_max``, positive definite mass matrix). A state that
becomes non-finite raises :class:`NonFiniteStateError` naming the sub-environments; the others
have stepped normally, and :meth:`BatchedVehicleSystem.step` is refused until the failed ones
are reset.
"""

from __future__ import annotations

import ctypes
import io
import os
from collections.abc import Mapping, Sequence
from concurrent.futures import Future, ThreadPoolExecutor
from dataclasses import dataclass
from pathlib import Path
from typing import Any, ClassVar, Final

import numpy as np
import numpy.typing as npt

from hptvsim.cosim.fmi import F64Array
from hptvsim.cosim.fmu_model import FmuModel, load_model
from hptvsim.cosim.interface import PLANAR_LAYOUT, Layout, SystemSpec, VehicleSystem
from hptvsim.cosim.orchestrator import SimulationFailedError
from hptvsim.cosim.vehicles import ExternalVehicleType
from hptvsim.dynamics import ParameterError, VehicleType

__all__ = ["BatchedSnapshot", "BatchedVehicleSystem", "NonFiniteStateError", "VehicleLibrary"]

NX: Final = PLANAR_LAYOUT.nx
NW: Final = len(PLANAR_LAYOUT.input_names)
NP: Final = len(PLANAR_LAYOUT.parameter_names)
NY: Final = len(PLANAR_LAYOUT.output_names)
SPLIT_MIN_WORK: Final = 2048
"""Vehicle-substeps per step below which a step stays on one thread (the hand-off costs tens of
microseconds, about 200 vehicle-substeps of work)."""


class NonFiniteStateError(SimulationFailedError):
    """The state of some vehicles became non-finite; those sub-environments must be reset.

    Attributes:
        env_ids: The failed sub-environments.
    """

    def __init__(self, message: str, env_ids: Sequence[int]) -> None:
        super().__init__(message)
        self.env_ids = tuple(env_ids)


class VehicleLibrary:
    """The batch entry points of one vehicle FMU's shared library (loaded once per process).

    Attributes:
        model: The FMU (model description, extracted files).
        start_parameters: The parameter vector ``p`` of the FMU's start values (``NP`` values).
    """

    _cache: ClassVar[dict[str, VehicleLibrary]] = {}

    def __init__(self, model: FmuModel, layout: Layout = PLANAR_LAYOUT) -> None:
        import fmpy

        self.model = model
        self.layout = layout
        binary = (
            model.unzip_dir / "binaries" / fmpy.platform / f"{model.identifier}{fmpy.sharedLibraryExtension}"
        )
        self.dll = ctypes.CDLL(str(binary))
        try:
            self.advance = self.dll.hptvsim_advance_batch
            self.output = self.dll.hptvsim_output_batch
            self.check = self.dll.hptvsim_check_params_batch
            dims = self.dll.hptvsim_dimensions
        except AttributeError as exc:
            raise RuntimeError(
                f"{model.path} has no hptvsim batch entry points; rebuild it with `hptvsim fmu build`"
            ) from exc
        vp = ctypes.c_void_p
        self.advance.argtypes = [ctypes.c_int, vp, vp, vp, ctypes.c_double, ctypes.c_double]
        self.advance.restype = ctypes.c_int
        self.output.argtypes = [ctypes.c_int, vp, vp, vp, vp]
        self.output.restype = None
        self.check.argtypes = [ctypes.c_int, vp, ctypes.c_char_p, ctypes.c_int]
        self.check.restype = ctypes.c_int
        sizes = [ctypes.c_int() for _ in range(4)]
        dims(*[ctypes.byref(s) for s in sizes])
        got = tuple(s.value for s in sizes)
        want = (layout.nx, len(layout.input_names), len(layout.parameter_names), len(layout.output_names))
        if got != want:
            raise RuntimeError(
                f"{model.path} has dimensions (nx, nw, np, ny) = {got}, the {layout.dof}-DOF model has "
                f"{want}; rebuild it with `hptvsim fmu build`"
            )
        start = []
        for name in layout.parameter_names:
            value = model.variable(name, causality=("parameter",)).start
            if value is None:
                raise RuntimeError(f"{model.path}: parameter {name!r} has no start value")
            start.append(value)
        self.start_parameters: F64Array = np.array(start, dtype=np.float64)

    @classmethod
    def for_type(cls, vehicle_type: str) -> VehicleLibrary:
        """The library of a vehicle type's shipped FMU (:func:`hptvsim.fmu.fmu_path`)."""
        from hptvsim.fmu import fmu_path

        return cls.for_path(fmu_path(vehicle_type))

    @classmethod
    def for_vehicle(cls, vehicle: VehicleType, layout: Layout = PLANAR_LAYOUT) -> VehicleLibrary:
        """The library of a vehicle type's FMU: :func:`hptvsim.fmu.fmu_for`, or the 6-DOF one.

        For ``layout.dof = 6`` it is the shipped 6-DOF FMU of a built-in type.
        """
        from hptvsim.fmu import fmu_for, fmu_path

        path = fmu_path(vehicle.name, dof=6) if layout.dof == 6 else fmu_for(vehicle)
        return cls.for_path(path, layout)

    @classmethod
    def for_path(cls, path: Path, layout: Layout = PLANAR_LAYOUT) -> VehicleLibrary:
        """The library of a vehicle FMU file, loaded once per process."""
        model = load_model(path)
        key = str(model.unzip_dir)
        lib = cls._cache.get(key)
        if lib is None:
            lib = cls(model, layout)
            cls._cache[key] = lib
        return lib

    def check_rows(self, p: F64Array) -> tuple[int, str] | None:
        """Check parameter rows ``p (rows, NP)``; returns ``(row, why)`` of the first bad one."""
        rows = np.ascontiguousarray(p, dtype=np.float64).reshape(-1, len(self.layout.parameter_names))
        why = ctypes.create_string_buffer(600)
        bad = self.check(len(rows), rows.ctypes.data, why, len(why))
        if bad == 0:
            return None
        return bad - 1, why.value.decode("utf-8", "replace")


@dataclass
class _Group:
    """The vehicles of one type in every sub-environment."""

    type: str
    lib: VehicleLibrary
    vehicles: npt.NDArray[np.intp]  # their indices among the N vehicles
    sel: slice | npt.NDArray[np.intp]  # the same, as a slice when contiguous
    base_p: F64Array  # (n, NP): start values with the spec's overrides
    x: F64Array  # (B, n, NX)
    w: F64Array  # (B, n, NW)
    p: F64Array  # (B, n, NP)
    y: F64Array  # (B, n, NY)
    alias: bool  # w and y are the caller's inputs and outputs

    @property
    def n(self) -> int:
        return len(self.vehicles)


_Task = tuple[Any, Any, int, int, int, int, int, int, int]  # adv, out, rows, x, w, p, y, group, row0


@dataclass(frozen=True)
class BatchedSnapshot:
    """A snapshot of a :class:`BatchedVehicleSystem` (plain arrays; :meth:`to_bytes` serialises)."""

    arrays: dict[str, F64Array]

    def to_bytes(self) -> bytes:
        """Serialise (``numpy.savez``), e.g. to survive a restart."""
        buf = io.BytesIO()
        np.savez(buf, **self.arrays)  # type: ignore[arg-type]  # numpy's stub wants Any; values are arrays
        return buf.getvalue()

    @classmethod
    def from_bytes(cls, data: bytes) -> BatchedSnapshot:
        """Read bytes from :meth:`to_bytes`."""
        with np.load(io.BytesIO(data), allow_pickle=False) as z:
            return cls(arrays={k: np.array(z[k]) for k in z.files})


class BatchedVehicleSystem(VehicleSystem):
    """B sub-environments x N vehicles stepped by the FMU binaries' batch entry points.

    Same interface and the same numbers as :class:`~hptvsim.cosim.system.FmuVehicleSystem`;
    see the module docstring for layout, threads and errors.

    Args:
        spec: The vehicles and step settings.
        num_envs: B.
        threads: Threads that share a big step (default: ``min(2, os.cpu_count())``).
    """

    def __init__(self, spec: SystemSpec, num_envs: int = 1, *, threads: int | None = None) -> None:
        super().__init__(spec, num_envs)
        n_all = spec.num_vehicles
        B = self.num_envs
        self.threads = max(1, int(threads if threads is not None else min(2, os.cpu_count() or 1)))
        layout = spec.layout
        self._nx, self._nw = layout.nx, len(layout.input_names)
        self._np, self._ny = len(layout.parameter_names), len(layout.output_names)
        NX, NW, NY = self._nx, self._nw, self._ny
        self._inputs = np.zeros((B, n_all, NW))
        self._outputs = np.zeros((B, n_all, NY))
        self._failed = np.zeros(B, dtype=bool)
        self._pool: ThreadPoolExecutor | None = None
        external = [v.name for v in spec.vehicles if isinstance(v.vehicle, ExternalVehicleType)]
        if external:
            raise ValueError(
                f"vehicle(s) {', '.join(external)} run an external FMU, which only the FMU backend "
                "runs (backend='fmu'); the batched backend steps the generated C of hptvsim's model"
            )
        types = list(dict.fromkeys(v.vehicle for v in spec.vehicles))
        self._groups: list[_Group] = []
        for vt in types:
            t = vt.name
            lib = VehicleLibrary.for_vehicle(vt, layout)
            vehicles = np.array([k for k, v in enumerate(spec.vehicles) if v.vehicle == vt], dtype=np.intp)
            n = len(vehicles)
            contiguous = bool(np.all(np.diff(vehicles) == 1))
            sel: slice | npt.NDArray[np.intp] = (
                slice(int(vehicles[0]), int(vehicles[-1]) + 1) if contiguous else vehicles
            )
            base_p = np.tile(lib.start_parameters, (n, 1))
            for i, k in enumerate(vehicles):
                for name, value in spec.vehicles[k].parameters.items():
                    base_p[i, layout.parameter_names.index(name)] = value
            bad = lib.check_rows(base_p)
            if bad is not None:
                raise ParameterError(f"vehicle {spec.vehicles[vehicles[bad[0]]].name!r}: {bad[1]}")
            alias = len(types) == 1
            self._groups.append(
                _Group(
                    type=t,
                    lib=lib,
                    vehicles=vehicles,
                    sel=sel,
                    base_p=base_p,
                    x=np.zeros((B, n, NX)),
                    w=self.inputs if alias else np.zeros((B, n, NW)),
                    p=np.tile(base_p, (B, 1, 1)),
                    y=self.outputs if alias else np.zeros((B, n, NY)),
                    alias=alias,
                )
            )
        self._plan()
        self.reset()

    # -- planning -----------------------------------------------------------------------------------

    def _tasks_for(self, gi: int, row0: int, rows: int) -> _Task:
        g = self._groups[gi]
        return (
            g.lib.advance,
            g.lib.output,
            rows,
            g.x.ctypes.data + row0 * self._nx * 8,
            g.w.ctypes.data + row0 * self._nw * 8,
            g.p.ctypes.data + row0 * self._np * 8,
            g.y.ctypes.data + row0 * self._ny * 8,
            gi,
            row0,
        )

    def _plan(self) -> None:
        """Fix the calls of a step: per thread, a list of (function, row range) tasks."""
        work = sum(g.n for g in self._groups) * self.num_envs * self.spec.substeps
        parts = self.threads if work >= SPLIT_MIN_WORK else 1
        self._chunks: list[list[_Task]] = [[] for _ in range(parts)]
        for gi, g in enumerate(self._groups):
            rows = self.num_envs * g.n
            bounds = [round(rows * j / parts) for j in range(parts + 1)]
            for j in range(parts):
                if bounds[j + 1] > bounds[j]:
                    self._chunks[j].append(self._tasks_for(gi, bounds[j], bounds[j + 1] - bounds[j]))
        if parts > 1 and self._pool is None:
            self._pool = ThreadPoolExecutor(max_workers=parts - 1, thread_name_prefix="hptvsim-batched")

    @staticmethod
    def _run(tasks: list[_Task], H: float, h_max: float) -> list[tuple[int, int]]:
        bad: list[tuple[int, int]] = []
        for adv, out, rows, x, w, p, y, gi, row0 in tasks:
            first_bad = adv(rows, x, w, p, H, h_max)
            out(rows, x, w, p, y)
            if first_bad:
                bad.append((gi, row0 + first_bad - 1))
        return bad

    # -- stepping -------------------------------------------------------------------------------------

    def step(self) -> F64Array:
        """See :meth:`VehicleSystem.step`.

        Raises:
            SimulationPausedError: The system is paused.
            SimulationFailedError: Sub-environments that failed earlier have not been reset.
            ValueError: A non-finite input (nothing is advanced).
            NonFiniteStateError: A vehicle's state became non-finite in this step.
        """
        self._check_can_step()
        if self._failed.any():
            failed = np.flatnonzero(self._failed).tolist()
            raise SimulationFailedError(
                f"sub-environments {failed} failed in an earlier step; reset them first"
            )
        self._check_inputs()
        groups = self._groups
        for g in groups:
            if not g.alias:
                g.w[...] = self.inputs[:, g.sel]
        H = self.spec.step_size
        h_max = self.spec.h_max
        chunks = self._chunks
        if len(chunks) == 1:
            bad = self._run(chunks[0], H, h_max)
        else:
            assert self._pool is not None
            futures: list[Future[list[tuple[int, int]]]] = [
                self._pool.submit(self._run, c, H, h_max) for c in chunks[1:]
            ]
            bad = self._run(chunks[0], H, h_max)
            for f in futures:
                bad += f.result()
        for g in groups:
            if not g.alias:
                self.outputs[:, g.sel] = g.y
        self.time += H
        if bad:
            self._fail(bad)
        return self.outputs

    def _fail(self, bad: list[tuple[int, int]]) -> None:
        envs: set[int] = set()
        for g in self._groups:
            rows = ~np.all(np.isfinite(g.x), axis=2)  # (B, n)
            envs.update(np.flatnonzero(np.any(rows, axis=1)).tolist())
        gi, row = bad[0]
        g = self._groups[gi]
        b, i = divmod(row, g.n)
        name = self.spec.vehicles[g.vehicles[i]].name
        self._failed[sorted(envs)] = True
        raise NonFiniteStateError(
            f"env {b}, vehicle {name!r}: the state became non-finite in the step to "
            f"t = {self.time[b]:.17g} s; reset sub-environments {sorted(envs)}",
            sorted(envs),
        )

    @property
    def parts(self) -> int:
        """Row ranges a step is split into (threads used per step)."""
        return len(self._chunks)

    @property
    def failed_envs(self) -> list[int]:
        """Sub-environments whose state became non-finite and that have not been reset."""
        return np.flatnonzero(self._failed).tolist()

    # -- resets and parameters ------------------------------------------------------------------------

    @staticmethod
    def _runs(idx: npt.NDArray[np.intp]) -> list[tuple[int, int]]:
        """Split sorted env indices into runs ``(start, count)`` of consecutive envs."""
        runs: list[tuple[int, int]] = []
        values = idx.tolist()
        if not values:
            return runs
        start = prev = values[0]
        for v in values[1:]:
            if v != prev + 1:
                runs.append((start, prev - start + 1))
                start = v
            prev = v
        runs.append((start, prev - start + 1))
        return runs

    def _candidate_p(
        self, idx: npt.NDArray[np.intp], params: Mapping[str, F64Array], *, from_base: bool
    ) -> list[F64Array]:
        """New parameter rows ``(k, n, NP)`` per group, checked by the FMU's own check."""
        out = []
        for g in self._groups:
            p = np.tile(g.base_p, (len(idx), 1, 1)) if from_base else g.p[idx].copy()
            names = self.spec.layout.parameter_names
            for name, arr in params.items():
                p[:, :, names.index(name)] = arr[:, g.vehicles]
            bad = g.lib.check_rows(p)
            if bad is not None:
                b, i = divmod(bad[0], g.n)
                name = self.spec.vehicles[g.vehicles[i]].name
                raise ParameterError(f"env {int(idx[b])}, vehicle {name!r}: {bad[1]}")
            out.append(p)
        return out

    def reset(
        self,
        env_ids: Sequence[int] | npt.ArrayLike | None = None,
        *,
        poses: npt.ArrayLike | None = None,
        velocities: npt.ArrayLike | None = None,
        parameters: Mapping[str, npt.ArrayLike] | None = None,
    ) -> F64Array:
        """See :meth:`VehicleSystem.reset` (everything is checked before anything changes)."""
        ids = self._env_index(env_ids)
        order = np.argsort(ids, kind="stable")
        idx = ids[order]
        k = len(idx)
        size = self.spec.layout.pose_size  # 3: x_0, y_0, psi_0 then u_0, v_0, r_0; 6: 6 and 6
        init = np.zeros((k, self.num_vehicles, 2 * size))
        if poses is not None:
            init[:, :, 0:size] = self._per_vehicle("poses", poses, k, size)[order]
        if velocities is not None:
            init[:, :, size : 2 * size] = self._per_vehicle("velocities", velocities, k, size)[order]
        params = {n: a[order] for n, a in self._parameter_arrays(parameters, k).items()}
        new_p = self._candidate_p(idx, params, from_base=True) if params else None
        runs = [(0, self.num_envs)] if env_ids is None else self._runs(idx)
        offset = 0
        for start, count in runs:
            envs = slice(start, start + count)
            rel = slice(offset, offset + count)
            offset += count
            self.inputs[envs] = 0.0
            for gi, g in enumerate(self._groups):
                g.p[envs] = g.base_p if new_p is None else new_p[gi][rel]
                g.x[envs] = 0.0
                g.x[envs, :, 0 : 2 * size] = init[rel, g.sel]
                if not g.alias:
                    g.w[envs] = 0.0
                r0 = start * g.n
                g.lib.output(
                    count * g.n,
                    g.x.ctypes.data + r0 * self._nx * 8,
                    g.w.ctypes.data + r0 * self._nw * 8,
                    g.p.ctypes.data + r0 * self._np * 8,
                    g.y.ctypes.data + r0 * self._ny * 8,
                )
                if not g.alias:
                    self.outputs[envs, g.sel] = g.y[envs]
        self.time[idx] = 0.0
        self._failed[idx] = False
        return self.outputs

    def set_parameters(
        self, parameters: Mapping[str, npt.ArrayLike], env_ids: Sequence[int] | npt.ArrayLike | None = None
    ) -> None:
        """See :meth:`VehicleSystem.set_parameters` (checked before anything changes)."""
        idx = self._env_index(env_ids)
        params = self._parameter_arrays(parameters, len(idx))
        new_p = self._candidate_p(idx, params, from_base=False)
        for g, p in zip(self._groups, new_p, strict=True):
            g.p[idx] = p

    def parameters(self, name: str) -> F64Array:
        """See :meth:`VehicleSystem.parameters`."""
        names = self.spec.layout.parameter_names
        if name not in names:
            raise ParameterError(f"unknown vehicle parameter {name!r}; valid names: {', '.join(names)}")
        j = names.index(name)
        out = np.empty((self.num_envs, self.num_vehicles))
        for g in self._groups:
            out[:, g.vehicles] = g.p[:, :, j]
        return out

    @property
    def states(self) -> F64Array:
        """Full states ``(B, N, 8)``: x, y, psi (not wrapped), u, v, r, and the controller integrators.

        6-DOF: ``(B, N, 17)``: eta, nu and five integrators.
        """
        out = np.empty((self.num_envs, self.num_vehicles, self._nx))
        for g in self._groups:
            out[:, g.vehicles] = g.x
        return out

    # -- snapshots --------------------------------------------------------------------------------------

    def snapshot(self) -> BatchedSnapshot:
        """See :meth:`VehicleSystem.snapshot` (copies of the arrays; microseconds to milliseconds)."""
        arrays: dict[str, F64Array] = {
            "inputs": self.inputs.copy(),
            "outputs": self.outputs.copy(),
            "time": self.time.copy(),
            "failed": self._failed.astype(np.float64),
        }
        for gi, g in enumerate(self._groups):
            arrays[f"x{gi}"] = g.x.copy()
            arrays[f"p{gi}"] = g.p.copy()
            arrays[f"w{gi}"] = g.w.copy()
            arrays[f"y{gi}"] = g.y.copy()
        return BatchedSnapshot(arrays=arrays)

    def restore(self, snapshot: object) -> F64Array:
        """See :meth:`VehicleSystem.restore`."""
        if not isinstance(snapshot, BatchedSnapshot):
            raise TypeError(f"expected a BatchedSnapshot, got {type(snapshot).__name__}")
        a = snapshot.arrays
        if a["inputs"].shape != self.inputs.shape or len(a) != 4 + 4 * len(self._groups):
            raise ValueError(
                f"the snapshot (inputs {a['inputs'].shape}) does not fit this system "
                f"(inputs {self.inputs.shape})"
            )
        for gi, g in enumerate(self._groups):
            g.x[...] = a[f"x{gi}"]
            g.p[...] = a[f"p{gi}"]
            g.w[...] = a[f"w{gi}"]
            g.y[...] = a[f"y{gi}"]
        self.inputs[...] = a["inputs"]
        self.outputs[...] = a["outputs"]
        self.time[...] = a["time"]
        self._failed[...] = a["failed"] != 0.0
        return self.outputs

    def close(self) -> None:
        """Stop the worker threads (idempotent)."""
        pool = getattr(self, "_pool", None)
        if pool is not None:
            pool.shutdown(wait=True)
            self._pool = None
            self._chunks = [[t for c in self._chunks for t in c]]
