"""Free-network datum: inner constraints over all or chosen object points.

A free network is rank deficient by a similarity transformation (translation, rotation
and, without distances, scale). The datum is fixed by the inner constraints
Bᵀ (x - x₀) = 0, where the columns of B span the unobservable directions restricted to
the coordinates of the datum points (x₀: the approximations). They enter the bundle as an
observation group whose residuals vanish at the solution: the minimum is that of the
free network, Levenberg-Marquardt sees a full-rank problem, and the redundancy counts
them as constraints, r = n - u + d. `jaxba.precision` recognises the group and returns
the inner-constraint cofactor, the top-left block of [[N, B], [Bᵀ, 0]]⁻¹.
"""

import equinox as eqx
import jax.numpy as jnp
import numpy as np
from jax.flatten_util import ravel_pytree
from jaxtyping import Array, Float

from ._camera import AbstractRefraction
from ._datum import DatumError, describe_defect, null_space
from ._linearisation import dense_jacobian
from ._observations import AbstractObservationGroup
from ._parameters import Parameters, flatten, parameter_labels, unflatten
from ._problem import BundleProblem, free_indices

STIFFNESS = 100.0


class InnerConstraints(AbstractObservationGroup):
    """d constraints Bᵀ (x - x₀) = 0 on the flattened unknowns (`flatten` order).

    `directions` (d, n_all) holds the rows of Bᵀ, `reference` (n_all,) x₀.
    """

    directions: Float[Array, "d n_all"]
    reference: Float[Array, " n_all"]
    stddev: Float[Array, "d 1"]
    name: str = eqx.field(static=True, default="inner_constraints")

    def residuals(self, params: Parameters, refraction: AbstractRefraction) -> Array:
        del refraction
        flat = ravel_pytree(params)[0]
        return -(self.directions @ (flat - self.reference))[:, None] / self.stddev


def inner_constraints(
    problem: BundleProblem,
    *,
    datum_points: list[int] | None = None,
    labels: list[str] | None = None,
) -> BundleProblem:
    """The problem with inner constraints over `datum_points` (point rows; None: all).

    The datum defect is found from the null space of the whitened Jacobian at the
    approximations; it must be a similarity transformation of the network (a defect
    of any other kind raises `DatumError`, naming it), and the datum points must fix it.
    """
    jacobian = np.asarray(dense_jacobian(problem, problem.initial)[0])
    null = null_space(problem, jacobian=jacobian)
    if null is None:
        raise DatumError("the network has no datum defect: it needs no inner constraints")
    index = free_indices(problem)
    labels = labels or parameter_labels(problem.initial)
    describe_defect(problem, null, index, labels, allow_similarity=True)
    positions = np.asarray(unflatten(problem.initial, np.arange(flatten(problem.initial).size))
                           .points)
    rows = np.arange(positions.shape[0]) if datum_points is None else np.asarray(datum_points)
    selected = np.zeros(flatten(problem.initial).size, dtype=bool)
    selected[positions[rows].ravel()] = True
    directions = np.zeros((null.shape[0], selected.size))
    directions[:, index] = null
    directions[:, ~selected] = 0.0
    if np.linalg.matrix_rank(directions[:, index] @ null.T) < null.shape[0]:
        raise DatumError("the datum points do not fix the network's datum defect: choose "
                         "points with free coordinates spread over the network")
    # Any scaling of the rows gives the same constraints (their residuals vanish at the
    # solution). In the solver's Jacobi-scaled unknowns the rows get norm STIFFNESS: weak
    # rows leave the datum directions nearly flat and LM crawls along them (80 steps
    # without convergence for 4 datum points at norm 1; 27 steps at 100).
    weight = np.linalg.norm(directions[:, index] / np.linalg.norm(jacobian, axis=0), axis=1)
    weight /= STIFFNESS
    group = InnerConstraints(
        directions=jnp.asarray(directions / weight[:, None]),
        reference=jnp.asarray(flatten(problem.initial)),
        stddev=jnp.ones((null.shape[0], 1)),
    )
    return eqx.tree_at(lambda p: p.groups, problem, (*problem.groups, group))
