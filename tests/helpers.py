"""Shared test helpers: central differences, Jacobian checks and named tolerances (float64)."""

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jax.flatten_util import ravel_pytree

import jaxba
from jaxba._problem._bundle import free_indices, observation_mask, params_from_free
from jaxba._problem._observations import ParameterObservations
from jaxba._solvers._schur._assembly import bundle_normal_equations
from jaxba._solvers._schur._columns import to_parameters
from jaxba._solvers._schur._descent import bundle_predicted_reduction
from jaxba._solvers._schur._reduced_solve import solve_bundle_damped

# Tolerances, named where the tests use them.
ROTATION_TOL = 1e-13  # elementwise agreement of two float64 rotation matrices / quaternions
ANGLE_TOL = 1e-12  # radians, round trips through atan2 / asin
FORMULA_RTOL = 1e-13  # a model against its formula written out again in NumPy
FD_STEP = 1e-6  # central-difference step, relative to max(1, |x_i|)
FD_RTOL = 1e-6  # jax.jacfwd against central differences (truncation ~ step², rounding ~ 1e-16/step)
FD_ATOL = 1e-8  # absolute floor of the same comparison, for entries that are (near) zero

# The synthetic self-calibration block that several modules adjust (18 images, 80 targets, the
# lab's datum and distances, 0.3 px noise): adjusted once per session by the `synthetic_block`
# fixture (conftest.py). Variants written with these arguments (blunders, other settings) have
# the same array shapes, so they reuse its compiled programs.
SYNTHETIC_BLOCK = {"seed": 21, "noise_px": 0.3}


def central_difference(f, x, eps):
    """Jacobian of `f` at `x` by central differences, (f(x + h e_i) - f(x - h e_i)) / 2h.

    `f` maps an array of the shape of `x` to an array of any shape; `eps` is a scalar step or
    an array of per-component steps broadcastable to `x`. Returns `f(x).shape + x.shape`, as
    `jax.jacfwd` does. Plain NumPy, float64.
    """
    x = np.asarray(x, dtype=np.float64)
    steps = np.broadcast_to(np.asarray(eps, dtype=np.float64), x.shape)
    value = np.asarray(f(x), dtype=np.float64)
    jacobian = np.empty(value.shape + x.shape)
    for index in np.ndindex(x.shape):
        dx = np.zeros_like(x)
        dx[index] = steps[index]
        forward = np.asarray(f(x + dx), dtype=np.float64)
        backward = np.asarray(f(x - dx), dtype=np.float64)
        jacobian[(..., *index)] = (forward - backward) / (2 * steps[index])
    return jacobian


def assert_jacobian_matches_fd(f, x, rtol, atol, *, step=FD_STEP):
    """Assert that `jax.jacfwd(f)(x)` matches central differences with steps step·max(1, |x_i|)."""
    x = np.asarray(x, dtype=np.float64)
    # `f` and its Jacobian compiled once each (op by op: dozens of small programs per call).
    exact = np.asarray(jax.jit(jax.jacfwd(f))(jnp.asarray(x)))
    assert np.all(np.isfinite(exact)), "jax.jacfwd returned non-finite entries"
    approximate = central_difference(jax.jit(f), x, step * np.maximum(1.0, np.abs(x)))
    np.testing.assert_allclose(exact, approximate, rtol=rtol, atol=atol)


def with_control_and_huber(problem, rows):
    """`problem` with weighted control on the three points `rows` (Z of the first
    unobserved; σ 1-2 mm, observed 3 mm off the approximations) and a Huber loss (k 1.5)."""
    rows = jnp.asarray(rows)
    stddev = jnp.array([[0.001, 0.001, jnp.inf], [0.002] * 3, [0.001] * 3])
    control = ParameterObservations(
        name="control", block="points", rows=rows,
        observed=problem.initial.points[rows] + 0.003, stddev=stddev,
    )  # fmt: skip
    problem = eqx.tree_at(lambda p: p.groups, problem, (*problem.groups, control))
    return eqx.tree_at(
        lambda p: p.robust, problem, jaxba.RobustLoss("huber", 1.5), is_leaf=lambda x: x is None
    )


def jacfwd_jacobian(problem, params):
    """Reference whitened Jacobian dẽ/dx_free and residuals ẽ of all residuals
    (`problem.residuals`), by forward mode over the free unknowns, real observations only:
    independent of the per-row blocks the library differentiates."""
    index = jnp.asarray(free_indices(problem))
    rows = jnp.asarray(np.flatnonzero(observation_mask(problem)))
    return _jacfwd_jacobian(problem, params, index, rows)


@eqx.filter_jit
def _jacfwd_jacobian(problem, params, index, rows):
    at_params = eqx.tree_at(lambda p: p.initial, problem, params)

    def residual_vector(x_free):
        values = params_from_free(at_params, x_free, index)
        return jnp.concatenate([jnp.ravel(r) for r in problem.residuals(values)])[rows]

    x_free = ravel_pytree(params)[0][index]
    return jax.jacfwd(residual_vector)(x_free), residual_vector(x_free)


@eqx.filter_jit
def schur_damped_step(problem, structure, params, damping):
    """One damped Schur step (JᵀJ + λD)⁻¹Jᵀe at `params` as Parameters, and its predicted
    reduction, as one program: run op by op, a step compiled ~500 small programs."""
    normal = bundle_normal_equations(problem, structure, params)
    x_r, x_e = solve_bundle_damped(structure, normal, damping)
    step = to_parameters(structure, params, x_r, x_e)
    return step, bundle_predicted_reduction(structure, normal, jax.tree.map(jnp.negative, step))


def synthetic_rig(seed: int = 0, n_frames: int = 8, noise_px: float = 0.2,
                  baseline: float = 120.0, n_cameras: int = 2):
    """A rig of `n_cameras` `opencv` cameras (pixels; 2: a stereo pair, 4: a head with the
    cameras at the corners of a square of side `baseline`) over a fixed 3D target (mm), and
    its truth.

    Returns (problem, truth): the `BundleProblem` (images block: one pose per frame; mounts:
    row 0 the fixed identity of the reference camera, row k camera k's pose in the rig
    frame, free; fx, fy, cx, cy, k1 of every camera free; the target fixed) with
    measurements computed at the truth plus N(0, noise_px²), and the true Parameters. The
    approximations are the truth moved a little, as a detector's closed form gives them.
    """
    rng = np.random.default_rng(seed)
    grid = np.stack(np.meshgrid(np.arange(9) * 25.0, np.arange(6) * 25.0), -1).reshape(-1, 2)
    points = np.column_stack([grid - grid.mean(0), 20.0 * np.sin(grid[:, 0] / 60.0)])
    frames = []
    for _ in range(n_frames):  # the rig about 600 mm in front of the target, looking at it
        angles = np.radians(rng.uniform(-15, 15, 3))
        station = np.array([*rng.uniform(-150, 150, 2), -600.0 + rng.uniform(-50, 50)])
        frames.append([*(station - np.array([baseline / 2, 0, 0])), np.pi + angles[0],
                       angles[1], angles[2]])
    corners = [[baseline, 2.0, -1.5], [0.0, baseline, 1.0], [baseline, baseline, -2.0]]
    turns = np.radians([[0.5, -3.0, 0.8], [2.0, 0.5, -1.0], [-1.0, 2.0, 1.5]])
    mounts = np.array([np.zeros(6), *(np.concatenate([c, t]) for c, t in
                                     zip(corners[:n_cameras - 1], turns))])
    iop = np.array([[900.0, 905.0, 320.0, 240.0, 0, -0.1, 0.05, 0, 0, 0],
                    [880.0, 882.0, 330.0, 235.0, 0, -0.12, 0.04, 0, 0, 0]])[
                        np.arange(n_cameras) % 2]
    free_iop = np.zeros_like(iop, dtype=bool)
    free_iop[:, [0, 1, 2, 3, 5]] = True
    n_points = points.shape[0]
    camera = np.repeat(np.arange(n_cameras), n_frames * n_points)
    frame = np.tile(np.repeat(np.arange(n_frames), n_points), n_cameras)
    point = np.tile(np.arange(n_points), n_cameras * n_frames)
    truth = jaxba.Parameters({"opencv": jnp.asarray(iop)}, jnp.asarray(np.array(frames)),
                             jnp.asarray(points), jnp.asarray(mounts))
    group = jaxba.ImagePoints(
        name="image_points", model="opencv", camera=jnp.asarray(camera),
        image=jnp.asarray(frame), point=jnp.asarray(point),
        measured=jnp.zeros((camera.size, 2)), stddev=jnp.ones((camera.size, 2)),
        mount=jnp.asarray(camera))
    computed = -np.asarray(group.residuals(truth, jaxba.NoRefraction()))
    measured = computed + noise_px * rng.standard_normal(computed.shape)
    group = eqx.tree_at(lambda g: (g.measured, g.stddev), group,
                        (jnp.asarray(measured), jnp.full(measured.shape, noise_px)))
    moved = np.array(frames) + np.concatenate([rng.normal(0, 5, (n_frames, 3)),
                                               rng.normal(0, 0.01, (n_frames, 3))], 1)
    start_mounts = mounts + np.concatenate(
        [np.zeros((1, 6)), np.tile([5, -3, 2, 0.01, -0.01, 0.01], (n_cameras - 1, 1))])
    initial = jaxba.Parameters({"opencv": jnp.asarray(iop * [1.01, 0.99, 1, 1, 1, 0, 1, 1, 1, 1])},
                               jnp.asarray(moved), jnp.asarray(points),
                               jnp.asarray(start_mounts))
    free_mounts = np.repeat(np.arange(n_cameras)[:, None] > 0, 6, axis=1)  # all but row 0
    free = jaxba.Parameters({"opencv": jnp.asarray(free_iop)},
                            jnp.ones((n_frames, 6), bool), jnp.zeros((n_points, 3), bool),
                            jnp.asarray(free_mounts))
    return jaxba.BundleProblem(initial=initial, free=free, groups=(group,)), truth


def synthetic_aerial(seed: int = 0, noise_mm: float = 0.005, gnss_sigma: float = 0.05,
                     ins_sigma_deg: float = 0.005):
    """A camera on a GNSS/INS platform over terrain: 3 strips of 6 vertical images (60 %
    forward, 30 % side overlap, alternating flight directions), c = 100 mm (smac, fixed),
    1000 m above ground, a grid of 121 points (those seen in 2 images or more kept), 4 of
    them control points (σ 2 cm, the corners); the body's pose observed
    by GNSS (σ `gnss_sigma`, m) and INS (σ `ins_sigma_deg`); the camera's lever arm (the
    perspective centre in the body frame, 10-30 cm) and boresight (body -> camera, 0.1-0.5
    degrees) the mount to recover (`Parameters.mounts` row 0, free, starting at 0).

    Returns (problem, truth): the images block holds the bodies' poses, the observations are
    computed at the truth plus noise (image points, GNSS/INS values and control alike).
    """
    rng = np.random.default_rng(seed)
    c, half = 100.0, np.array([45.0, 30.0])  # mm: principal distance, half the format
    height, scale = 1000.0, 1000.0 / 100.0 * 1000.0  # m; image mm -> ground mm
    footprint = 2 * half * scale / 1000.0  # m across (x), along (y) track
    base, spacing = 0.4 * footprint[1], 0.7 * footprint[0]
    bodies = []
    for strip in range(3):
        for k in range(6):
            y = k * base if strip % 2 == 0 else (5 - k) * base
            kappa = 0.0 if strip % 2 == 0 else np.pi
            angles = np.radians(rng.normal(0, 1.0, 2))
            bodies.append([strip * spacing, y, height, *angles, kappa + np.radians(
                rng.normal(0, 1.0))])
    bodies = np.array(bodies)
    grid = np.stack(np.meshgrid(np.linspace(-300, 2 * spacing + 300, 11),
                                np.linspace(-200, 5 * base + 200, 11)), -1).reshape(-1, 2)
    points = np.column_stack([grid, rng.uniform(-20, 20, len(grid))])
    mount = np.array([0.15, -0.25, 0.30, *np.radians([0.3, -0.2, 0.4])])
    iop = np.zeros((1, 12))
    iop[0, 2] = c
    truth = jaxba.Parameters({"smac": jnp.asarray(iop)}, jnp.asarray(bodies),
                             jnp.asarray(points), jnp.asarray(mount[None]))
    image, point = (np.repeat(np.arange(len(bodies)), len(points)),
                    np.tile(np.arange(len(points)), len(bodies)))
    group = jaxba.ImagePoints(
        name="image_points", model="smac", camera=jnp.zeros(image.size, int),
        image=jnp.asarray(image), point=jnp.asarray(point), measured=jnp.zeros((image.size, 2)),
        stddev=jnp.ones((image.size, 2)), mount=jnp.zeros(image.size, int))
    computed = -np.asarray(group.residuals(truth, jaxba.NoRefraction()))
    seen = np.all(np.abs(computed) < half, axis=1)
    kept = np.bincount(point[seen], minlength=len(points)) >= 2  # points in 2 images or more
    seen &= kept[point]
    points, point = points[kept], (np.cumsum(kept) - 1)[point]
    truth = eqx.tree_at(lambda p: p.points, truth, jnp.asarray(points))
    measured = computed[seen] + noise_mm * rng.standard_normal(computed[seen].shape)
    group = jaxba.ImagePoints(
        name="image_points", model="smac", camera=jnp.zeros(int(seen.sum()), int),
        image=jnp.asarray(image[seen]), point=jnp.asarray(point[seen]),
        measured=jnp.asarray(measured), stddev=jnp.full(measured.shape, noise_mm),
        mount=jnp.zeros(int(seen.sum()), int))
    sigma = np.array([gnss_sigma] * 3 + [np.radians(ins_sigma_deg)] * 3)
    gnss = jaxba.ParameterObservations(
        name="gnss_ins", block="images", rows=jnp.arange(len(bodies)),
        observed=jnp.asarray(bodies + sigma * rng.standard_normal(bodies.shape)),
        stddev=jnp.asarray(np.broadcast_to(sigma, bodies.shape).copy()))
    corners = np.stack([points[:, 0] + points[:, 1], points[:, 0] - points[:, 1]], 1)
    control_rows = np.array([np.argmin(corners[:, 0]), np.argmax(corners[:, 0]),
                             np.argmin(corners[:, 1]), np.argmax(corners[:, 1])])
    control = jaxba.ParameterObservations(
        name="control", block="points", rows=jnp.asarray(control_rows),
        observed=jnp.asarray(points[control_rows] + 0.02 * rng.standard_normal((4, 3))),
        stddev=jnp.full((4, 3), 0.02))
    moved = points + rng.normal(0, 1.0, points.shape)
    initial = jaxba.Parameters({"smac": jnp.asarray(iop)}, jnp.asarray(np.asarray(gnss.observed)),
                               jnp.asarray(moved), jnp.zeros((1, 6)))
    free = jaxba.Parameters({"smac": jnp.zeros((1, 12), bool)}, jnp.ones(bodies.shape, bool),
                            jnp.ones(points.shape, bool), jnp.ones((1, 6), bool))
    problem = jaxba.BundleProblem(initial=initial, free=free, groups=(group, gnss, control))
    return problem, truth


def significant_digits(text: str) -> int:
    """The significant digits a number's text spells: "-0.00120" and "1.2e-3" have 2."""
    return len(text.split("e")[0].replace("-", "").replace(".", "").strip("0"))


def move_tie_points(points_table, dz: float) -> None:
    """Shift the approximate Z of every tie point (a row whose σ columns are `- - -`) of a
    points table (`point_id X Y Z sX sY sZ`) by `dz`, object units."""
    rows = [line.split() for line in points_table.read_text().splitlines()]
    for row in rows:
        if len(row) > 4 and row[4] == "-":
            row[3] = repr(float(row[3]) + dz)
    points_table.write_text("\n".join(" ".join(row) for row in rows) + "\n")
