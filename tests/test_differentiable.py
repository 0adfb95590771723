"""Gradients through the solve (implicit differentiation) against central differences of
re-solved bundles; the network-design gradient against central differences."""

import equinox as eqx
import numpy as np
import pytest

import jaxba
from jaxba._differentiable import adjusted, iop_trace_gradient, sensitivity

GRAD_RTOL = 1e-5  # issue 6: d IOP / d observation against central differences, relative
OBS_STEP = 1e-3  # mm (≈ σ): truncation ~1e-7; smaller steps drown in the re-solves' tolerance
STATION_STEP = 1e-4  # m, central-difference step of a station coordinate
FD_SOLVE_TOL = 1e-15  # re-solves for the differences: to rounding, or they drown the step
CHECKED = ((0, 0), (7, 1), (60, 0), (121, 1), (200, 0))  # (observation, coordinate)


@pytest.fixture(scope="module")
def block(tmp_path_factory):
    truth = jaxba.write_synthetic_project(tmp_path_factory.mktemp("diff"), seed=5, n_images=8,
                                          n_targets=30)
    return jaxba.build_project(jaxba.read_project(truth.project_file)).problem


@pytest.mark.slow  # ~1 min: ten re-solved bundles and the implicit adjoint
def test_iop_gradients_match_central_differences(block):
    problem = block
    start = jaxba.adjust(problem, check=False).parameters
    problem = eqx.tree_at(lambda p: p.initial, problem, start)  # re-solves start nearby
    sens, names = sensitivity(problem, rtol=FD_SOLVE_TOL, atol=FD_SOLVE_TOL, max_steps=200)
    keep = np.array([jaxba.SmacCamera.parameter_names.index(n) for n in names])
    plan = jaxba.linearisation_plan(problem)
    measured = problem.groups[0].measured

    def iops(m):
        moved = eqx.tree_at(lambda p: p.groups[0].measured, problem, m)
        solved = adjusted(moved, plan, rtol=FD_SOLVE_TOL, atol=FD_SOLVE_TOL, max_steps=200)
        return np.asarray(solved.cameras["smac"][0])[keep]

    # Each IOP's own scale: its largest sensitivity to any observation.
    scale = np.abs(np.asarray(sens)).max(axis=(1, 2))
    for k, j in CHECKED:
        fd = (iops(measured.at[k, j].add(OBS_STEP)) - iops(measured.at[k, j].add(-OBS_STEP)))
        fd = fd / (2 * OBS_STEP)
        error = np.abs(np.asarray(sens[:, k, j]) - fd) / scale
        assert np.all(error < GRAD_RTOL), dict(zip(names, error))


@pytest.mark.slow  # ~45 s: iop_trace_gradient runs eagerly (not jittable), five calls
def test_network_design_gradient(block):
    problem = block
    params = jaxba.adjust(problem, check=False).parameters
    value, grad = iop_trace_gradient(problem, params)
    assert value > 0 and grad.shape == (8, 3)

    def trace_at(image, axis, step):
        moved = params.images.at[image, axis].add(step)
        return float(iop_trace_gradient(problem, eqx.tree_at(lambda p: p.images, params,
                                                             moved))[0])

    for image, axis in ((0, 0), (3, 2)):
        fd = (trace_at(image, axis, STATION_STEP) - trace_at(image, axis, -STATION_STEP))
        fd = fd / (2 * STATION_STEP)
        assert float(grad[image, axis]) == pytest.approx(fd, rel=1e-4, abs=1e-6 * float(value))
