"""A BAL problem as a `BundleProblem`: BAL cameras, Rodrigues poses, one image group.

BAL's camera row (r1, r2, r3, t1, t2, t3, f, k1, k2) splits into the image's pose (the
"rodrigues" pose model, P = R(r) X + t) and its camera (the "bal" camera model, one camera
row per image: x = f (1 + k1 |p|² + k2 |p|⁴) p, p = -P[:2] / P[2]). Every observation has
σ = 1 pixel, so that ½ Σ e² is BAL's (and Ceres') cost ½ Σ |x - observed|²; the whitened
residual observed - x has the opposite sign of Ceres' `SnavelyReprojectionError`.
"""

import jax
import jax.numpy as jnp
import numpy as np

from ..._problem._bundle import BundleProblem
from ..._problem._observations import ImagePoints
from ..._problem._parameters import Parameters
from ._reader import BalProblem


def bal_bundle(bal: BalProblem) -> BundleProblem:
    """The BAL problem `bal` as a BundleProblem: cameras {"bal": (n_cameras, 3)} (f, k1,
    k2), images (n_cameras, 6) (r, t; pose "rodrigues"), points (n_points, 3), all free,
    one ImagePoints group "bal" with σ = 1 (pixels)."""
    initial = Parameters(
        cameras={"bal": jnp.asarray(bal.cameras[:, 6:])},
        images=jnp.asarray(bal.cameras[:, :6]),
        points=jnp.asarray(bal.points),
    )
    free = jax.tree.map(lambda x: np.ones(np.shape(x), dtype=bool), initial)
    group = ImagePoints(
        name="bal",
        model="bal",
        camera=jnp.asarray(bal.camera_index),
        image=jnp.asarray(bal.camera_index),
        point=jnp.asarray(bal.point_index),
        measured=jnp.asarray(bal.observed),
        stddev=jnp.ones_like(jnp.asarray(bal.observed)),
        pose="rodrigues",
    )
    return BundleProblem(initial, free, (group,))
