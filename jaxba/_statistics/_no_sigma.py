"""The unknowns that have no σ at a solution, and why: a σ is never NaN without a word.

Where N is singular at the solution, the unknowns along its null space have no σ. The Schur
backend finds the object points whose own 3 x 3 block is singular (rays that nearly
coincide: `jaxba._solvers._schur._normal.singular_points`) and gives every other unknown
its σ; any other free unknown without a finite σ lies along a singular direction of N that
the observations and the datum leave undetermined.
"""

import numpy as np

from .._problem._bundle import BundleProblem
from .._problem._parameters import flatten, unflatten
from ._covariance import Precision

POINT = ("its rays (nearly) coincide: its depth along them is not determined (the point's"
         " 3 x 3 block of N is singular)")
OTHER = "N is singular along it: the observations and the datum do not determine it"


def unknowns_without_sigma(problem: BundleProblem, precision: Precision) -> dict[int, str]:
    """{`flatten` position: reason} of every free unknown whose σ is not finite (`POINT` for
    the three coordinates of an object point that all have none, `OTHER` else)."""
    std = flatten(precision.std)
    free = flatten(problem.free)
    missing = np.flatnonzero(free & ~np.isfinite(std))
    if missing.size == 0:
        return {}
    points = np.asarray(unflatten(problem.initial, np.arange(std.size)).points)
    lost = points[~np.isfinite(std[points]).all(axis=1)]  # rows of points without any σ
    in_points = set(lost.ravel().tolist())
    return {int(k): POINT if int(k) in in_points else OTHER for k in missing.tolist()}
