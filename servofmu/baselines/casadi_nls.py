"""CasADi nonlinear least squares: PSO-ANN's output-error fit, solved by a derivative-based optimiser.

The residuals are those of servofmu.identification.criterion.SineCriterion — per experiment Re and Im of
(H_model − H)/|H| and √2·(dc_model − dc)/(|H|·m) (criterion.sine_residuals) — but computed from the CasADi model of servofmu.model.symbolic (the single source of the
equations) so that CasADi gives their exact derivatives.

Per experiment (amplitude m, frequency f):

- the states without ``position`` (it integrates v and does not act back, unless a load's spring or ripple
  depends on it: then it is a state like the others), divided by the measured velocity
  amplitude a = |H|·m so that they are O(1), are integrated by CVODES over one period in the scaled time
  τ = f·t ∈ [0, 1], with the quadratures q' = (2v·sin 2πτ, 2v·cos 2πτ, v)/a; then S1 = a·(q1 + j·q2) and
  dc = a·q3 (the phasor convention of servofmu.measurement.frf), H = S1/m;
- the periodic steady state is the fixed point x0 = Φ(x0; θ) of this period map, found by Newton's method with
  the sensitivity ∂Φ/∂x0 (warm-started from the previous evaluation; a line search, and where Newton does not
  shrink the gap one more simulated period instead).  A fixed point whose monodromy matrix ∂Φ/∂x0 has a
  spectral radius ≥ 1 is not where the plant settles: that experiment has no steady state and gives NaN, as in
  SineCriterion;
- derivatives by the implicit function theorem: dx0/dθ = (I − Φx)⁻¹·Φθ and dq/dθ = Qx·dx0/dθ + Qθ, with Φx,
  Φθ, Qx, Qθ from the variational equations, which CasADi differentiates from the model and CVODES integrates
  beside the states under the same error control (several times faster than differentiating the CVODES
  integrator itself with CasADi, which gives the same numbers).

Optimisers:

- ``"ipopt"`` (default): multiple shooting as in CasADi's sysid example: the periodic states are decision
  variables with the periodicity constraints Φ(x0_k; θ) − x0_k = 0, the objective ½‖r‖², the Gauss–Newton
  Hessian σ·JᵀJ and the exact first derivatives above.  Its iterates need not have a periodic steady state, so
  it can cross parameter regions where an experiment has none (a stable period-one orbit is lost);
- ``"gauss-newton"``: scipy's trust-region reflective least squares — a damped Gauss–Newton method — in the
  reduced space of the parameters (the steady states solved at every iterate), with the exact Jacobian.  Fewer
  simulations per iteration, but it can stall at the border of such a region.
Both work on parameters scaled to O(1) by the start values, within bounds that keep the poles in the closed
left half-plane and the friction levels non-negative.

The documented default start (``theta0=None``) is the structure file's own values: the user's nominal plant.
"""
from __future__ import annotations

import time
from dataclasses import dataclass
from functools import cached_property

import casadi as ca
import numpy as np
from numpy.typing import ArrayLike

from ..errors import UserError
from ..identification.criterion import SineData, output_error_fitness, sine_residual_jacobian, sine_residuals
from ..identification.prior import full_entries, full_vectors, identified_mask, identified_names
from ..model.plant import Plant
from ..model.symbolic import build_model
from ..runtime import Progress
from ..simulation.batch import valid_parameter_sets
from . import BaselineResult

__all__ = ["fit_casadi_nls", "NlsOptions", "CasadiCriterion", "PeriodicSteadyState"]

METHODS = ("ipopt", "gauss-newton")
FAILED_RESIDUAL = 1e3  # what the optimiser sees where a candidate has no steady state (a step it must reject)


@dataclass(frozen=True)
class NlsOptions:
    """Settings of the least-squares fit.

    ``method``: "ipopt" or "gauss-newton" (module docstring); ``rtol``: CVODES relative tolerance (the absolute
    tolerance is the same number, the states being O(1)); ``max_iterations``: Ipopt iterations, or Gauss–Newton
    residual evaluations (one per iteration plus one per rejected step); ``tolerance``: stop when the relative
    change of the scaled parameters (Gauss–Newton) or Ipopt's scaled NLP error falls below it (Ipopt: 100 times
    it, the first derivatives being as exact as the integration, about rtol);
    ``steady_state_passes``: evaluations of the period map allowed to find the periodic steady states (Newton
    steps, line-search trials, single simulated periods); an experiment not settled by then has no steady state.
    """

    method: str = "ipopt"
    rtol: float = 1e-10
    max_iterations: int = 100
    tolerance: float = 1e-10
    steady_state_passes: int = 30

    def __post_init__(self):
        if self.method not in METHODS:
            raise UserError(f"unknown least-squares method {self.method!r} (choose {', '.join(METHODS)})")
        if not 0 < self.rtol < 1e-2:
            raise UserError(f"rtol must be in (0, 0.01), not {self.rtol}")
        if self.max_iterations < 1:
            raise UserError(f"max_iterations must be at least 1, not {self.max_iterations}")
        if not 0 < self.tolerance < 1:
            raise UserError(f"tolerance must be in (0, 1), not {self.tolerance}")
        if self.steady_state_passes < 2:
            raise UserError(f"steady_state_passes must be at least 2, not {self.steady_state_passes}")


@dataclass(frozen=True)
class PeriodicFeatures:
    """Steady-state features of one parameter vector in every experiment (arrays of shape (n_exp,)), and with
    ``jacobian=True`` their derivatives with respect to the identified parameters (shape (n_exp, p))."""

    H: np.ndarray
    dc: np.ndarray
    converged: np.ndarray
    dH: np.ndarray | None = None
    ddc: np.ndarray | None = None


class PeriodicSteadyState:
    """The CasADi period map of a structure under a plan, and the periodic steady state with its sensitivities.

    ``scale`` (n_exp,): the velocity amplitude each experiment's states are divided by (any positive values of
    the order of the response work; the fit uses the measured |H|·m).
    """

    def __init__(self, structure: Plant, amplitudes, frequencies, scale, rtol: float = 1e-10):
        self.structure = structure
        self.amplitudes = np.asarray(amplitudes, dtype=float).ravel()
        self.frequencies = np.asarray(frequencies, dtype=float).ravel()
        self.scale = np.asarray(scale, dtype=float).ravel()
        self.rtol = rtol
        self.n_exp = self.amplitudes.size
        self.names = identified_names(structure)
        model = build_model(structure)
        # the position acts back only through a load's spring or ripple; otherwise it is left out
        with_position = structure.load.depends_on_position()
        keep = [i for i, n in enumerate(model.state_names) if n != "position" or with_position]
        self.nx, self.n_theta = len(keep), len(self.names)

        # Symbols: reduced scaled states, identified parameters, and the experiment's m, f, a.
        xs, tau = ca.SX.sym("xs", self.nx), ca.SX.sym("tau")
        theta = ca.SX.sym("theta", self.n_theta)
        m, f, a = ca.SX.sym("m"), ca.SX.sym("f"), ca.SX.sym("a")
        p_full = ca.vertcat(*full_entries(structure, theta), m, f)
        x_full, j = [], iter(range(self.nx))
        for name in model.state_names:
            x_full.append(0.0 if name == "position" and not with_position else a * xs[next(j)])
        xdot = ca.substitute(model.xdot, ca.vertcat(model.t, model.x, model.u, model.p),
                             ca.vertcat(tau / f, ca.vertcat(*x_full), 0.0, p_full))
        if not with_position and ca.depends_on(model.xdot[keep], model.x[model.state_names.index("position")]):
            raise RuntimeError("the model's dynamics depend on the position state")  # a model change to revisit
        v = a * xs[0]
        ode = xdot[keep] / (a * f)
        quad = ca.vertcat(2 * v * ca.sin(2 * np.pi * tau), 2 * v * ca.cos(2 * np.pi * tau), v) / a
        self._symbols = (xs, theta, ca.vertcat(theta, m, f, a), tau, ode, quad)
        self._x0 = np.zeros((self.nx, self.n_exp))  # warm start: the last periodic states found

    def _integrator(self, sensitivities: str) -> ca.Function:
        """CVODES over one period of the states, their quadratures, and the variational equations
        S' = (∂ẋ/∂x)·S + [0, ∂ẋ/∂θ] with S(0) = [I, 0] (S = ∂x/∂[x0, θ]; and likewise for the quadratures):
        first-order sensitivities by CasADi's differentiation of the model, integrated with error control.
        (Integrating them as states is several times faster than CasADi's derivative of an integrator.)"""
        xs, theta, p, tau, ode, quad = self._symbols
        cols = self._columns(sensitivities)
        S = ca.SX.sym("S", self.nx, cols)

        def sens(expr):
            if cols == 0:
                return ca.SX(0, 1)
            direct = ca.jacobian(expr, theta) if cols > self.nx else ca.SX(expr.numel(), 0)
            return ca.vec(ca.mtimes(ca.jacobian(expr, xs), S) + ca.horzcat(ca.SX(expr.numel(), self.nx), direct))

        dae = {"x": ca.vertcat(xs, ca.vec(S)), "p": p, "t": tau, "ode": ca.vertcat(ode, sens(ode)),
               "quad": ca.vertcat(quad, sens(quad))}
        opts = {"reltol": self.rtol, "abstol": self.rtol, "max_num_steps": 200_000, "quad_err_con": True,
                "disable_internal_warnings": True}
        return ca.integrator(f"period_{sensitivities}", "cvodes", dae, 0.0, 1.0, opts).map(self.n_exp)

    def _columns(self, sensitivities: str) -> int:
        """Columns of S: none, ∂/∂x0 ("x"), or ∂/∂[x0, θ] ("all")."""
        return {"none": 0, "x": self.nx, "all": self.nx + self.n_theta}[sensitivities]

    def _initial(self, x0, sensitivities: str):
        cols = self._columns(sensitivities)
        return ca.vertcat(x0, ca.repmat(ca.DM(np.eye(self.nx, cols).T.reshape(-1, 1)), 1, self.n_exp))

    def symbolic_period(self, X: ca.MX, theta: ca.MX, sensitivities: str = "all"):
        """(xf, qf) of one period of every experiment as CasADi expressions of the states X (nx × n_exp) and
        θ: rows [x; vec(S)] and [q; vec(Sq)] (S column-major, see _call)."""
        p = ca.vertcat(ca.repmat(theta, 1, self.n_exp), ca.DM(self.amplitudes).T, ca.DM(self.frequencies).T,
                       ca.DM(self.scale).T)
        out = self._maps[sensitivities](x0=self._initial(X, sensitivities), p=p)
        return out["xf"], out["qf"]

    @cached_property
    def _maps(self) -> dict:
        return _LazyDict(self._integrator)

    def _call(self, with_theta: bool, x0: np.ndarray, theta: np.ndarray):
        """(xf (nx × n), qf (3 × n), S (n × nx × cols), Sq (n × 3 × cols)) of one period from ``x0``, or None
        where the integrator fails (too much work, a non-finite value: no steady state)."""
        sensitivities = "all" if with_theta else "x"
        cols, n = self._columns(sensitivities), self.n_exp
        p = np.vstack([np.tile(theta[:, None], (1, n)), self.amplitudes, self.frequencies, self.scale])
        try:
            out = self._maps[sensitivities](x0=self._initial(x0, sensitivities), p=p)
        except RuntimeError:
            return None
        xf, qf = np.asarray(out["xf"]), np.asarray(out["qf"])
        S = xf[self.nx:].T.reshape(n, cols, self.nx).transpose(0, 2, 1)
        Sq = qf[3:].T.reshape(n, cols, 3).transpose(0, 2, 1)
        return xf[:self.nx], qf[:3], S, Sq

    def periodic_states(self, theta: np.ndarray, max_passes: int = 30):
        """(x0 (nx × n_exp), converged (n_exp,)): the periodic steady state of every experiment at ``theta``.

        Newton on the gap g(x0) = Φ(x0) − x0 with a backtracking line search (the step halved while |g| does not
        shrink; after three halvings one simulated period, x0 ← Φ(x0), which a stable orbit contracts), all
        experiments at once, for at most ``max_passes`` evaluations of the period map.  Converged when
        |g| < 1000·rtol (the states being O(1)); a last Newton correction then leaves x0 at the integrator's
        noise level.  A fixed point whose monodromy matrix Φx has a spectral radius ≥ 1 repels: not converged.
        """
        x0, tol = self._x0.copy(), 1000 * self.rtol
        n, nx, eye = self.n_exp, self.nx, np.eye(self.nx)
        converged, active = np.zeros(n, bool), np.ones(n, bool)
        base, base_xf = x0.copy(), x0.copy()  # the last accepted point and its image Φ(base)
        base_gap = np.full(n, np.nan)         # max |g| there; NaN: accept the next point unconditionally
        direction, step = np.zeros((nx, n)), np.ones(n)
        for _ in range(max_passes):
            out = self._call(False, x0, theta)
            if out is None or not np.all(np.isfinite(out[0])):
                return x0, np.zeros(n, bool)
            xf, _, jac, _ = out
            for k in np.flatnonzero(active):
                gap = xf[:, k] - x0[:, k]
                g = np.max(np.abs(gap))
                if np.isnan(base_gap[k]) or g < (1 - step[k] / 4) * base_gap[k]:
                    base[:, k], base_xf[:, k], base_gap[k] = x0[:, k], xf[:, k], g
                    try:
                        direction[:, k] = -np.linalg.solve(jac[k] - eye, gap)
                    except np.linalg.LinAlgError:
                        direction[:, k] = gap
                    step[k] = 1.0
                    if g < tol:
                        active[k] = False
                        converged[k] = np.max(np.abs(np.linalg.eigvals(jac[k]))) < 1.0
                        x0[:, k] = base[:, k] + direction[:, k]
                        continue
                elif step[k] > 1 / 8:
                    step[k] /= 2
                else:  # Newton does not contract here: one simulated period instead
                    x0[:, k], base_gap[k] = base_xf[:, k], np.nan
                    continue
                x0[:, k] = base[:, k] + step[k] * direction[:, k]
            if not np.any(active):
                break
        self._x0[:, converged] = x0[:, converged]
        return x0, converged

    def features_failed(self, jacobian: bool) -> PeriodicFeatures:
        """The features of a parameter vector without a steady state: NaN everywhere, nothing converged."""
        nan = np.full(self.n_exp, np.nan)
        full = np.full((self.n_exp, self.n_theta), np.nan)
        return PeriodicFeatures(H=nan + 0j, dc=nan, converged=np.zeros(self.n_exp, bool),
                                dH=full + 0j if jacobian else None, ddc=full if jacobian else None)

    def features(self, theta, jacobian: bool = False, max_passes: int = 30):
        """H, dc (and their derivatives with respect to θ) of the periodic steady state at ``theta``."""
        theta = np.asarray(theta, dtype=float).ravel()
        x0, converged = self.periodic_states(theta, max_passes)
        if not np.any(converged):
            return self.features_failed(jacobian)
        out = self._call(jacobian, x0, theta)
        if out is None:
            return self.features_failed(jacobian)
        qf = out[1]
        H = np.where(converged, self.scale * (qf[0] + 1j * qf[1]) / self.amplitudes, np.nan)
        dc = np.where(converged, self.scale * qf[2], np.nan)
        if not jacobian:
            return PeriodicFeatures(H=H, dc=dc, converged=converged)
        _, _, S, Sq = out
        dH = np.full((self.n_exp, self.n_theta), np.nan + 0j)
        ddc = np.full((self.n_exp, self.n_theta), np.nan)
        nx = self.nx
        for k in np.flatnonzero(converged):
            # implicit function theorem on x0 = Φ(x0, θ)
            dx0 = np.linalg.solve(np.eye(nx) - S[k][:, :nx], S[k][:, nx:])
            dq = Sq[k][:, :nx] @ dx0 + Sq[k][:, nx:]
            dH[k] = self.scale[k] * (dq[0] + 1j * dq[1]) / self.amplitudes[k]
            ddc[k] = self.scale[k] * dq[2]
        return PeriodicFeatures(H=H, dc=dc, converged=converged, dH=dH, ddc=ddc)


class _LazyDict(dict):
    """A dict that makes missing values with ``factory(key)``."""

    def __init__(self, factory):
        super().__init__()
        self.factory = factory

    def __missing__(self, key):
        self[key] = value = self.factory(key)
        return value


class CasadiCriterion:
    """The residuals of servofmu.identification.criterion.SineCriterion for one parameter vector, with their exact
    Jacobian."""

    def __init__(self, structure: Plant, data: SineData, options: NlsOptions = NlsOptions()):
        self.structure, self.data, self.options = structure, data, options
        self.steady = PeriodicSteadyState(structure, data.amplitudes, data.frequencies,
                                          scale=np.abs(data.H) * data.amplitudes, rtol=options.rtol)
        self.evaluations = 0

    def residuals(self, theta) -> np.ndarray:
        """Residual vector at ``theta`` (NaN for experiments without a stable periodic steady state)."""
        self.evaluations += 1
        f = self.steady.features(theta, False, self.options.steady_state_passes)
        return sine_residuals(self.data, f.H, f.dc)

    def residuals_and_jacobian(self, theta) -> tuple[np.ndarray, np.ndarray]:
        """The residuals at ``theta`` (as :meth:`residuals`) and their exact derivatives (residuals, p) from the
        CasADi sensitivities of the periodic steady state."""
        self.evaluations += 1
        f = self.steady.features(theta, True, self.options.steady_state_passes)
        return sine_residuals(self.data, f.H, f.dc), sine_residual_jacobian(self.data, f.dH, f.ddc)


# ---------------------------------------------------------------------------
# The fit
# ---------------------------------------------------------------------------
def _bounds(structure: Plant) -> tuple[np.ndarray, np.ndarray]:
    """Box of physically meaningful values: poles in the closed left half-plane (imaginary parts of pairs
    positive), friction levels non-negative; zeros and gains free."""
    names = identified_names(structure)
    lo, hi = np.full(len(names), -np.inf), np.full(len(names), np.inf)
    for i, n in enumerate(names):
        if n.startswith("pole") and not n.endswith("_im"):
            hi[i] = 0.0
        elif n.endswith("_im") or not n.startswith(("pole", "zero", "dc_gain", "gain")):
            lo[i] = 0.0
    return lo, hi


def _check_inputs(structure: Plant, data, theta0) -> np.ndarray:

    if not isinstance(data, SineData):
        raise UserError("the CasADi least-squares baseline fits stepped-sine data (first harmonics); "
                        "this data set has none")
    names = identified_names(structure)
    theta0 = np.asarray(structure.parameter_vector()[identified_mask(structure)] if theta0 is None else theta0,
                        dtype=float).ravel()
    if theta0.size != len(names):
        raise UserError(f"the start guess has {theta0.size} values; {structure.name} identifies {len(names)} "
                        f"({', '.join(names)})")
    if not valid_parameter_sets(structure, full_vectors(structure, theta0))[0]:
        raise UserError(f"the start guess {np.array2string(theta0, precision=6)} is not a valid plant "
                        f"({', '.join(names)}): non-finite, an unstable pole, a zero gain or negative friction")
    if 2 * data.amplitudes.size + data.amplitudes.size < len(names):
        raise UserError(f"{data.source}: {data.amplitudes.size} experiments give fewer residuals than the "
                        f"{len(names)} parameters to identify")
    return theta0


def fit_casadi_nls(structure: Plant, data: SineData, theta0: ArrayLike | None = None,
                   options: NlsOptions = NlsOptions(), progress: Progress | None = None) -> BaselineResult:
    """CasADi nonlinear least squares on the identifier's output-error residuals, with exact derivatives.

    Parameters
    ----------
    structure : Plant
        The structure identified.
    data : SineData
        Stepped-sine data (:func:`servofmu.sine_data`).
    theta0 : array_like, optional
        Start values in ``identified_names`` order; default: the structure's own values (the nominal plant).
    options : NlsOptions
        Method (Gauss–Newton or Ipopt), tolerances, iteration limit.
    progress : Progress, optional
        Called with (iterations done, max_iterations) after every Jacobian evaluation (Gauss–Newton only).

    Returns
    -------
    BaselineResult
        Identified parameters, the identifier's fitness at them, time and how the fit ended.

    Raises
    ------
    UserError
        For data that is not stepped-sine data, or start values of the wrong size or outside the valid region.
    """
    theta0 = _check_inputs(structure, data, theta0)
    start = time.perf_counter()
    crit = CasadiCriterion(structure, data, options)
    scale = np.where(theta0 != 0, np.abs(theta0), 1.0)  # parameters of O(1) for the optimiser
    lo, hi = _bounds(structure)
    if options.method == "ipopt":
        theta, iterations, success, message = _ipopt(crit, theta0, scale, lo, hi, options)
    else:
        theta, iterations, success, message = _gauss_newton(crit, theta0, scale, lo, hi, options, progress)
    evaluations = crit.evaluations
    fitness = output_error_fitness(structure, data, theta)
    if not np.isfinite(fitness):
        success, message = False, message + "; the identified plant has no steady state in some experiment"
    return BaselineResult(method=f"casadi-{options.method}", names=tuple(identified_names(structure)),
                          theta=theta, fitness=fitness, seconds=time.perf_counter() - start,
                          evaluations=evaluations, iterations=iterations, success=success, message=message)


def _gauss_newton(crit: CasadiCriterion, theta0, scale, lo, hi, options: NlsOptions, progress):
    from scipy.optimize import least_squares

    cache = {}
    count = [0]

    def evaluate(s):
        key = s.tobytes()
        if key not in cache:
            r, J = crit.residuals_and_jacobian(s * scale)
            ok = np.all(np.isfinite(r)) and np.all(np.isfinite(J))
            cache.clear()
            cache[key] = (r, J * scale[None]) if ok else (np.full(r.size, FAILED_RESIDUAL), np.zeros_like(J))
        return cache[key]

    def fun(s):
        return evaluate(s)[0]

    def jac(s):
        count[0] += 1
        if progress is not None:
            progress(count[0], options.max_iterations)
        return evaluate(s)[1]

    s0 = theta0 / scale
    r0 = fun(s0)
    if np.all(r0 == FAILED_RESIDUAL):
        return theta0, 0, False, "the start guess has no periodic steady state in some experiment"
    # ftol, gtol: just above machine precision — with exact data the cost falls to the integrator's noise floor
    sol = least_squares(fun, s0, jac=jac, bounds=(lo / scale, hi / scale), method="trf", x_scale=1.0,
                        xtol=options.tolerance, ftol=1e-15, gtol=1e-15, max_nfev=options.max_iterations)
    return sol.x * scale, int(sol.njev), bool(sol.status > 0), sol.message


def _ipopt(crit: CasadiCriterion, theta0, scale, lo, hi, options: NlsOptions):
    """Multiple shooting: w = [θ/scale, x0_1, …, x0_n]; min ½‖r(w)‖² s.t. Φ(x0_k; θ) − x0_k = 0, with the
    Gauss–Newton Hessian and first derivatives from the variational equations."""
    steady, data = crit.steady, crit.data
    n, nx, p = steady.n_exp, steady.nx, steady.n_theta
    x_start, converged = steady.periodic_states(theta0, options.steady_state_passes)
    if not np.all(converged):
        return theta0, 0, False, "the start guess has no periodic steady state in some experiment"

    s, X, none = ca.MX.sym("s", p), ca.MX.sym("X", nx, n), ca.MX.sym("p", 0)
    w = ca.vertcat(s, ca.vec(X))
    theta = s * ca.DM(scale)
    # residual row i·n + k = c[i, k]·q_i(experiment k) − d[i, k]  (i: Re H, Im H, dc), the affine map of
    # sine_residuals written for the quadratures q: H = (Re q_0 + j q_1)·scale/m, dc = q_2·scale
    zero, h = np.zeros(n), steady.scale / data.amplitudes
    d = -sine_residuals(data, zero + 0j, zero).reshape(3, n)
    c = np.vstack([sine_residual_jacobian(data, h + 0j, zero)[:n], sine_residual_jacobian(data, 1j * h, zero)[n:2 * n],
                   sine_residual_jacobian(data, zero + 0j, steady.scale)[2 * n:]])

    def residuals_and_gaps(xf, qf):
        return ca.vec((ca.DM(c) * qf[:3, :] - ca.DM(d)).T), ca.vec(xf[:nx, :] - X)

    r, g = residuals_and_gaps(*steady.symbolic_period(X, theta, "none"))
    xf, qf = steady.symbolic_period(X, theta, "all")
    r_j, g_j = residuals_and_gaps(xf, qf)
    cols = nx + p
    rows_r, rows_g = [], []
    for k in range(n):
        S = ca.reshape(xf[nx:, k], nx, cols)
        Sq = ca.reshape(qf[3:, k], 3, cols)
        before, after = ca.MX(nx, nx * k), ca.MX(nx, nx * (n - k - 1))
        rows_g.append(ca.horzcat(S[:, nx:] @ ca.diag(ca.DM(scale)), before, S[:, :nx] - ca.DM.eye(nx), after))
        for i in range(3):
            rows_r.append((i * n + k, c[i, k] * ca.horzcat(Sq[i, nx:] @ ca.diag(ca.DM(scale)), before[:1, :],
                                                           Sq[i, :nx], after[:1, :])))
    J_r = ca.vertcat(*[row for _, row in sorted(rows_r, key=lambda item: item[0])])
    J_g = ca.vertcat(*rows_g)
    lam_f, lam_g = ca.MX.sym("lam_f"), ca.MX.sym("lam_g", g.numel())
    functions = {
        "grad_f": ca.Function("grad_f", [w, none], [0.5 * ca.dot(r_j, r_j), J_r.T @ r_j], ["x", "p"], ["f", "grad"]),
        "jac_g": ca.Function("jac_g", [w, none], [g_j, J_g], ["x", "p"], ["g", "jac"]),
        "hess_lag": ca.Function("hess_lag", [w, none, lam_f, lam_g], [ca.triu(lam_f * (J_r.T @ J_r))],
                                ["x", "p", "lam_f", "lam_g"], ["hess"]),
    }
    solver = ca.nlpsol("nls", "ipopt", {"x": w, "f": 0.5 * ca.dot(r, r), "g": g}, {
        **functions, "print_time": False, "show_eval_warnings": False,
        "ipopt": {"print_level": 0, "sb": "yes", "tol": 100 * options.tolerance,
                  "max_iter": options.max_iterations}})
    w_lo = np.concatenate([lo / scale, np.full(nx * n, -np.inf)])
    w_hi = np.concatenate([hi / scale, np.full(nx * n, np.inf)])
    sol = solver(x0=np.concatenate([theta0 / scale, x_start.T.ravel()]), lbx=w_lo, ubx=w_hi, lbg=0, ubg=0)
    stats = solver.stats()
    crit.evaluations += sum(int(v) for k, v in stats.items() if k.startswith("n_call_"))
    theta = np.asarray(sol["x"], dtype=float).ravel()[:p] * scale
    return theta, int(stats.get("iter_count", 0)), bool(stats.get("success", False)), str(stats.get("return_status"))
