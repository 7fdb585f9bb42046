"""Calibration: a grey-box fit of the vehicle model's parameters to a logged trajectory.

**Method.** Multiple shooting (Bock and Plitt 1984) over the project's own RK4 step
(:class:`~hptvsim.twin.plant.Plant`, built from :mod:`hptvsim.dynamics`: the equations are not
written again here), solved by IPOPT through CasADi. The log's armed stretches (runs) are cut into
segments of ``segment_steps`` steps of the log's own grid; the decision variables are the free
parameters (scaled by their starting values) and the full state at each segment's start, and the
continuity of the state from one segment to the next within a run is an equality constraint. The
objective is the weighted least-squares output error ``sum_k sum_c ((y_c,k - x_c,k) / sigma_c)^2``
over the measured states ``c`` (missing values are left out). ``sigma_c`` starts from
:func:`~hptvsim.twin.table.default_sigma` and is re-estimated from the residuals, after which the
problem is solved again.

**Constraints.** Each parameter's bounds are its :class:`~hptvsim.dynamics.ParameterSpec`'s
(damping derivatives ``<= 0``: damping dissipates; masses and inertias ``> 0``); the mass matrix
``M = M_RB + M_A`` stays positive definite: each leading principal minor of ``M`` stays above
``1e-3`` times its value at the start (Sylvester's criterion).

**Confidence and identifiability.** At the solution, the residual Jacobian ``J`` (weighted) is
restricted to the directions the continuity constraints allow (an orthonormal basis ``Z`` of the
null space of their Jacobian: the free parameters and each run's initial state), ``J_r = J Z``.
Its singular values show what the data determine: a direction whose singular value is below
``rel_singular_threshold`` times the largest is not determined at all, and every free parameter
with a component above ``null_component`` in such a direction is *not identifiable*. The
covariance is the Gauss-Newton (Fisher) approximation ``s^2 Z (J_r^T J_r)^+ Z^T`` with ``s^2``
the residual variance per degree of freedom; 95 % intervals are ``estimate +- 1.96 std``. A
parameter whose interval's half-width exceeds ``max_rel_halfwidth`` times its estimate, or is
wider than its bounds, is not identifiable either. Two checks guard against intervals that the
linear approximation makes too narrow (a parameter "determined" only by a transient fitted to
noise, e.g. at the start of a run): the profile likelihood (the parameter fixed at each end of its
interval and the rest re-fitted: chi^2 must rise by ``profile_min_rise``; linear theory: 3.84),
and the split-half check (each half of the log fitted alone: both must determine the parameter,
and agree within ``split_max_z`` standard deviations). A fit with any non-identifiable parameter is
reported as such; those parameters keep their starting values in the vehicle file written (the
data do not support the estimate), and the prediction error after the fit is that of the file.

**Does the fit predict better?** A model whose structure or inputs cannot explain the log (a
thruster curve or allocation that is not the vehicle's, a missing term) makes the fit absorb the
misfit into the free parameters, with intervals as narrow as any: a confident wrong answer. So
the fitted model must also predict better than the starting one: where its k-step RMSE of some
measured state exceeds the starting model's by more than :data:`WORSE_FACTOR` times (and by
more than that state's noise), every parameter the checks above let through is reported *not
identifiable* with that reason, and the vehicle file keeps the starting values.

**Prediction error.** The k-step-ahead error (k = 1, 10, 100 steps of the log's grid): from every
sample of a run, the state is set to the measurement (unmeasured states: the fit's estimate) and
the model is run k steps on the logged inputs; the RMSE per measured state is over all such
predictions (angles compared modulo 2 pi). Nothing here draws or writes; see
:mod:`hptvsim.twin.fit_report`.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field, replace
from typing import Any, Final

import numpy as np

from hptvsim.dynamics._casadi import ca
from hptvsim.twin.plant import ANGLE_NAMES, Plant
from hptvsim.twin.table import (
    LogError,
    LogTable,
    Runs,
    default_sigma,
    measured_matrix,
    plant_inputs,
    split_runs,
)

__all__ = [
    "HORIZONS",
    "WORSE_FACTOR",
    "FitError",
    "FitOptions",
    "FitResult",
    "ParameterEstimate",
    "fit_log",
    "k_step_rmse",
    "simulate",
]

HORIZONS: Final = (1, 10, 100)
"""The prediction horizons reported [steps of the log's grid]."""
_Z95: Final = 1.959963984540054  # two-sided 95 % quantile of the standard normal
_MINOR_FLOOR: Final = 1e-3  # leading minors of M stay above this fraction of their starting values


class FitError(ValueError):
    """A fit cannot be set up (unknown or fixed parameter, no usable data)."""


@dataclass(frozen=True)
class FitOptions:
    """Settings of :func:`fit_log` (defaults are what ``hptvsim vehicle fit`` uses).

    Attributes:
        segment_steps: Steps of the log's grid per shooting segment.
        max_segments: At most this many segments (longer logs get longer segments).
        max_iter: IPOPT's iteration limit per solve.
        reweight: Re-estimate each measured state's noise from the residuals and solve again.
        rel_singular_threshold: Singular values of ``J_r`` below this fraction of the largest are
            directions the data do not determine.
        null_component: A parameter with a component above this in such a direction is not
            identifiable.
        max_rel_halfwidth: A parameter whose 95 % half-width exceeds this fraction of its
            estimate is not identifiable.
        profile_check: Check each interval against the profile likelihood (two more solves per
            parameter; see the module docstring).
        profile_min_rise: A parameter whose chi^2 rises by less than this at an end of its 95 %
            interval (linear theory: 3.84) is not identifiable.
        split_check: Fit each half of the log alone too (two more fits): a parameter must be
            identifiable in both and the two estimates must agree.
        split_max_z: Largest distance between the halves' estimates, in standard deviations of
            their difference.
        sigma: Starting noise guess per measured state (default: :func:`default_sigma`).
        horizons: Prediction horizons [steps].
    """

    segment_steps: int = 20
    max_segments: int = 150
    max_iter: int = 300
    reweight: bool = True
    rel_singular_threshold: float = 1e-6
    null_component: float = 0.05
    max_rel_halfwidth: float = 0.5
    profile_check: bool = True
    profile_min_rise: float = 1.0
    split_check: bool = True
    split_max_z: float = 3.0
    sigma: Mapping[str, float] = field(default_factory=dict)
    horizons: tuple[int, ...] = HORIZONS


@dataclass(frozen=True)
class ParameterEstimate:
    """One free parameter's result.

    Attributes:
        name: Parameter name (SNAME notation).
        unit: SI unit.
        initial: Starting value (the vehicle's).
        estimate: Fitted value.
        std: Standard deviation (Gauss-Newton), ``inf`` where the data do not determine it.
        low: Lower end of the 95 % interval.
        high: Upper end of the 95 % interval.
        identifiable: Whether the data determine it (see the module docstring).
        reason: Why not (empty when identifiable).
        written: The value written to the vehicle file.
        profile_rise: Rise of chi^2 when the parameter is fixed at the low and the high end of its
            interval and the rest re-fitted (empty when not checked).
    """

    name: str
    unit: str
    initial: float
    estimate: float
    std: float
    low: float
    high: float
    identifiable: bool
    reason: str
    written: float
    profile_rise: tuple[float, ...] = ()

    @property
    def verdict(self) -> str:
        """``"identified"`` or ``"not identifiable"``."""
        return "identified" if self.identifiable else "not identifiable"


@dataclass(frozen=True)
class FitResult:
    """What :func:`fit_log` found.

    Attributes:
        plant: The model fitted.
        free: The free parameters' names.
        estimates: One per free parameter.
        p_fitted: The full parameter vector at the optimum.
        p_written: The vector of the vehicle file (non-identifiable ones at their start).
        identifiable: Whether every free parameter is identifiable.
        relative_singular_values: Singular values of ``J_r`` over the largest, descending.
        covariance: Covariance of the free parameters (SI units, Gauss-Newton).
        sigma: Noise estimate per measured state (unit of the state).
        n_observations: Measured values used.
        solver_status: IPOPT's return status of the last solve.
        iterations: IPOPT iterations (all solves).
        time: Sample times [s] of the log.
        measured: Measured states (samples x ``plant.measured``), angles unwrapped.
        inputs: The plant's inputs (samples x ``plant.nu``).
        states: Estimated full state per sample (``NaN`` outside the runs).
        runs: The runs used.
        rmse_before: ``{k: {state: rmse}}`` with the starting parameters.
        rmse_after: The same with ``p_written``.
    """

    plant: Plant
    free: tuple[str, ...]
    estimates: tuple[ParameterEstimate, ...]
    p_fitted: np.ndarray
    p_written: np.ndarray
    identifiable: bool
    relative_singular_values: np.ndarray
    covariance: np.ndarray
    sigma: dict[str, float]
    n_observations: int
    solver_status: str
    iterations: int
    time: np.ndarray
    measured: np.ndarray
    inputs: np.ndarray
    states: np.ndarray
    runs: Runs
    rmse_before: dict[int, dict[str, float]]
    rmse_after: dict[int, dict[str, float]]

    def estimate(self, name: str) -> ParameterEstimate:
        """The estimate of one free parameter."""
        for e in self.estimates:
            if e.name == name:
                return e
        raise KeyError(f"{name!r} was not free; free: {', '.join(self.free)}")


@dataclass(frozen=True)
class _Segments:
    """The shooting grid: segment ``j`` starts at row ``rows[j, 0]`` and takes ``L`` steps."""

    rows: np.ndarray  # nseg x (L + 1) row indices (padded steps repeat the last row)
    steps: np.ndarray  # nseg x L step lengths [s] (0 for padding)
    valid: np.ndarray  # nseg x (L + 1): whether the sample is a real one
    continues: np.ndarray  # nseg: whether the next segment continues this one's run


def _segments(time: np.ndarray, runs: Runs, L: int) -> _Segments:
    rows, steps, valid, cont = [], [], [], []
    for a, b in runs.spans:
        for s in range(a, b, L):
            e = min(s + L, b)
            r = np.arange(s, s + L + 1)
            ok = r <= e
            r = np.minimum(r, e)
            h = np.diff(time[r])
            rows.append(r)
            steps.append(h)
            valid.append(ok)
            cont.append(e < b)
    return _Segments(
        rows=np.asarray(rows, dtype=int),
        steps=np.asarray(steps, dtype=float),
        valid=np.asarray(valid, dtype=bool),
        continues=np.asarray(cont, dtype=bool),
    )


def _scale(value: float) -> float:
    """A free parameter's scale: its starting magnitude (1 in SI when it starts at zero)."""
    return abs(value) if value != 0.0 else 1.0


def _interp_states(plant: Plant, Y: np.ndarray, time: np.ndarray) -> np.ndarray:
    """A first guess of the full state per row: measured values, interpolated; others zero."""
    X = np.zeros((time.size, plant.nx))
    for j in range(Y.shape[1]):
        ok = np.isfinite(Y[:, j])
        if ok.sum() >= 2:
            X[:, j] = np.interp(time, time[ok], Y[ok, j])
        elif ok.sum() == 1:
            X[:, j] = Y[ok, j][0]
    return X


def _minors(M: Any, n: int) -> list[Any]:
    return [ca.det(M[0:k, 0:k]) for k in range(1, n + 1)]


def _check_free(plant: Plant, free: Sequence[str]) -> list[int]:
    if not free:
        raise FitError("give at least one free parameter")
    out = []
    for name in free:
        if name not in plant.param_names:
            raise FitError(
                f"unknown parameter {name!r} for the {plant.dof}-DOF model; valid names: "
                f"{', '.join(n for n in plant.param_names if n != 'control_mode')}"
            )
        spec = plant.specs[plant.index(name)]
        if spec.integer or name in ("control_mode", "rho"):
            raise FitError(f"parameter {name!r} cannot be fitted (it is a setting, not a property)")
        out.append(plant.index(name))
    if len(set(out)) != len(out):
        raise FitError(f"a free parameter is named twice: {', '.join(free)}")
    return out


def fit_log(
    table: LogTable,
    plant: Plant,
    free: Sequence[str],
    *,
    from_pwm: bool = False,
    options: FitOptions | None = None,
) -> FitResult:
    """Fit the free parameters of ``plant`` to a log (see the module docstring).

    Args:
        table: The log.
        plant: The model, its ``base`` vector the starting values (a vehicle's).
        free: Names of the parameters to fit.
        from_pwm: Whether the inputs are thruster PWM (through :mod:`hptvsim.twin.thrusters`).
        options: Settings.

    Returns:
        The estimates with intervals and verdicts, and the prediction errors before and after.

    Raises:
        FitError: A free parameter is unknown or fixed.
        LogError: The log lacks a column or has no run of at least 3 armed samples.
    """
    opt = options or FitOptions()
    idx = _check_free(plant, free)
    U = plant_inputs(table, plant, from_pwm=from_pwm)
    Y = measured_matrix(table, plant)
    runs = split_runs(table)
    if not runs.spans:
        raise LogError(f"{table.source}: no armed stretch of at least 3 samples to fit")
    time = table.time
    n_steps = sum(b - a for a, b in runs.spans)
    L = max(1, opt.segment_steps, math.ceil(n_steps / max(1, opt.max_segments)))
    seg = _segments(time, runs, L)
    nseg = seg.rows.shape[0]
    nx, nu, nm, nf = plant.nx, plant.nu, len(plant.measured), len(idx)
    base = plant.base
    scale = np.array([_scale(base[i]) for i in idx])

    # --- symbolic problem -------------------------------------------------------------------
    z = ca.MX.sym("z", nf)
    # estimated start states: all of them, but in raw-force mode the controller's integrators,
    # which hold there, are zero and left out
    ns = nm if plant.kind == "tau" else nx
    S = ca.MX.sym("S", ns, nseg)
    S_full = ca.vertcat(S, ca.MX.zeros(nx - ns, nseg)) if ns < nx else S
    entries = [ca.MX(float(v)) for v in base]
    for k, i in enumerate(idx):
        entries[i] = z[k] * float(scale[k])
    p = ca.vertcat(*entries)
    Xs = ca.MX.sym("Xs", nx)
    Us = ca.MX.sym("Us", nu, L)
    Ps = ca.MX.sym("Ps", plant.base.size)
    Hs = ca.MX.sym("Hs", 1, L)
    acc = plant.step.mapaccum("plant_acc", L)
    seg_fun = ca.Function("segment", [Xs, Us, Ps, Hs], [ca.horzcat(Xs, acc(Xs, Us, ca.repmat(Ps, 1, L), Hs))])
    all_fun = seg_fun.map("segments", "serial", nseg, [2], [])
    U_all = U[seg.rows[:, :L].reshape(-1)].T  # nu x (nseg L)
    H_all = seg.steps.reshape(1, -1)
    X_all = all_fun(S_full, ca.DM(U_all), p, ca.DM(H_all))  # nx x (nseg (L + 1))

    rows_flat = seg.rows.reshape(-1)
    Y_seg = Y[rows_flat].T  # nm x (nseg (L + 1))
    mask = np.isfinite(Y_seg) & seg.valid.reshape(1, -1)
    ends = np.arange(nseg) * (L + 1) + L
    mask[:, ends[seg.continues]] = False  # the next segment's first sample: counted once
    Y0 = np.where(mask, Y_seg, 0.0)
    names = plant.measured
    sigma = np.array([float(opt.sigma.get(n, default_sigma(n))) for n in names])
    W = ca.MX.sym("W", nm)  # 1 / sigma per measured state
    E = X_all[0:nm, :] - ca.DM(Y0)
    R = ca.vec(ca.DM(mask.astype(float)) * (ca.repmat(W, 1, E.shape[1]) * E))
    cont = [X_all[0:ns, int(ends[j])] - S[:, j + 1] for j in range(nseg) if seg.continues[j]]
    g_cont = ca.vertcat(*cont) if cont else ca.MX(0, 1)
    M = plant.mass_matrix(p)
    M0 = np.array(plant.mass_matrix(ca.DM(base)))
    ndof = M0.shape[0]
    minors0 = [float(np.linalg.det(M0[0:k, 0:k])) for k in range(1, ndof + 1)]
    g_pd = ca.vertcat(*[m / abs(m0) for m, m0 in zip(_minors(M, ndof), minors0, strict=True)])
    v = ca.vertcat(z, ca.vec(S))
    nlp = {"x": v, "p": W, "f": 0.5 * ca.sumsqr(R), "g": ca.vertcat(g_cont, g_pd)}
    solver = ca.nlpsol(
        "fit",
        "ipopt",
        nlp,
        {
            "ipopt": {"print_level": 0, "max_iter": opt.max_iter, "tol": 1e-10, "acceptable_tol": 1e-7},
            "print_time": False,
            "expand": True,
            "show_eval_warnings": False,  # a trial step that makes the simulation diverge is normal
        },
    )
    lbz, ubz = np.full(nf, -np.inf), np.full(nf, np.inf)
    for k, i in enumerate(idx):
        spec = plant.specs[i]
        if spec.lower is not None:
            lbz[k] = (spec.lower + (1e-9 * scale[k] if spec.lower_open else 0.0)) / scale[k]
        if spec.upper is not None:
            ubz[k] = spec.upper / scale[k]
    n_c = int(g_cont.shape[0])
    lbg = np.concatenate([np.zeros(n_c), np.full(ndof, _MINOR_FLOOR)])
    ubg = np.concatenate([np.zeros(n_c), np.full(ndof, np.inf)])
    X_guess = _interp_states(plant, Y, time)
    v0 = np.concatenate([base[idx] / scale, X_guess[seg.rows[:, 0], 0:ns].reshape(-1)])
    lbv = np.concatenate([lbz, np.full(ns * nseg, -np.inf)])
    ubv = np.concatenate([ubz, np.full(ns * nseg, np.inf)])

    iterations = 0
    status = ""
    solves = 2 if opt.reweight else 1
    resid_fun = ca.Function("resid", [v, W], [E])
    for solve in range(solves):
        sol = solver(x0=v0, p=1.0 / sigma, lbx=lbv, ubx=ubv, lbg=lbg, ubg=ubg)
        stats = solver.stats()
        iterations += int(stats.get("iter_count", 0))
        status = str(stats.get("return_status", ""))
        v0 = np.array(sol["x"]).ravel()
        if solve + 1 < solves:
            e = np.array(resid_fun(v0, 1.0 / sigma))
            for c in range(nm):
                if mask[c].any():
                    sigma[c] = max(float(np.sqrt(np.mean(e[c, mask[c]] ** 2))), 1e-9)
    v_opt = v0
    p_fit = base.copy()
    p_fit[idx] = v_opt[:nf] * scale

    # --- confidence and identifiability (Gauss-Newton at the optimum) ---------------------
    jac = ca.Function("fit_jacobian", [v, W], [R, ca.jacobian(R, v), ca.jacobian(g_cont, v)])
    r_opt, J_opt, A_opt = (np.array(a) for a in jac(v_opt, 1.0 / sigma))
    r_opt = r_opt.ravel()
    n_obs = int(mask.sum())
    Z = _null_space(A_opt) if n_c else np.eye(v_opt.size)
    Jr = J_opt @ Z
    _, s, Vt = np.linalg.svd(Jr, full_matrices=False)
    rel = s / s[0] if s.size and s[0] > 0 else np.zeros_like(s)
    keep = rel > opt.rel_singular_threshold
    dof_res = max(1, n_obs - int(keep.sum()))
    s2 = float(r_opt @ r_opt) / dof_res
    Vk = Vt[keep].T
    cov_red = (Vk / s[keep] ** 2) @ Vk.T
    cov_z = (Z[:nf] @ cov_red @ Z[:nf].T) * s2
    null_dirs = Z[:nf] @ Vt[~keep].T  # nf x n_null: the parameters' part of undetermined directions

    f_opt = 0.5 * float(r_opt @ r_opt)
    halves = _split_fits(table, plant, free, from_pwm, opt, runs) if opt.split_check else None

    def _profile_rise(z_end: float) -> float:
        lb, ub = lbv.copy(), ubv.copy()
        z_end = float(np.clip(z_end, lb[k], ub[k]))
        lb[k] = ub[k] = z_end
        start = v_opt.copy()
        start[k] = z_end
        sol_k = solver(x0=start, p=1.0 / sigma, lbx=lb, ubx=ub, lbg=lbg, ubg=ubg)
        return 2.0 * (float(sol_k["f"]) - f_opt) / s2

    estimates = []
    p_written = base.copy()
    for k, i in enumerate(idx):
        spec = plant.specs[i]
        est = float(p_fit[i])
        std = float(math.sqrt(max(cov_z[k, k], 0.0)) * scale[k])
        reasons = []
        if null_dirs.size and float(np.max(np.abs(null_dirs[k]))) > opt.null_component:
            reasons.append(
                "the data do not determine it (a direction of relative singular value below "
                f"{opt.rel_singular_threshold:g})"
            )
            std = math.inf
        hw = _Z95 * std
        if math.isfinite(hw) and hw > opt.max_rel_halfwidth * abs(est):
            reasons.append(f"95 % half-width {hw:.3g} exceeds {opt.max_rel_halfwidth:g} x |estimate|")
        if spec.lower is not None and spec.upper is not None and 2 * hw > spec.upper - spec.lower:
            reasons.append("interval wider than the parameter's bounds")
        rise: tuple[float, ...] = ()
        if not reasons and opt.profile_check:
            rise = tuple(_profile_rise(end / scale[k]) for end in (est - hw, est + hw))
            if min(rise) < opt.profile_min_rise:
                reasons.append(
                    f"flat profile likelihood: fixed at an end of its 95 % interval, chi^2 rises by "
                    f"only {min(rise):.2g} (the linear theory behind the interval: {_Z95**2:.2f})"
                )
        if not reasons and halves is not None:
            a, b = halves[0].estimates[k], halves[1].estimates[k]
            if not (a.identifiable and b.identifiable):
                reasons.append("not identifiable from one half of the log alone")
            else:
                z_ab = abs(a.estimate - b.estimate) / math.hypot(a.std, b.std)
                if z_ab > opt.split_max_z:
                    reasons.append(
                        f"the log's two halves disagree: {a.estimate:.4g} +- {a.std:.2g} and "
                        f"{b.estimate:.4g} +- {b.std:.2g} ({z_ab:.1f} standard deviations apart)"
                    )
        ok = not reasons
        p_written[i] = est if ok else base[i]
        estimates.append(
            ParameterEstimate(
                name=spec.name,
                unit=spec.unit,
                initial=float(base[i]),
                estimate=est,
                std=std,
                low=est - hw,
                high=est + hw,
                identifiable=ok,
                reason="; ".join(reasons),
                written=float(p_written[i]),
                profile_rise=rise,
            )
        )

    # --- states and prediction errors -------------------------------------------------------
    S_opt = np.zeros((nx, nseg))
    S_opt[0:ns] = v_opt[nf:].reshape(nseg, ns).T
    X_opt = np.array(all_fun(S_opt, ca.DM(U_all), ca.DM(p_fit), ca.DM(H_all)))
    states = np.full((time.size, nx), np.nan)
    vr = seg.valid.reshape(-1)
    states[rows_flat[vr]] = X_opt.T[vr]
    rmse_before = k_step_rmse(plant, base, time, U, Y, states, runs, opt.horizons)
    rmse_after = k_step_rmse(plant, p_written, time, U, Y, states, runs, opt.horizons)
    noise = {n: float(sigma[c]) for c, n in enumerate(names) if mask[c].any()}
    worse = _worse_predictions(rmse_before, rmse_after, noise)
    if worse is not None and any(e.identifiable for e in estimates):
        estimates = [
            replace(e, identifiable=False, reason=worse, written=e.initial) if e.identifiable else e
            for e in estimates
        ]
        p_written = base.copy()
        rmse_after = rmse_before
    return FitResult(
        plant=plant,
        free=tuple(free),
        estimates=tuple(estimates),
        p_fitted=p_fit,
        p_written=p_written,
        identifiable=all(e.identifiable for e in estimates),
        relative_singular_values=rel,
        covariance=cov_z * np.outer(scale, scale),
        sigma={n: float(sigma[c]) for c, n in enumerate(names) if mask[c].any()},
        n_observations=n_obs,
        solver_status=status,
        iterations=iterations,
        time=time,
        measured=Y,
        inputs=U,
        states=states,
        runs=runs,
        rmse_before=rmse_before,
        rmse_after=rmse_after,
    )


WORSE_FACTOR: Final = 1.25
"""How much larger the fitted model's k-step RMSE of a state may be than the starting model's
before the fit counts as predicting worse (see the module docstring)."""


def _worse_predictions(
    before: Mapping[int, Mapping[str, float]],
    after: Mapping[int, Mapping[str, float]],
    noise: Mapping[str, float],
) -> str | None:
    """Why the fitted model predicts worse than the starting one (the worst case), or None."""
    worst: tuple[float, int, str, float, float] | None = None
    for k, row in before.items():
        for state, b in row.items():
            a = after.get(k, {}).get(state, math.nan)
            if not (math.isfinite(a) and math.isfinite(b)):
                continue
            if a > WORSE_FACTOR * b and a - b > noise.get(state, 0.0):
                ratio = a / b if b > 0 else math.inf
                if worst is None or ratio > worst[0]:
                    worst = (ratio, k, state, b, a)
    if worst is None:
        return None
    _, k, state, b, a = worst
    return (
        f"the fitted model predicts worse than the starting one ({state} over {k} steps: RMSE "
        f"{b:.3g} -> {a:.3g}): the model or its inputs (thruster curve, allocation) do not explain "
        "this log, and the fit absorbed the misfit into the parameters"
    )


def _split_fits(
    table: LogTable, plant: Plant, free: Sequence[str], from_pwm: bool, opt: FitOptions, runs: Runs
) -> tuple[FitResult, FitResult] | None:
    """Fit the first and the second half of the log's used samples alone (``None``: too short)."""
    used = np.concatenate([np.arange(a, b + 1) for a, b in runs.spans])
    if used.size < 4 * max(1, opt.segment_steps):
        return None
    mid = used[used.size // 2]
    inner = replace(opt, split_check=False, profile_check=False)
    out = []
    for rows in (used[used < mid], used[used >= mid]):
        mask = np.zeros(table.time.size, dtype=bool)
        mask[rows] = True
        if table.has("armed"):
            mask &= table.column("armed") >= 0.5
        part = table.slice(mask)
        try:
            out.append(fit_log(part, plant, free, from_pwm=from_pwm, options=inner))
        except LogError:
            return None
    return out[0], out[1]


def _null_space(A: np.ndarray) -> np.ndarray:
    """An orthonormal basis of the null space of ``A`` (from its SVD)."""
    _, s, Vt = np.linalg.svd(A, full_matrices=True)
    tol = max(A.shape) * np.finfo(float).eps * (s[0] if s.size else 0.0)
    rank = int((s > tol).sum())
    return np.asarray(Vt[rank:].T)


def simulate(plant: Plant, p: np.ndarray, x0: np.ndarray, U: np.ndarray, time: np.ndarray) -> np.ndarray:
    """Run the plant from ``x0`` over the log's grid (inputs held over each step).

    Returns:
        States (samples x ``plant.nx``), the first row ``x0``.
    """
    X = np.zeros((time.size, plant.nx))
    X[0] = x0
    pd = ca.DM(p)
    for k in range(time.size - 1):
        X[k + 1] = np.array(plant.step(X[k], U[k], pd, time[k + 1] - time[k])).ravel()
    return X


def k_step_predictions(
    plant: Plant,
    p: np.ndarray,
    time: np.ndarray,
    U: np.ndarray,
    Y: np.ndarray,
    states: np.ndarray,
    runs: Runs,
    k_max: int,
) -> np.ndarray:
    """``P[k, i]``: the state at row ``i`` predicted ``k`` steps earlier (``NaN`` where none).

    Each prediction starts from the measurement ``k`` rows earlier (unmeasured or missing states:
    ``states``) and runs the model on the logged inputs.

    Returns:
        An array ``(k_max + 1) x samples x plant.nx``.
    """
    n = time.size
    P = np.full((k_max + 1, n, plant.nx), np.nan)
    nm = Y.shape[1]
    for a, b in runs.spans:
        starts = np.arange(a, b + 1)
        x = states[starts].copy()
        meas = Y[starts]
        x[:, :nm] = np.where(np.isfinite(meas), meas, x[:, :nm])
        x = np.nan_to_num(x)
        P[0, starts] = x
        F = plant.step.map(starts.size)
        alive = np.ones(starts.size, dtype=bool)
        for k in range(1, k_max + 1):
            row = starts + k
            alive &= row <= b
            if not alive.any():
                break
            rr = np.minimum(row, b)
            h = np.where(alive, time[rr] - time[np.minimum(row - 1, b)], 0.0)
            x = np.array(F(x.T, U[np.minimum(row - 1, b)].T, ca.DM(p), h.reshape(1, -1))).T
            P[k, rr[alive]] = x[alive]
    return P


def k_step_rmse(
    plant: Plant,
    p: np.ndarray,
    time: np.ndarray,
    U: np.ndarray,
    Y: np.ndarray,
    states: np.ndarray,
    runs: Runs,
    horizons: Sequence[int] = HORIZONS,
) -> dict[int, dict[str, float]]:
    """The k-step-ahead RMSE per measured state (``NaN`` where there is no k-step pair)."""
    P = k_step_predictions(plant, p, time, U, Y, states, runs, max(horizons))
    out: dict[int, dict[str, float]] = {}
    for k in horizons:
        row: dict[str, float] = {}
        for c, name in enumerate(plant.measured):
            err = P[k, :, c] - Y[:, c]
            if name in ANGLE_NAMES:
                err = (err + math.pi) % (2 * math.pi) - math.pi
            ok = np.isfinite(err)
            if ok.any() and np.isfinite(Y[:, c]).any():
                row[name] = float(np.sqrt(np.mean(err[ok] ** 2)))
        out[k] = row
    return out
