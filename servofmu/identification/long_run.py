"""The long-run covariance of least squares whose residuals are correlated in time (a record's noise filtered by
a loop, a quantiser's error): Newey–West's sandwich on leave-one-segment-out residuals, its bandwidth and its
degrees of freedom — what servofmu.identification.criterion's intervals of time-domain fits are made from."""
from __future__ import annotations

import numpy as np

__all__ = ["bartlett_lags", "long_run_dof", "newey_west_covariance", "SEGMENT_GRIDS"]

SEGMENT_GRIDS = 4  # grids of segments (offset by a quarter segment) whose Newey–West estimates are averaged


def bartlett_lags(r: np.ndarray) -> int:
    """The Newey–West bandwidth L of residuals ``r`` (one signal, consecutive samples) by Andrews's (1991) AR(1)
    plug-in rule from their lag-1 autocorrelation ρ: L = ⌈1.1447·(α·n)^(1/3)⌉, α = 4ρ²/((1−ρ)²(1+ρ)²)."""
    n = r.size
    rho = float(np.clip(r[1:] @ r[:-1] / max(r @ r, 1e-300), -0.97, 0.97))
    alpha = 4 * rho**2 / ((1 - rho) ** 2 * (1 + rho) ** 2)
    return max(min(int(np.ceil(1.1447 * (alpha * n) ** (1 / 3))), n - 1), 0)


def _groups(blocks: list[slice], concurrent: list[tuple[int, ...]] | None) -> list[list[slice]]:
    """The blocks in their groups of signals sampled together (each block alone without ``concurrent``)."""
    return [[blocks[k] for k in group] for group in concurrent or [(k,) for k in range(len(blocks))]]


def long_run_dof(r: np.ndarray, blocks: list[slice], concurrent: list[tuple[int, ...]] | None = None) -> int:
    """The degrees of freedom of :func:`newey_west_covariance`: about 1.5·n/L independent pieces of information per
    group of n samples and bandwidth L (the equivalent degrees of freedom of a Bartlett estimate at frequency 0,
    Priestley 1981) — far fewer than n − p when the residuals are strongly coloured."""
    total = sum(1.5 * (parts[0].stop - parts[0].start) / max(max(bartlett_lags(r[b]) for b in parts), 1)
                for parts in _groups(blocks, concurrent))
    return max(int(total), 1)


def newey_west_covariance(r: np.ndarray, jac: np.ndarray, blocks: list[slice],
                          concurrent: list[tuple[int, ...]] | None = None) -> np.ndarray:
    """The sandwich (JᵀJ)⁻¹ Ω (JᵀJ)⁻¹ of least squares whose residuals may be correlated in time within each block
    (Newey & West 1987), and between the blocks of a group in ``concurrent`` (signals sampled at the same instants,
    e.g. a closed loop's position and command: their scores are summed sample by sample; default: every block
    alone).  Ω sums the scores g_t = J_t·r_t and their lagged products with Bartlett weights 1 − l/(L+1); the
    bandwidth L is :func:`bartlett_lags`'s, the largest of the group's signals.

    The scores are taken on the residuals each segment of L+1 samples (all the group's signals) would have had
    in a fit without it, r_S + J_S (JᵀJ − J_SᵀJ_S)⁻¹ J_Sᵀ r_S: the leave-one-segment-out residuals (the jackknife's,
    the time-series counterpart of HC3), averaged over :data:`SEGMENT_GRIDS` grids of segments offset by a
    fraction of a segment (where the segments begin is arbitrary, and one event — a fast move, a reversal — split
    or not changes a single grid's estimate).  A fit absorbs the part of the noise that its parameters can explain;
    for white noise that is p of n samples' worth, but coloured noise has few degrees of freedom where its power
    is (a closed loop's position error is noise filtered to the loop's bandwidth), and the parameters may take up
    much of it — in the fit's own residuals the scores then look up to 3 times smaller than they are
    (docs/bench-quantiser.md).  For white residuals L is 1-2, the segments hold a few samples, and the estimate
    is s²(JᵀJ)⁻¹ up to O(p/n)."""
    gram = jac.T @ jac
    bread = np.linalg.pinv(gram)
    omega = np.zeros_like(bread)
    for parts in _groups(blocks, concurrent):
        n = parts[0].stop - parts[0].start
        lags = max(bartlett_lags(r[b]) for b in parts)
        span = lags + 1
        plain = 0.0
        for b in parts:
            plain = plain + jac[b] * r[b, None]
        offsets = sorted({k * span // SEGMENT_GRIDS for k in range(SEGMENT_GRIDS)})
        for offset in offsets:
            g = plain.copy()  # the scores on the leave-one-segment-out residuals of this grid of segments
            edges = [0] + list(range(offset or span, n, span)) + [n]
            # the segments of a whole span at once (a batch of p×p pseudo-inverses: a 6·10⁵-sample record has
            # 3·10⁵ two-sample segments per grid), the first and last, shorter, one by one
            whole = [(a, b) for a, b in zip(edges[:-1], edges[1:]) if b - a == span]
            if whole:
                _shift_segments(g, jac, r, gram, parts, whole[0][0], whole[-1][1], span)
            for start, stop in zip(edges[:-1], edges[1:]):
                if stop - start != span:
                    _shift_segments(g, jac, r, gram, parts, start, stop, stop - start)
            weight = 1 / len(offsets)
            omega += weight * (g.T @ g)
            for lag in range(1, lags + 1):
                gamma = g[lag:].T @ g[:-lag]
                omega += weight * (1 - lag / (lags + 1)) * (gamma + gamma.T)
    return bread @ omega @ bread


def _shift_segments(g: np.ndarray, jac: np.ndarray, r: np.ndarray, gram: np.ndarray, parts: list[slice], start: int,
                    stop: int, span: int) -> None:
    """Add to the scores ``g`` (of a group's samples start..stop, consecutive segments of ``span``) each segment's
    leave-it-out shift J_S·(JᵀJ − J_SᵀJ_S)⁻¹·J_Sᵀr_S, every block of ``parts`` sharing its segment's refit."""
    count, p = (stop - start) // span, jac.shape[1]
    js = [jac[b.start + start:b.start + stop].reshape(count, span, p) for b in parts]
    rs = [r[b.start + start:b.start + stop].reshape(count, span) for b in parts]
    jtj = sum(np.einsum("nsp,nsq->npq", j, j) for j in js)
    jtr = sum(np.einsum("nsp,ns->np", j, e) for j, e in zip(js, rs))
    coef = np.einsum("npq,nq->np", _inverses(gram - jtj), jtr)
    for j in js:
        d = np.einsum("nsp,np->ns", j, coef)
        g[start:stop] += (j * d[..., None]).reshape(-1, p)


def _inverses(a: np.ndarray) -> np.ndarray:
    """The inverses of a batch of matrices (LU, faster than the SVD), their pseudo-inverses where one is singular or
    so ill-conditioned that its inverse does not reproduce the identity (a segment whose removal leaves a parameter
    unseen)."""
    with np.errstate(all="ignore"):
        try:
            out = np.linalg.inv(a)
        except np.linalg.LinAlgError:
            return np.linalg.pinv(a)
        error = np.abs(np.einsum("npq,nqr->npr", a, out) - np.eye(a.shape[-1]))
        bad = ~np.all(np.isfinite(out), axis=(1, 2)) | ~(error.max(axis=(1, 2)) <= 1e-8)
    if np.any(bad):
        out[bad] = np.linalg.pinv(a[bad])
    return out
