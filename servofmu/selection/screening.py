"""What a screened candidate could still reach: the lowest −2·ln L a full polish could give from its screening fit,
by the Gauss–Newton model of the search's last Jacobian (docs/selection.md, screening)."""
from __future__ import annotations

import math

import numpy as np

from ..identification.criterion import SineData
from ..identification.roughness import neg2loglik

__all__ = ["screen_bound", "screening_jacobian"]


def screening_jacobian(jacobian, crit, data) -> tuple[np.ndarray | None, np.ndarray]:
    """The search's Jacobian of the criterion's residuals and the weight of each of its rows, in the rows of the
    output errors a selection scores (select._signal_errors): per signal its scale (records), the response phasors' rows with |H| each
    (stepped sines; their mean velocities are not among the errors)."""
    if jacobian is None:
        return None, np.ones(0)
    if isinstance(data, SineData):
        scale = np.abs(data.H).ravel()
        return jacobian[:2 * scale.size], np.concatenate([scale, scale])
    return jacobian, np.concatenate([np.full(n, s) for n, s in zip(
        [b.stop - b.start for b in crit.blocks], crit.scales)]) if crit.blocks is not None else np.ones(0)


def screen_bound(jacobian: np.ndarray, weights: np.ndarray, errors: list[np.ndarray]) -> float:
    """The lowest −2·ln L a polish could reach from a fit by the Gauss–Newton model: every signal's RSS after one
    full Gauss–Newton step on its output errors (``errors`` at the fit; ``jacobian`` the polish's last, of the
    residuals weighted by 1/``weights`` row by row, in any coordinates).  At a converged fit it is the fit's own
    −2·ln L less a fraction of one; far from a minimum, what the linearised model promises there."""
    r = np.concatenate(errors)
    if jacobian is None or not (np.all(np.isfinite(r)) and np.all(np.isfinite(jacobian))) or \
            jacobian.shape[0] != r.size or weights.size != r.size:
        return -math.inf  # no Jacobian to bound it by: it could be anything
    jac = jacobian * weights[:, None]
    step = np.linalg.lstsq(jac, r, rcond=None)[0]
    left = r - jac @ step
    sizes = np.cumsum([x.size for x in errors])[:-1]
    return neg2loglik(np.split(left, sizes))[0]
