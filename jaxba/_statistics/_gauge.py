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
"""

import jax
import numpy as np

from .._problem._bundle import BundleProblem
from .._problem._inner_constraints import InnerConstraints
from .._problem._parameters import Parameters, flatten, unflatten
from ._datum import network_centre
from ._free_network import _inner_datum


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
    d = len(problem.gauge)
    n_all = flatten(problem.initial).size
    directions = np.zeros((d, n_all))
    directions[np.arange(d), list(problem.gauge)] = 1.0
    group = InnerConstraints(
        *jax.device_put((directions, flatten(problem.initial), np.ones((d, 1)), np.eye(7)[:, :d],
                         network_centre(problem))),
        pose=problem.pose,
    )
    return _inner_datum(group, problem.refraction, params)
