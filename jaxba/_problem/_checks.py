"""Checks that a bundle is a problem at all, before anything is traced.

An adjustment needs observations, free unknowns, and for every free unknown an observation
that reaches it: an image with no image points (nor GNSS/INS), a camera no image was taken
with, a point nobody measured. Without these checks such a problem fails inside jax
("Need at least one array to concatenate") or is named by the datum check as if its
approximations were to blame.
"""

import numpy as np

from ._bundle import BundleProblem
from ._parameters import flatten, parameter_labels, positions_of


class ProblemError(ValueError):
    """A bundle that cannot be adjusted: no observations, no free unknowns, or free
    unknowns that no observation reaches."""


def check_problem(problem: BundleProblem, labels: list[str] | None = None) -> None:
    """Raise `ProblemError` for a bundle with no observations or no free unknowns, or with
    a free image, camera or point that no observation reaches, naming it (`labels`: one
    per scalar unknown as `parameter_labels` writes them; row numbers without)."""
    if not any(not group.constraint and np.any(np.asarray(group.mask()))
               for group in problem.groups):
        raise ProblemError("the problem has no observations: nothing to adjust")
    free = flatten(problem.free)
    if not np.any(free):
        raise ProblemError("the problem has no free unknowns: every camera, image and point "
                           "parameter is fixed, nothing to adjust")
    labels = labels or parameter_labels(problem.initial)
    unreached = np.flatnonzero(free & ~_reached(problem))
    if unreached.size:
        owners = list(dict.fromkeys(labels[k].rsplit(" ", 1)[0] for k in unreached))
        what = {"camera": "no image was taken with it", "image": "no image points or other "
                "observations", "point": "it is measured in no image",
                "mount": "no image of a rig frame was taken with it",
                "board": "no image point is on it"}
        first = owners[0]
        more = f" (and {len(owners) - 1} more: {', '.join(owners[1:4])})" if owners[1:] else ""
        raise ProblemError(
            f"{first}: {what[first.split(' ', 1)[0]]}, so its free parameters cannot be "
            f"determined{more}; remove it or fix its parameters")


def _reached(problem: BundleProblem) -> np.ndarray:
    """(n_all,) bool in `flatten` order: the unknowns some real observation depends on,
    from the blocks each group's rows refer to, the camera (mount and board warp) rows of
    image-point groups and the unknowns the priors observe directly."""
    positions = positions_of(problem.initial)
    reached = np.zeros(flatten(problem.free).size, dtype=bool)
    for group in problem.groups:
        if group.constraint:
            continue
        real = np.any(np.asarray(group.mask()), axis=1)
        for _, block, rows in group.row_references():
            reached[positions.block(block)[np.asarray(rows)[real]]] = True
        camera, model = getattr(group, "camera", None), getattr(group, "model", None)
        if camera is not None and model in positions.cameras:  # image points: their camera
            reached[positions.cameras[model][np.asarray(camera)[real]]] = True
        mount = getattr(group, "mount", None)
        if mount is not None:  # image points of rig cameras: their mounts
            reached[positions.mounts[np.asarray(mount)[real]]] = True
        board = getattr(group, "board", None)
        if board is not None:  # image points of a warped board: its warp
            reached[positions.warp[np.asarray(board)[real]]] = True
        reached[np.asarray(group.prior_positions(positions), dtype=int)] = True
    return reached
