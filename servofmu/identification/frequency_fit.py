"""The frequency-domain fit of G(s) to the best linear approximation (docs/broadband.md, "Fitting G(s)").

A weighted nonlinear least-squares estimator, the frequency-domain maximum-likelihood estimator of Pintelon &
Schoukens (ch. 9) with the BLA's own variances as the noise model: for the parameters θ of G (the structure's
poles, zeros and gain, in the identifier's names), the residual of every excited line k of every level is

    e_k(θ) = (G_model(θ, ω_k) − G_BLA,k) / σ_k,    σ²_k the BLA's total variance (noise and distortions),

split into real and imaginary parts (each × √2: unit variance), and V(θ) = Σ |e_k|² is minimised by
scipy.optimize.least_squares.  G_model is what a broadband measurement sees of the plant without friction: the
linear part of v = G·(u − fv·v − k·x) (viscous friction and a spring, both fixed by the structure) sampled as a
drive samples it — the zero-order-hold response C(e^{jωT}I − A_d)⁻¹B_d, not G(jω) (servofmu.broadband.measure).

Start: a Sanathanan–Koerner iteration (linear least squares on N(s) − G·D(s), reweighted by 1/|D|) on the BLA
with the hold's first term e^{−jωT/2}·sinc(ωT/2) divided out, its roots matched to the structure's (which are real,
which complex); the structure's own G is tried too and the lower cost kept.

Weights: a line's variance estimated from M realisations has only 2(M − 1) degrees of freedom (6 for M = 4); weighted
by it, the fit loses efficiency and its intervals the scatter of the weights (over 100 seeds of a linear g2 at
40 dB, M = 4: 61–80 % coverage of the truth by nominal 95 % intervals).  The variance is smooth in frequency (the
noise's spectrum over the input's, flat for a multisine), so it is averaged over SMOOTH_LINES neighbouring lines
first (42 degrees of freedom for M = 4; the same study: 94–97 %).  Covariance (JᵀJ)⁻¹ of the weighted residuals
(J their Jacobian), times V/(2K − p) where that exceeds 1 (a model error); intervals θ ± t(0.95, 2K − p)·σ_θ.

Friction is not in G_model: with friction the BLA is not G's response but the best linear approximation of the
whole nonlinear plant at that level, and the fit's G is biased towards it (a lower gain, poles moved; the more so the
lower the level: scripts/bench_fdfit.py).  One level's cost does not show it — its BLA is a linear system
and the variance it is weighted by holds the distortions — but the BLA's change from level to level does: fitted
jointly, two levels of a plant with friction give ``cost_ratio`` (V over its degrees of freedom) far above 1, a
linear plant about 1.  The distortion level (servofmu frf) is the direct measure.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from ..errors import UserError
from ..model.plant import Plant, root_names
from .prior import identified_names
from .student_t import t_quantile

__all__ = ["FrequencyFit", "fit_bla", "linear_response", "g_names", "WEIGHT_FLOOR"]

# relative floor of a line's standard deviation: noise-free data (σ ≈ 1e-16·|G|) stays weighted by its lines' sizes
WEIGHT_FLOOR = 1e-10
SK_ITERATIONS = 20
# lines a variance is averaged over: one line's estimate from M realisations has 2(M − 1) degrees of freedom
# (6 for M = 4), too few to weight by (the weights' scatter costs efficiency and their heavy tail the intervals)
SMOOTH_LINES = 7


@dataclass(frozen=True)
class FrequencyFit:
    """A fit of G to BLAs: ``names`` (G's identified parameters), ``theta``, ``covariance`` (p, p), ``intervals``
    (p, 2; 95 %), ``cost`` V, ``dof`` 2K − p, ``cost_ratios`` V/dof of each level's lines (in the order the BLAs
    were given), ``weights`` ("total", "noise" or "relative": which variance weighted the lines), ``start``
    ("linear" or "structure": where the kept fit started), ``plant`` (the structure with the fitted G),
    ``relative_error`` (‖G_model − G_BLA‖/‖G_BLA‖ over the lines) and ``evaluations`` (of the model)."""

    names: tuple[str, ...]
    theta: np.ndarray
    covariance: np.ndarray
    intervals: np.ndarray
    cost: float
    dof: int
    cost_ratios: tuple[float, ...]
    weights: str
    start: str
    plant: Plant
    relative_error: float
    evaluations: int

    @property
    def cost_ratio(self) -> float:
        """V over its degrees of freedom, all levels together."""
        return self.cost / self.dof


def g_names(structure: Plant) -> list[str]:
    """The identified parameters of G (poles, zeros, gain), in identified_names order."""
    count = len(root_names("pole", structure.poles)) + len(root_names("zero", structure.zeros)) + 1
    own = set(structure.parameter_names()[:count])
    return [n for n in identified_names(structure) if n in own]


def _roots(values: dict, prefix: str, template) -> list[complex]:
    out = []
    for name, r in zip(range(1, len(template) + 1), template):
        if r.imag != 0:
            z = complex(values[f"{prefix}{name}_re"], values[f"{prefix}{name}_im"])
            out += [z, z.conjugate()]
        else:
            out.append(complex(values[f"{prefix}{name}"]))
    return out


def _linear_part(structure: Plant, full: np.ndarray):
    """(poles, residues) of the plant's linear part without friction: G/(1 + (fv + k/s)·G)."""
    values = dict(zip(structure.parameter_names(), full))
    poles, zeros = _roots(values, "pole", structure.poles), _roots(values, "zero", structure.zeros)
    if structure.gain_key == "gain":
        K = values["gain"]
    else:
        K = values["dc_gain"] * np.prod([-p for p in poles]).real / (np.prod([-z for z in zeros]).real
                                                                     if zeros else 1.0)
    fv, k = values.get("fv", 0.0) or 0.0, values.get("stiffness", 0.0) or 0.0
    num = K * (np.real(np.poly(zeros)) if zeros else np.ones(1))
    if fv == 0 and k == 0:
        p = np.asarray(poles, complex)
        residues = np.array([np.polyval(num, pi) / np.prod([pi - q for j, q in enumerate(p) if j != i])
                             for i, pi in enumerate(p)])
        return p, residues
    den = np.real(np.poly(poles))
    if k:
        num, den = np.polymul(num, [1.0, 0.0]), np.polyadd(np.polymul(den, [1.0, 0.0]), np.polymul(num, [fv, k]))
    else:
        den = np.polyadd(den, fv * num)
    p = np.roots(den)
    return p, np.polyval(num, p) / np.polyval(np.polyder(den), p)


def linear_response(structure: Plant, full: np.ndarray, frequencies: np.ndarray, rate: float | None) -> np.ndarray:
    """The response at ``frequencies`` (Hz) of the linear part of the plant of the parameter vector ``full`` (all
    of ``structure.parameter_names()``), friction left out: sampled at ``rate`` with the input held between samples
    (the zero-order-hold response a broadband measurement gives), or G(jω) itself for ``rate`` None."""
    p, c = _linear_part(structure, np.asarray(full, float))
    w = 2 * np.pi * np.asarray(frequencies, float)
    if rate is None:
        return np.sum(c[:, None] / (1j * w[None] - p[:, None]), axis=0)
    T = 1.0 / rate
    a = np.exp(p * T)
    with np.errstate(divide="ignore", invalid="ignore"):
        b = np.where(np.abs(p * T) > 1e-12, np.expm1(p * T) / p, T)
    z = np.exp(1j * w * T)
    return np.sum((c * b)[:, None] / (z[None] - a[:, None]), axis=0)


def _smoothed(var: np.ndarray) -> np.ndarray:
    """The variance averaged over SMOOTH_LINES neighbouring lines (fewer at the band's edges)."""
    half = SMOOTH_LINES // 2
    padded = np.concatenate([[0.0], np.cumsum(var)])
    lo = np.clip(np.arange(var.size) - half, 0, var.size)
    hi = np.clip(np.arange(var.size) + half + 1, 0, var.size)
    return (padded[hi] - padded[lo]) / (hi - lo)


def _weights(blas) -> tuple[list[np.ndarray], str]:
    """Per BLA the standard deviation of each line (its variance smoothed over neighbouring lines), and which
    variance it is."""
    for kind, attr in (("total", "var_total"), ("noise", "var_noise")):
        vars_ = [np.asarray(getattr(b, attr), float) for b in blas]
        if all(np.all(np.isfinite(v)) for v in vars_):
            return [np.sqrt(np.maximum(_smoothed(np.clip(v, 0, None)), (WEIGHT_FLOOR * np.abs(b.G)) ** 2))
                    for v, b in zip(vars_, blas)], kind
    return [np.abs(b.G) for b in blas], "relative"


def _sk_start(structure: Plant, f: np.ndarray, G: np.ndarray, sigma: np.ndarray, rate: float | None):
    """G's parameters from a Sanathanan–Koerner fit (None when its roots are not of the structure's kinds)."""
    values = dict(zip(structure.parameter_names(), structure.parameter_vector()))
    if values.get("stiffness"):
        return None
    w = 2 * np.pi * f
    if rate is not None:  # the hold's main term divided out
        G = G * np.exp(1j * w / (2 * rate)) / np.sinc(w / (2 * np.pi * rate))
    n, m = len(structure.all_poles()), len(structure.all_zeros())
    scale = float(np.max(w))
    s = 1j * w / scale
    weight = 1.0 / sigma
    den = np.ones_like(s)
    for _ in range(SK_ITERATIONS):
        cols = [s ** j for j in range(m + 1)] + [-G * s ** j for j in range(n)]
        A = np.stack(cols, axis=1) * (weight / np.abs(den))[:, None]
        rhs = G * s ** n * weight / np.abs(den)
        x = np.linalg.lstsq(np.vstack([A.real, A.imag]), np.concatenate([rhs.real, rhs.imag]), rcond=None)[0]
        d = np.concatenate([[1.0], x[m + 1:][::-1]])
        den = np.polyval(d, s)
    num_s = x[:m + 1][::-1] * scale ** (n - np.arange(m, -1, -1))  # N(s) with D(s) monic in s
    den_s = d * scale ** np.arange(0, n + 1)
    den_s = np.polysub(den_s, (values.get("fv") or 0.0) * num_s)  # G's denominator: D_H − fv·N_H
    return _match(structure, np.roots(den_s), np.roots(num_s) if m else np.zeros(0), num_s, den_s)


def _match(structure: Plant, poles, zeros, num, den):
    """The identified values of G from roots and polynomials, or None when the roots are of other kinds."""
    out = {}
    for prefix, template, found in (("pole", structure.poles, poles), ("zero", structure.zeros, zeros)):
        tol = 1e-9 * max(1.0, float(np.max(np.abs(found)))) if len(found) else 0.0
        pairs = sorted((r for r in found if r.imag > tol), key=abs)
        reals = sorted((r.real for r in found if abs(r.imag) <= tol), reverse=True)
        if len(pairs) != sum(r.imag != 0 for r in template) or len(reals) != sum(r.imag == 0 for r in template):
            return None
        for i, r in enumerate(template, start=1):
            if r.imag != 0:
                z = pairs.pop(0)
                out[f"{prefix}{i}_re"], out[f"{prefix}{i}_im"] = z.real, z.imag
            else:
                out[f"{prefix}{i}"] = reals.pop(0)
    if structure.gain_key == "gain":
        out["gain"] = float(num[0])
    else:
        out["dc_gain"] = float(np.polyval(num, 0.0) / np.polyval(den, 0.0)) if np.polyval(den, 0.0) else math.nan
    return out


def _canonical(names: list[str], theta: np.ndarray, cov: np.ndarray):
    """Real roots in descending order (as every identification stores them), the covariance permuted alike."""
    perm = np.arange(len(names))
    for prefix in ("pole", "zero"):
        cols = [i for i, n in enumerate(names) if n.startswith(prefix) and "_" not in n]
        perm[cols] = np.array(cols)[np.argsort(-theta[cols], kind="stable")]
    return theta[perm], cov[np.ix_(perm, perm)]


def _residuals(structure, names, blas, sigmas, rate):
    """The weighted residuals' function of G's parameters (real and imaginary parts of every line, × √2/σ)."""
    base = structure.parameter_vector()
    at = [structure.parameter_names().index(n) for n in names]
    G = np.concatenate([b.G for b in blas])
    f = np.concatenate([b.frequencies for b in blas])
    scale = np.sqrt(2.0) / np.concatenate(sigmas)

    def fun(x):
        full = base.copy()
        full[at] = x
        with np.errstate(all="ignore"):  # a pole on a line's point of the unit circle, or overflowing: not finite
            e = (linear_response(structure, full, f, rate) - G) * scale
        return np.concatenate([e.real, e.imag])

    return fun


def _jacobian(fun, x):
    """Central differences (the covariance's; the search uses least_squares' own)."""
    h = 1e-6 * np.maximum(np.abs(x), 1e-8)
    cols = [(fun(x + hi) - fun(x - hi)) / (2 * hi[i]) for i, hi in enumerate(np.diag(h))]
    return np.stack(cols, axis=1)


def _covariance(J: np.ndarray, r: np.ndarray) -> np.ndarray:
    """(JᵀJ)⁻¹ scaled by V/(2K − p) when above 1 (a model error: the residuals exceed their variances)."""
    s2 = float(np.sum(r ** 2)) / max(r.size - J.shape[1], 1)
    return np.linalg.pinv(J.T @ J) * max(1.0, s2)


def fit_bla(structure: Plant, blas, rate: float | None) -> FrequencyFit:
    """Fit G's poles, zeros and gain to one or more BLAs (module docstring).

    Parameters
    ----------
    structure : Plant
        Orders, which roots are complex, the gain's key, the fixed fv (and spring); its G is one of the starts.
    blas : sequence of BLA
        The BLAs (servofmu.broadband.estimate_bla), e.g. one per RMS level, fitted jointly.
    rate : float or None
        The sample rate (Hz) of the measurement (the model is the zero-order-hold response), None for G(jω).

    Returns
    -------
    FrequencyFit
        G's parameters, covariance, 95 % intervals and costs.

    Raises
    ------
    UserError
        When the BLAs hold fewer real numbers than G has parameters, or no start gives a finite cost.
    """
    from scipy.optimize import least_squares

    names = g_names(structure)
    blas = list(blas)
    lines = sum(b.frequencies.size for b in blas)
    if 2 * lines <= len(names):
        raise UserError(f"the BLA has {lines} lines: too few for the {len(names)} parameters of G "
                        f"({', '.join(names)})")
    sigmas, kind = _weights(blas)
    fun = _residuals(structure, names, blas, sigmas, rate)
    nominal = dict(zip(structure.parameter_names(), structure.parameter_vector()))
    starts = {"structure": np.array([nominal[n] for n in names])}
    sk = _sk_start(structure, np.concatenate([b.frequencies for b in blas]), np.concatenate([b.G for b in blas]),
                   np.concatenate(sigmas), rate)
    if sk is not None and all(np.isfinite(sk.get(n, math.nan)) for n in names):
        starts["linear"] = np.array([sk[n] for n in names])
    best, evaluations = None, 0
    for label, x0 in starts.items():
        if not np.all(np.isfinite(fun(x0))):
            continue
        sol = least_squares(fun, x0, x_scale="jac", xtol=1e-14, ftol=1e-14, gtol=1e-14, max_nfev=400 * len(names))
        evaluations += sol.nfev + sol.njev * len(names)
        if np.all(np.isfinite(sol.fun)) and (best is None or sol.cost < best[1].cost):
            best = (label, sol)
    if best is None:
        raise UserError("the frequency-domain fit of G found no start with a finite response (check the structure)")
    label, sol = best
    r = fun(sol.x)
    J = _jacobian(fun, sol.x)
    theta, cov = _canonical(names, sol.x, _covariance(J, r))
    dof = max(r.size - len(names), 1)
    half = t_quantile(0.95, dof) * np.sqrt(np.clip(np.diag(cov), 0, None))
    bounds = np.cumsum([0] + [b.frequencies.size for b in blas])
    k = lines
    ratios = tuple(float((np.sum(r[a:b] ** 2) + np.sum(r[k + a:k + b] ** 2)) / max(2 * (b - a), 1))
                   for a, b in zip(bounds[:-1], bounds[1:]))
    full = structure.parameter_vector()
    full[[structure.parameter_names().index(n) for n in names]] = theta
    G = np.concatenate([b.G for b in blas])
    model = linear_response(structure, full, np.concatenate([b.frequencies for b in blas]), rate)
    return FrequencyFit(names=tuple(names), theta=theta, covariance=cov,
                        intervals=np.stack([theta - half, theta + half], axis=1), cost=float(np.sum(r ** 2)),
                        dof=dof, cost_ratios=ratios, weights=kind, start=label,
                        plant=structure.with_parameters(full), evaluations=int(evaluations + 2 * len(names)),
                        relative_error=float(np.linalg.norm(model - G) / np.linalg.norm(G)))
