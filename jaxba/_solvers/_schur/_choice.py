"""Which solver adjusts a bundle: the dense normal equations or the Schur split."""

from ..._problem._bundle import BundleProblem

# Above this many unknowns, or this many entries of the whitened Jacobian (observations x
# unknowns), `adjust` eliminates the object points: the dense path's datum check and
# statistics form that Jacobian and n x n matrices; the Schur split forms neither. Measured
# (benchmarks/block_vs_ceres.py, 115-image free network, 1148 unknowns x 19509
# observations, warm): dense 11.9 s, Schur 3.2 s; the lab (350 x 2794) stays dense.
SCHUR_MIN_UNKNOWNS = 2000
SCHUR_MIN_JACOBIAN_ENTRIES = 4_000_000
SOLVERS = ("auto", "dense", "schur")


def use_schur(problem: BundleProblem, solver: str = "auto") -> bool:
    """Whether to adjust `problem` with its object points eliminated.

    `solver`: "dense" never, "schur" always, "auto" for a bundle of more than
    `SCHUR_MIN_UNKNOWNS` unknowns or `SCHUR_MIN_JACOBIAN_ENTRIES` Jacobian entries whose
    observations the Schur split supports (row-local groups, whose rows each depend on a
    few parameter blocks: `AbstractObservationGroup.row_blocks`; a free network's inner
    constraints through `jaxba._statistics._free_network.minimal_constraints`). A problem with a
    board warp (`Parameters.warp`) is dense: "schur" refuses it.
    """
    if solver not in SOLVERS:
        raise ValueError(f"solver must be one of {', '.join(SOLVERS)}, not {solver!r}")
    supported = all(g.row_blocks() or g.constraint for g in problem.groups)
    if solver == "schur" and not supported:
        raise ValueError(
            "solver 'schur' handles observations whose rows each depend on a few parameter"
            " blocks (image points, direct observations of unknowns, distances) and a free"
            " network's inner constraints only")
    if problem.initial.warp is not None:  # its blocks have no columns for a board's warp
        if solver == "schur":
            raise ValueError("solver 'schur' does not adjust a board warp (kx, ky): take "
                             "solver 'dense' (or 'auto'), a calibration's size")
        return False
    n_unknowns = problem.n_unknowns()
    large = (n_unknowns > SCHUR_MIN_UNKNOWNS
             or n_unknowns * problem.n_observations() > SCHUR_MIN_JACOBIAN_ENTRIES)
    return solver == "schur" or (solver == "auto" and supported and large)
