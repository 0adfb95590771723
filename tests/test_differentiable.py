"""Gradients through the solve (implicit differentiation) against central differences of
re-solved bundles, the Schur backend's against the dense backend's; the network-design
gradient against central differences."""

import re

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import pytest

import jaxba
import jaxba._solvers._schur._choice
from jaxba._problem._observations import ParameterObservations
from jaxba._solvers._schur._structure import bundle_structure
from jaxba._statistics._differentiable import adjusted, iop_trace_gradient, sensitivity
from jaxba.advanced import choose_backend

GRAD_RTOL = 1e-5  # d IOP / d observation against central differences, relative
OBS_STEP = 1e-3  # mm (≈ σ): truncation ~1e-7; smaller steps drown in the re-solves' tolerance
STATION_STEP = 1e-4  # m, central-difference step of a station coordinate
FD_SOLVE_TOL = 1e-15  # re-solves for the differences: to rounding, or they drown the step
# The solves of the derivatives and of the differences' re-solves: tolerances are static
# arguments of the compiled programs, so one setting lets the tests share them.
FD_OPTIONS = {"rtol": FD_SOLVE_TOL, "atol": FD_SOLVE_TOL, "max_steps": 200}
CHECKED = ((0, 0), (7, 1), (60, 0), (121, 1), (200, 0))  # (observation, coordinate)
# The Schur backend's adjoint (jaxba._solvers._schur._adjoint) against the dense one: the IOPs'
# sensitivity on `block`, and against central differences too the gradient of a quantity on
# `small_block`: 10 images, 80 targets, 5 free IOPs, the lab datum (6 fixed coordinates, the
# distances' scale) and weighted control on 3 points.
BACKEND_RTOL = 1e-8  # Schur vs dense gradient, relative to each block's largest entry
CONTROL_STEP = 1e-4  # m (≈ 0.1 σ of the control), central-difference step of a control value
SCHUR_CHECKED = ((0, 0), (33, 1), (400, 0))  # (observation, coordinate)


def _solved(problem, measured):
    """The adjusted Parameters of `problem` with the image coordinates `measured` (dense
    backend, `FD_OPTIONS`), computed by jax.vjp's forward pass: the very program that
    `sensitivity` runs forward (a plain call compiles the solve once more); the pullback is
    never run."""
    plan = jaxba.advanced.linearisation_plan(problem)

    def solve(m):
        moved = eqx.tree_at(lambda p: p.groups[0].measured, problem, m)
        return adjusted(moved, backend="dense", plan=plan, **FD_OPTIONS)

    return jax.vjp(solve, measured)[0]


@pytest.fixture(scope="module")
def block(tmp_path_factory):
    """8 images, 30 targets, 8 free IOPs, the lab datum; starting at its optimum, so that
    re-solves start nearby."""
    truth = jaxba.write_synthetic_project(tmp_path_factory.mktemp("diff"), seed=5, n_images=8,
                                          n_targets=30)
    problem = jaxba.build_project(jaxba.read_project(truth.project_file)).problem
    optimum = _solved(problem, problem.groups[0].measured)
    return eqx.tree_at(lambda p: p.initial, problem, optimum)


@pytest.fixture(scope="module")
def dense_sensitivity(block):
    """`sensitivity` of `block` on the dense backend, `FD_OPTIONS`: (S, names)."""
    return sensitivity(block, backend="dense", **FD_OPTIONS)


@pytest.mark.slow  # ~10 s: compiles the dense solve and its implicit adjoint, ten re-solves
def test_iop_gradients_match_central_differences(block, dense_sensitivity):
    problem = block
    sens, names = dense_sensitivity
    keep = np.array([jaxba.SmacCamera.parameter_names.index(n) for n in names])
    measured = problem.groups[0].measured

    def iops(m):
        return np.asarray(_solved(problem, m).cameras["smac"][0])[keep]

    # Each IOP's own scale: its largest sensitivity to any observation.
    scale = np.abs(np.asarray(sens)).max(axis=(1, 2))
    for k, j in CHECKED:
        fd = (iops(measured.at[k, j].add(OBS_STEP)) - iops(measured.at[k, j].add(-OBS_STEP)))
        fd = fd / (2 * OBS_STEP)
        error = np.abs(np.asarray(sens[:, k, j]) - fd) / scale
        assert np.all(error < GRAD_RTOL), dict(zip(names, error))


def test_network_design_gradient(block):
    problem = block
    params = problem.initial  # the adjusted geometry
    # iop_trace_gradient is compiled once for the five calls (op by op they compiled ~470
    # small programs).
    def trace_and_gradient(params):
        return iop_trace_gradient(problem, params)

    value, grad = trace_and_gradient(params)
    assert value > 0 and grad.shape == (8, 3)

    def trace_at(image, axis, step):
        moved = jnp.asarray(params.images).at[image, axis].add(step)
        return float(trace_and_gradient(eqx.tree_at(lambda p: p.images, params, moved))[0])

    for image, axis in ((0, 0), (3, 2)):
        fd = (trace_at(image, axis, STATION_STEP) - trace_at(image, axis, -STATION_STEP))
        fd = fd / (2 * STATION_STEP)
        assert float(grad[image, axis]) == pytest.approx(fd, rel=1e-4, abs=1e-6 * float(value))


@pytest.mark.slow  # ~10 s: compiles the Schur backend's jacrev (its CG vmapped over 8 IOPs)
def test_schur_sensitivity_matches_dense(block, dense_sensitivity):
    schur, names = sensitivity(block, backend="schur", **FD_OPTIONS)
    dense, dense_names = dense_sensitivity
    assert names == dense_names == ["xp", "yp", "c", "K1", "K2", "K3", "P1", "P2"]
    scale = np.abs(np.asarray(dense)).max(axis=(1, 2), keepdims=True)
    error = np.abs(np.asarray(schur) - np.asarray(dense)) / scale
    assert np.all(error < BACKEND_RTOL), dict(zip(names, error.max(axis=(1, 2))))


@pytest.fixture(scope="module")
def small_block(tmp_path_factory):
    truth = jaxba.write_synthetic_project(tmp_path_factory.mktemp("schur_diff"), seed=5,
                                          n_images=10, n_targets=80,
                                          free=("xp", "yp", "c", "K1", "K2"))
    problem = jaxba.build_project(jaxba.read_project(truth.project_file)).problem
    rows = jnp.array([5, 20, 41])
    control = ParameterObservations(
        name="control", block="points", rows=rows, observed=problem.initial.points[rows] + 0.002,
        stddev=jnp.full((3, 3), 0.001))
    return eqx.tree_at(lambda p: p.groups, problem, (*problem.groups, control))


def _data(problem):
    """The arrays differentiated: image coordinates, control values, all initial values (the
    datum's fixed coordinates among them)."""
    return problem.groups[0].measured, problem.groups[-1].observed, problem.initial.points


def _adjusted_quantity(problem, data, backend, **options):
    """A scalar of the adjusted block: the free IOPs, an image's EOPs, some points."""
    measured, control, points = data
    moved = eqx.tree_at(lambda p: (p.groups[0].measured, p.groups[-1].observed, p.initial.points),
                        problem, (measured, control, points))
    x = adjusted(moved, backend=backend, **options)
    iops = x.cameras["smac"][0]
    return (jnp.sum(iops * jnp.arange(1.0, 1.0 + iops.size)) + jnp.sum(x.images[3])
            + jnp.sum(x.points[10:13]))


def _split(problem, backend):
    """The static structure `adjusted` needs, made from the concrete problem: the initial
    values are among the arrays differentiated."""
    if backend == "schur":
        return {"structure": bundle_structure(problem)}
    return {"plan": jaxba.advanced.linearisation_plan(problem)}


def _central_difference_steps(problem):
    """(which array of `_data`, index, step) of the Schur gradient's central differences:
    image coordinates, control values and a fixed coordinate of the datum."""
    checked = [(0, index, OBS_STEP) for index in SCHUR_CHECKED]
    checked += [(1, (0, 2), CONTROL_STEP), (1, (2, 0), CONTROL_STEP)]
    fixed = int(np.flatnonzero(~np.asarray(problem.free.points).all(axis=1))[0])
    checked += [(2, (fixed, int(np.flatnonzero(~np.asarray(problem.free.points[fixed]))[0])),
                 CONTROL_STEP)]
    return checked


def _moved(data, which, index, step):
    changed = list(data)
    changed[which] = changed[which].at[index].add(step)
    return tuple(changed)


@pytest.fixture(scope="module")
def gradients(small_block):
    """Per backend: the quantity's gradient w.r.t. `_data` ("gradient"), the StableHLO text of
    its program ("lowered"), and for the Schur backend the central differences of the
    quantity by re-solves (`_central_difference_steps` -> value, "differences").

    One compiled program per backend, data -> (quantity, gradient), solved to rounding (the
    tolerances of the re-solves: the program serves both), closed over the problem (its
    index arrays concrete, not traced). Everything is evaluated here, while the programs
    are compiled: jax's caches are cleared after a test that leaves the process large, and
    these programs hold a host callback (equinox's error checks), so the persistent cache
    does not keep them."""
    data = _data(small_block)
    out = {}
    for backend in ("schur", "dense"):
        options = dict(FD_OPTIONS, **_split(small_block, backend))
        compiled = jax.jit(jax.value_and_grad(
            lambda data, backend=backend, options=options: _adjusted_quantity(
                small_block, data, backend, **options)))
        out[backend] = {"gradient": compiled(data)[1],
                        "lowered": compiled.lower(data).as_text()}  # the call's own lowering
        if backend == "schur":
            out[backend]["differences"] = [
                (float(compiled(_moved(data, which, index, step))[0])
                 - float(compiled(_moved(data, which, index, -step))[0])) / (2 * step)
                for which, index, step in _central_difference_steps(small_block)]
    return out


@pytest.mark.slow  # ~25 s for `gradients`: compiles both backends' solve and adjoint
def test_schur_gradient_matches_dense(gradients):
    for name, schur, dense in zip(("measured", "control", "points"),
                                  gradients["schur"]["gradient"], gradients["dense"]["gradient"]):
        scale = np.abs(np.asarray(dense)).max()
        assert scale > 0, name
        error = np.abs(np.asarray(schur) - np.asarray(dense)).max() / scale
        assert error < BACKEND_RTOL, (name, error)


def test_schur_gradient_matches_central_differences(small_block, gradients):
    grad = gradients["schur"]["gradient"]
    for (which, index, _), fd in zip(_central_difference_steps(small_block),
                                     gradients["schur"]["differences"], strict=True):
        scale = np.abs(np.asarray(grad[which])).max()
        assert float(grad[which][index]) == pytest.approx(fd, abs=GRAD_RTOL * scale), (which, index)


def _largest_matrix_dimension(text: str) -> int:
    """The largest k such that some f64 tensor in the StableHLO `text` has two dimensions of
    at least k."""
    largest = 0
    for shape in re.findall(r"tensor<((?:\d+x)+)f64>", text):
        dims = sorted((int(d) for d in shape.rstrip("x").split("x")), reverse=True)
        if len(dims) >= 2:
            largest = max(largest, dims[1])
    return largest


def test_schur_adjoint_forms_no_dense_matrix(small_block, gradients):
    """No array of the Schur path's forward solve and reverse pass has two dimensions longer
    than the reduced camera matrix (n_r + 1, its padding column); the dense path's Hessian
    (n_free x n_free) fails the same check."""
    problem = small_block
    n_reduced = bundle_structure(problem).n_reduced
    n_free = problem.n_unknowns()
    assert n_free > 2 * (n_reduced + 1)
    schur = _largest_matrix_dimension(gradients["schur"]["lowered"])
    assert schur <= n_reduced + 1, (schur, n_reduced)
    assert _largest_matrix_dimension(gradients["dense"]["lowered"]) >= n_free


def test_backend_choice(small_block, monkeypatch):
    """"auto" chooses as `adjust` does where the problem's values are concrete, the dense path
    (which batches) where they are traced."""
    assert choose_backend(small_block).name == "dense"  # 299 unknowns
    monkeypatch.setattr(jaxba._solvers._schur._choice, "SCHUR_MIN_UNKNOWNS", 100)
    assert choose_backend(small_block).name == "schur"
    assert choose_backend(small_block, "dense").name == "dense"
    chosen = []

    def choose(problem):
        chosen.append(choose_backend(problem).name)
        return problem.initial.images

    jax.eval_shape(choose, small_block)
    assert chosen == ["dense"]
    with pytest.raises(ValueError, match="backend must be one of"):
        choose_backend(small_block, "cg")
