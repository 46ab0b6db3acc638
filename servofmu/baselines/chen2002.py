"""The "existing technique" of the paper: Chen, Huang & Yen (2002), two-magnitude describing-function identification.

Coulomb friction F(v) = F̄·sgn(v) + F_d (F̄ = (fc_pos + fc_neg)/2, F_d = (fc_pos − fc_neg)/2) acting on a
velocity v ≈ B + A·sin(ωt + φ) is replaced by its dual-input describing function: a sinusoid gain and a constant,

    N(A, B) = F̄·n(A, B),   n = (4/(πA))·sqrt(1 − B²/A²),      F_dc = F_d + F̄·(2/π)·asin(B/A).

With G_e = G/(1 + fv·G) (fv: the structure's fixed viscous friction), the first harmonic H = V1/U1 measured at
magnitude m, velocity amplitude A = |H|·m and mean velocity B satisfies

    1/H = 1/G_e(jω) + F̄·n(A, B)      (the same G_e(jω) at every magnitude of one frequency)
    B   = −G_e(0)·F_dc                 (the DC balance).

The method:
1. F̄: least squares over the frequencies of the real parts, after removing each frequency's own 1/G_e by
   centring over its magnitudes (with two magnitudes: Re(1/H1 − 1/H2) = F̄·(n1 − n2));
2. G(jω) = 1/(1/H − F̄·n − fv) at the highest magnitude of each frequency (the one least disturbed by stick-slip,
   where the describing function is best);
3. poles, zeros and gain of the structure fitted to G(jω): Levy's linear least squares refined by
   Sanathanan–Koerner iterations, then nonlinear least squares on the relative complex error;
4. F_d from the DC balance, averaged over the experiments, with the fitted G_e(0).

Only for Coulomb friction and stepped-sine data with two or more magnitudes at a frequency.  The describing
function ignores the higher harmonics and the sticking phases, so the method is biased where the excitation is
below about 4·Fc (stick-slip) — as in the paper's Table II (errors up to 25 %).
"""
from __future__ import annotations

import time

import numpy as np

from ..errors import UserError
from ..identification.criterion import SineData, output_error_fitness
from ..identification.prior import canonical_order, identified_names
from ..model.laws.registry import base_law
from ..model.plant import Plant
from . import BaselineResult

# The friction the method identifies: the simplest law's (Coulomb levels; fv and v_smooth are the structure's)
_COULOMB_KEYS = set(base_law().parameter_keys(lambda key: False))

__all__ = ["fit_chen2002", "describing_function"]


def describing_function(A, B) -> tuple[np.ndarray, np.ndarray]:
    """(n, d): sinusoid gain per unit F̄ and mean per unit F̄ of sgn(B + A·sin θ) (dual-input describing function).

    Where |B| ≥ A the velocity does not reverse: n = 0 and d = sgn(B)."""
    A, B = np.asarray(A, dtype=float), np.asarray(B, dtype=float)
    ratio = np.clip(B / A, -1.0, 1.0)
    return 4 / (np.pi * A) * np.sqrt(1 - ratio**2), 2 / np.pi * np.arcsin(ratio)


def _groups(data: SineData) -> list[np.ndarray]:
    """Indices of the experiments of each frequency measured at two or more magnitudes."""
    out = []
    for f in np.unique(data.frequencies):
        idx = np.flatnonzero(data.frequencies == f)
        if np.unique(data.amplitudes[idx]).size >= 2:
            out.append(idx)
    return out


def fit_chen2002(structure: Plant, data: SineData) -> BaselineResult:
    """Chen, Huang & Yen (2002): G(s) and Coulomb friction from two magnitudes by describing functions.

    Parameters
    ----------
    structure : Plant
        The structure identified (a Coulomb friction model).
    data : SineData
        Stepped-sine data at two or more magnitudes.

    Returns
    -------
    BaselineResult
        The identified parameters and the identifier's output-error fitness at them.

    Raises
    ------
    UserError
        For data that is not stepped-sine data or a structure the method cannot identify.
    """
    start = time.perf_counter()
    if not isinstance(data, SineData):
        raise UserError("the Chen 2002 method works on stepped-sine data (first harmonics at two magnitudes per "
                        "frequency); time-domain records cannot be used")
    if set(structure.friction.keys()) - _COULOMB_KEYS:
        beyond = ", ".join(k for k in structure.friction.keys() if k not in _COULOMB_KEYS)
        raise UserError(f"the Chen 2002 method identifies Coulomb friction only; {structure.name} has "
                        f"{structure.friction.model} friction ({beyond})")
    if structure.friction.symmetric:
        raise UserError(f"the Chen 2002 method estimates fc_pos and fc_neg apart; {structure.name}'s friction is "
                        "symmetric (friction.symmetric = true)")
    groups = _groups(data)
    names = identified_names(structure)
    n_linear = len(names) - 2  # poles, zeros, gain; then fc_pos, fc_neg
    if not groups:
        raise UserError(f"{data.source}: the Chen 2002 method needs a frequency measured (with a steady state) at "
                        f"two or more magnitudes; no frequency is")
    if 2 * len(groups) < n_linear:
        raise UserError(f"{data.source}: {len(groups)} frequencies measured at two magnitudes cannot determine the "
                        f"{n_linear} parameters of G(s) ({', '.join(names[:n_linear])})")
    fv = structure.friction.fv
    A = np.abs(data.H) * data.amplitudes
    B = data.dc
    n, d = describing_function(A, B)
    inv_H = 1 / data.H

    # 1. F̄ from the magnitude dependence of Re(1/H) at each frequency
    y = np.concatenate([inv_H[g].real - inv_H[g].real.mean() for g in groups])
    x = np.concatenate([n[g] - n[g].mean() for g in groups])
    if not np.any(x != 0):
        raise UserError(f"{data.source}: the responses at the different magnitudes do not differ: the friction "
                        f"cannot be separated from G(s)")
    f_bar = float(np.dot(x, y) / np.dot(x, x))

    # 2. G(jω) at the highest magnitude of each frequency
    top = np.array([g[np.argmax(data.amplitudes[g])] for g in groups])
    omega = 2 * np.pi * data.frequencies[top]
    G = 1 / (inv_H[top] - f_bar * n[top] - fv)

    # 3. poles, zeros and gain fitted to G(jω)
    linear, iterations, fit_ok = _fit_transfer_function(structure, omega, G)

    # 4. F_d from the DC balance B = −G_e(0)·(F_d + F̄·d) over the experiments of the used frequencies
    used = np.concatenate(groups)
    num, den = _polynomials(structure, linear)
    if num[-1] == 0:
        raise UserError(f"{structure.name}: G(s) has a zero at s = 0, so the mean velocity carries no "
                        f"information on the friction asymmetry (fc_pos − fc_neg)")
    inv_G0 = den[-1] / num[-1] + fv  # 1/G_e(0); 0 for an integrating plant without viscous friction
    f_d = float(np.mean(-B[used] * inv_G0 - f_bar * d[used]))

    theta = canonical_order(structure, np.concatenate([linear, [f_bar + f_d, f_bar - f_d]]))[0]
    valid = bool(np.all(np.isfinite(theta)) and f_bar - abs(f_d) >= 0)
    message = ("describing-function solution" if valid else
               f"the describing function gives negative friction (F̄ = {f_bar:.4g}, F_d = {f_d:.4g})")
    if not fit_ok:
        message += "; the transfer-function fit did not converge"
    fitness = output_error_fitness(structure, data, theta)
    return BaselineResult(method="chen2002", names=tuple(names), theta=theta, fitness=fitness,
                          seconds=time.perf_counter() - start, evaluations=0, iterations=iterations,
                          success=valid and fit_ok, message=message)


# ---------------------------------------------------------------------------
# Fitting the structure's G(s) to a frequency response
# ---------------------------------------------------------------------------
def _polynomials(structure: Plant, linear: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(num, den) of the structure with linear parameters ``linear`` (poles, zeros, gain)."""
    friction = structure.parameter_vector()[len(linear):]
    return structure.with_parameters(np.concatenate([linear, friction])).transfer_function()


def _levy(omega: np.ndarray, G: np.ndarray, n_pole: int, n_zero: int, iterations: int = 20):
    """Real num (degree n_zero) and monic den (degree n_pole) with num/den ≈ G at jω: Levy's linear least
    squares, re-weighted by the last denominator (Sanathanan–Koerner) until it settles."""
    s = 1j * omega
    weight = np.ones_like(omega)
    den = None
    for _ in range(iterations):
        # num(s) − G·(den(s) − sⁿ) = G·sⁿ, unknowns b_nz..b_0 and a_(n−1)..a_0
        cols = [s ** k for k in range(n_zero, -1, -1)] + [-G * s ** k for k in range(n_pole - 1, -1, -1)]
        M = np.column_stack(cols) * weight[:, None]
        rhs = G * s ** n_pole * weight
        coef = np.linalg.lstsq(np.vstack([M.real, M.imag]), np.concatenate([rhs.real, rhs.imag]), rcond=None)[0]
        num, new = coef[:n_zero + 1], np.concatenate([[1.0], coef[n_zero + 1:]])
        if den is not None and np.allclose(new, den, rtol=1e-12, atol=0):
            break
        den = new
        weight = 1 / np.abs(np.polyval(den, s))
    return num, den


def _to_template(roots: np.ndarray, template) -> list[float]:
    """Parameters (re[, im] per distinct root) for ``template``'s pattern of real roots and complex pairs from
    estimated ``roots`` — complex pairs from the most oscillatory estimates, real roots from the rest (a start
    for the nonlinear fit, which sorts out the rest)."""
    upper = sorted([r for r in roots if r.imag > 0], key=lambda r: -r.imag)
    reals = sorted([r.real for r in roots if r.imag == 0])
    n_pairs = sum(1 for r in template if r.imag != 0)
    pairs = upper[:n_pairs]
    for r in upper[n_pairs:]:  # more oscillatory estimates than pairs: split into two real roots
        reals += [r.real - abs(r.imag), r.real + abs(r.imag)]
    reals.sort()
    while len(pairs) < n_pairs:  # fewer: merge the two closest real roots into a pair
        if len(reals) >= 2:
            i = int(np.argmin(np.diff(reals)))
            a, b = reals.pop(i), reals.pop(i)
            pairs.append(complex((a + b) / 2, max(abs(b - a) / 2, 1e-3 * abs(a + b) / 2 + 1e-9)))
        else:
            pairs.append(complex(-1.0, 1.0))
    pairs_it, reals_it = iter(pairs), iter(sorted(reals, reverse=True))
    out = []
    for r in template:
        if r.imag != 0:
            p = next(pairs_it)
            out += [p.real, p.imag]
        else:
            out.append(next(reals_it, -1.0))
    return out


def _fit_transfer_function(structure: Plant, omega: np.ndarray, G: np.ndarray) -> tuple[np.ndarray, int, bool]:
    """Linear parameters (poles, zeros, gain in identified_names order) of ``structure`` fitted to G(jω);
    also the nonlinear fit's evaluations and whether it converged."""
    from scipy.optimize import least_squares

    n_pole, n_zero = len(structure.all_poles()), len(structure.all_zeros())
    num, den = _levy(omega, G, n_pole, n_zero)
    k = num[0] if n_zero else num[-1]
    if not (np.isfinite(k) and k != 0):
        k = 1.0
    poles = _to_template(np.roots(den), structure.poles)
    zeros = _to_template(np.roots(num), structure.zeros) if n_zero else []
    if structure.dc_gain is not None:
        gain = float(num[-1] / den[-1]) if den[-1] != 0 and num[-1] != 0 else 1.0
    else:
        gain = float(k)
    x0 = np.array(poles + zeros + [gain], dtype=float)
    friction = structure.parameter_vector()[x0.size:]
    scale = np.where(x0 != 0, np.abs(x0), 1.0)

    def residual(x):
        model = structure.with_parameters(np.concatenate([x * scale, friction])).frequency_response(omega)
        e = (model - G) / np.abs(G)
        return np.concatenate([e.real, e.imag])

    sol = least_squares(residual, x0 / scale, method="lm", xtol=1e-15, ftol=1e-15, gtol=1e-15, max_nfev=2000)
    return sol.x * scale, int(sol.nfev), bool(sol.status > 0)
