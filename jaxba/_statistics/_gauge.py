"""A minimal datum left to the damping: solve with the gauge free, move into the datum after.

A bundle held by a minimal datum (`BundleProblem.gauge`: a dependent relative orientation's
six EOPs of one image and one station coordinate) has the solutions of the free bundle up to
a similarity. Levenberg-Marquardt converges faster with the gauge free: where the datum image
starts off, every other unknown must move to make up for it, and the damping slows those
moves (Dubrovnik-16 imported from BAL: 12 iterations with the datum held, 7 with it free, as
Ceres, which has no datum). So the solve frees the gauge (`released`; its Gauss-Newton steps
hold it, `BundleSchurDescent.gauge`), and `to_gauge_datum` moves its solution by the
similarity that gives the gauge's unknowns their datum values back: the residuals are
invariant, so this is the solution in the datum.

For omega-phi-kappa poses (every project's) the move is NumPy: the Newton steps on the
gauge's images alone, then one similarity of every unknown (`_moved_opk`, the formula of
`similarity_transform`). As a compiled program (jax's `similarity_transform` differentiated
inside a loop over all unknowns) it cost Dubrovnik-16 imported as a project 1.3 s of CPU to
compile and 0.8 s to trace and lower, for less than a millisecond of arithmetic. Other pose
models move by that program (`_free_network._inner_datum`).
"""

import jax
import numpy as np

from .._models._rotation_numpy import matrix_to_opk, opk_to_matrix, rodrigues_to_matrix
from .._problem._bundle import BundleProblem
from .._problem._inner_constraints import InnerConstraints
from .._problem._parameters import Parameters, flatten, unflatten
from ._datum import network_centre
from ._free_network import NEWTON_STEPS, _inner_datum


def released(problem: BundleProblem) -> tuple[BundleProblem, Parameters]:
    """`problem` with its gauge's unknowns free, and the gauge as booleans like `free`."""
    free = flatten(problem.free).copy()
    gauge = np.zeros_like(free)
    gauge[list(problem.gauge)] = True
    free |= gauge
    as_tree = jax.device_put(unflatten(problem.free, free))
    return (BundleProblem(problem.initial, as_tree, problem.groups, problem.refraction,
                          problem.robust, ties=problem.ties),
            jax.device_put(unflatten(problem.free, gauge)))


def to_gauge_datum(problem: BundleProblem, params: Parameters) -> Parameters:
    """`params`, a solution of `released(problem)`, moved by the similarity that sets the
    gauge's unknowns to their values in `problem.initial` (Newton on the d = len(gauge)
    similarity parameters: translation, rotation and, for d = 7, scale)."""
    centre = network_centre(problem)
    if problem.pose == "opk":
        return _gauge_datum_opk(problem, params, centre)
    return _gauge_datum_compiled(problem, params, centre)


def _gauge_datum_compiled(problem: BundleProblem, params: Parameters, centre: np.ndarray
                          ) -> Parameters:
    """`to_gauge_datum` of any pose model: the gauge as inner constraints, moved to by
    `_inner_datum`'s compiled Newton steps."""
    d = len(problem.gauge)
    n_all = flatten(problem.initial).size
    directions = np.zeros((d, n_all))
    directions[np.arange(d), list(problem.gauge)] = 1.0
    group = InnerConstraints(
        *jax.device_put((directions, flatten(problem.initial), np.ones((d, 1)), np.eye(7)[:, :d],
                         centre)),
        pose=problem.pose,
    )
    return _inner_datum(group, problem.refraction, params)


def _gauge_datum_opk(problem: BundleProblem, params: Parameters, centre: np.ndarray
                     ) -> Parameters:
    """`to_gauge_datum` of omega-phi-kappa images, in NumPy: the gauge's unknowns are EOPs
    (`_project._build`), so the Newton steps (derivatives by central differences) move only
    their images' rows; angles compared modulo 2π."""
    n_all = flatten(problem.initial).size
    positions = np.asarray(unflatten(problem.initial, np.arange(n_all)).images)
    rows, columns = np.nonzero(np.isin(positions, problem.gauge))
    target = np.asarray(problem.initial.images)[rows, columns]
    images = np.asarray(params.images)[rows]
    similarity = np.eye(7)[:, :rows.size]
    angle = columns >= 3

    def violation(phi):
        moved = _moved_opk(images, similarity @ phi, centre)[np.arange(rows.size), columns]
        difference = moved - target
        return np.where(angle, (difference + np.pi) % (2 * np.pi) - np.pi, difference)

    phi, steps = np.zeros(rows.size), np.eye(rows.size) * _DIFFERENCE_STEP
    for _ in range(NEWTON_STEPS):
        jacobian = np.stack([violation(phi + h) - violation(phi - h) for h in steps], axis=1)
        phi = phi - np.linalg.solve(jacobian / (2 * _DIFFERENCE_STEP), violation(phi))
    theta = similarity @ phi
    scale, rotation = 1.0 + theta[6], rodrigues_to_matrix(theta[3:6])
    mounts = params.mounts
    if mounts is not None:  # a rig scales with the network; its cameras keep their rotations
        mounts = np.asarray(mounts)
        mounts = np.concatenate([scale * mounts[:, :3], mounts[:, 3:]], axis=1)
    warp = None if params.warp is None else scale * np.asarray(params.warp)  # a length
    return jax.device_put(Parameters(
        params.cameras, _moved_opk(np.asarray(params.images), theta, centre),
        _move(np.asarray(params.points), theta, rotation, centre), mounts, warp))


# Central differences of the similarity parameters (object units, radians, scale): the
# derivative's error ~1e-12 relative slows no Newton step.
_DIFFERENCE_STEP = 1e-6


def _move(xyz: np.ndarray, theta: np.ndarray, rotation: np.ndarray, centre: np.ndarray
          ) -> np.ndarray:
    """X -> centre + (1 + s) R (X - centre) + t of points (n, 3) (`similarity_transform`)."""
    return centre + (1.0 + theta[6]) * (xyz - centre) @ rotation.T + theta[:3]


def _moved_opk(images: np.ndarray, theta: np.ndarray, centre: np.ndarray) -> np.ndarray:
    """omega-phi-kappa images rows (n, 6) under the similarity theta = (t, a, s) about
    `centre` (`similarity_transform`): stations moved, attitudes M -> M R(a)ᵀ."""
    rotation = rodrigues_to_matrix(theta[3:6])
    turned = opk_to_matrix(images[:, 3:]) @ rotation.T
    return np.concatenate([_move(images[:, :3], theta, rotation, centre),
                           matrix_to_opk(turned)], axis=1)
