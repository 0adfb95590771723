"""Which solver adjusts a bundle: the dense normal equations or the Schur split."""

from .._observations import Distances, ImagePoints, ParameterObservations
from .._problem import BundleProblem

# Above this many unknowns `adjust` eliminates the object points: the dense path's
# statistics form the whitened Jacobian (observations x unknowns: ~300 MB for 2000 unknowns
# and 20000 observations) and n x n matrices; the Schur split forms neither.
SCHUR_MIN_UNKNOWNS = 2000
SOLVERS = ("auto", "dense", "schur")


def use_schur(problem: BundleProblem, solver: str = "auto") -> bool:
    """Whether to adjust `problem` with its object points eliminated.

    `solver`: "dense" never, "schur" always, "auto" for a bundle of more than
    `SCHUR_MIN_UNKNOWNS` unknowns whose observations the Schur split supports (image
    points, direct observations of unknowns, distances: not inner constraints).
    """
    if solver not in SOLVERS:
        raise ValueError(f"solver must be one of {', '.join(SOLVERS)}, not {solver!r}")
    supported = all(
        isinstance(g, ImagePoints | ParameterObservations | Distances) for g in problem.groups)
    if solver == "schur" and not supported:
        raise ValueError(
            "solver 'schur' handles image points, direct observations of unknowns and "
            "distances only (a free network's inner constraints need solver 'dense')")
    return solver == "schur" or (
        solver == "auto" and supported and problem.n_unknowns() > SCHUR_MIN_UNKNOWNS)
