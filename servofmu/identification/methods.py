"""The identification methods by name (a light module: the command line lists them without loading the
numerical code)."""

__all__ = ["METHODS", "NEEDS_ANN", "SEARCH_NAMES"]

# The paper's hybrid, the swarm alone, and its comparators GA-ANN [31] and adaptive GA-ANN [35]: the same ANN
# estimate, box, criterion, polish and number of model evaluations, only the search differs.
METHODS = ("pso-ann", "pso", "ga-ann", "aga-ann")
NEEDS_ANN = ("pso-ann", "ga-ann", "aga-ann")
SEARCH_NAMES = {"pso-ann": "pso", "pso": "pso", "ga-ann": "ga", "aga-ann": "aga"}
