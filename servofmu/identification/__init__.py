"""Stage 5, identification: the prior, the output-error criterion, ANN features and targets, training sets,
the ANN, the searches (PSO, GAs), the PSO-ANN identifier, closed-loop data and criterion (closed_loop), fleets of
fits (fleet) and the results."""

__all__: list[str] = []
