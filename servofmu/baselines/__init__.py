"""Stage 6, baselines: identifiers to compare PSO-ANN against (docs/identification.md), and the comparison
of every method on the same data (compare):

- :mod:`servofmu.baselines.casadi_nls`: nonlinear least squares on the same output-error residuals, with exact
  derivatives from the CasADi model (the periodic steady state of each experiment by Newton on the period map);
- :mod:`servofmu.baselines.chen2002`: the two-magnitude describing-function method of Chen, Huang & Yen (2002).

Both return a :class:`BaselineResult`.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING

from ..display import Shown, figure, parameter_figures, shown_html, shown_repr

if TYPE_CHECKING:  # this package is imported by the command line's parser: no numerical imports here
    import numpy as np

    from ..model.plant import Plant

__all__ = ["BaselineResult", "BASELINE_METHODS", "BASELINE_NEEDS_ANN"]

BASELINE_METHODS = ("chen2002", "casadi-nls-ann", "casadi-nls")
BASELINE_NEEDS_ANN = ("casadi-nls-ann",)  # least squares started from the ANN's estimate


@dataclass(frozen=True)
class BaselineResult:
    """The outcome of one baseline identification.

    ``theta``: identified parameters in ``names`` order (servofmu.identification.prior.identified_names);
    ``fitness``: the RMS of the output-error residuals of servofmu.identification.criterion.SineCriterion at
    ``theta`` (inf when the identified plant is invalid or has no steady state in some experiment); ``seconds``: wall time, the fitness included;
    ``evaluations``: evaluations of the output-error residuals (each simulates every experiment; for the least
    squares with their Jacobian; 0 for Chen 2002, which simulates nothing); ``iterations``: optimiser iterations
    (for Chen 2002 those of its transfer-function fit); ``success``: the method ended as it should (converged,
    or a physically valid direct solution); ``message``: how it ended.
    """

    method: str
    names: tuple[str, ...]
    theta: np.ndarray
    fitness: float
    seconds: float
    evaluations: int
    iterations: int
    success: bool
    message: str

    def plant(self, structure: Plant) -> Plant:
        """The identified plant (``structure`` with ``theta``; fixed parameters from the structure)."""
        from ..identification.prior import full_vectors

        return structure.with_parameters(full_vectors(structure, self.theta)[0])

    __repr__, _repr_html_ = shown_repr, shown_html

    def _shown(self) -> Shown:
        from ..model.plant import parameter_info  # lazily: the command line's parser imports this package

        params = parameter_figures(self.names, self.theta, [parameter_info(n)[0] for n in self.names])
        fits = (figure("fitness (RMS residual)", self.fitness, "", ".3e"), figure("time", self.seconds, "s", ".3g"),
                figure("evaluations", int(self.evaluations)), figure("iterations", int(self.iterations)))
        return Shown(type(self).__name__, f"{self.method}, {'succeeded' if self.success else 'FAILED'}, "
                     f"{len(self.names)} parameters",
                     fits[:2] + tuple(figure(f.label, f.value, f.unit) for f in params), params + fits, (self.message,) if self.message else ())

    def parameters(self) -> dict[str, float]:
        """The identified parameters by name (units of the plant file: 1/s, m/(N·s), N, ...)."""
        return dict(zip(self.names, self.theta.tolist()))

