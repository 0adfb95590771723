"""The statistical stopping rule (`jaxba._solvers._trust_region`) measured on block A and on Zhang.

    python benchmarks/stopping_rule.py [--tolerances 1e-3 1e-4 1e-5 1e-6]

1. Block A (`blocks.py` close-range, 60 images, 78,958 unknowns), Schur backend, damped
   Levenberg-Marquardt with the statistical test off (τ = 0): per accepted iterate the cost,
   its relative change, the Gauss-Newton decrement gᵀN⁻¹g and the two sides of the bound
   the rule rests on, √(gᵀN⁻¹g)/σ̂0 against max_i |Δ_i|/σ̂_i of the Gauss-Newton step Δ
   (σ̂_i from `schur_cofactors` at the last iterate).
2. Steps of the Schur backend on block A and of the dense backend on configs/zhang for each τ
   (with the Gauss-Newton end game), and for Zhang the largest distance of an intrinsic from
   the optimum (a solve run to rtol = atol = 1e-14, τ = 0) in units of its σ̂.
"""

import argparse
import os
import pathlib
import tempfile

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import jax  # noqa: E402

jax.config.update("jax_enable_x64", True)

import jax.numpy as jnp  # noqa: E402
import numpy as np  # noqa: E402
from blocks import write_block  # noqa: E402

import jaxba  # noqa: E402
from jaxba._solvers._backend import Tolerances  # noqa: E402
from jaxba._solvers._schur._assembly import bundle_normal_equations  # noqa: E402
from jaxba._solvers._schur._columns import reduced_vector  # noqa: E402
from jaxba._solvers._schur._descent import Schur  # noqa: E402
from jaxba._solvers._schur._reduced_solve import solve_bundle_damped  # noqa: E402
from jaxba._solvers._schur._structure import bundle_structure  # noqa: E402
from jaxba._solvers._steps import _init, _step  # noqa: E402
from jaxba._statistics._covariance import schur_cofactors  # noqa: E402

ZHANG = pathlib.Path(__file__).resolve().parents[1] / "configs" / "zhang" / "zhang.toml"


def damped_iterates(problem, structure, max_steps: int) -> list:
    """The accepted iterates of the Schur LM with the statistical test off, stepped here."""
    fn, solver, _, arguments = Schur(structure).least_squares(
        problem, Tolerances(rtol=1e-8, atol=1e-8, step=0.0, function=0.0))
    state, *_ = _init(fn, solver, problem.initial, arguments)
    y, iterates = problem.initial, []
    for _ in range(max_steps):
        accepted = int(state.num_accepted_steps)
        y, state, _, terminate, *_ = _step(fn, solver, y, arguments, state)
        if int(state.num_accepted_steps) > accepted:
            iterates.append((y, float(state.cost)))
        if bool(terminate):
            break
    return iterates


def bound_table(problem, structure) -> None:
    iterates = damped_iterates(problem, structure, 12)
    cofactors = schur_cofactors(problem, iterates[-1][0], structure=structure)
    sigma0 = float(jnp.sqrt(cofactors.sigma0_squared))
    std_r = reduced_vector(structure, cofactors.std)
    std_e = cofactors.std.points[structure.eliminated_points]

    @jax.jit
    def gauss_newton(y):
        normal = bundle_normal_equations(problem, structure, y)
        x_r, x_e = solve_bundle_damped(structure, normal, 0.0)
        ratio = jnp.maximum(
            jnp.max(jnp.where(std_r > 0, jnp.abs(x_r) / jnp.where(std_r > 0, std_r, 1), 0)),
            jnp.max(jnp.where(std_e > 0, jnp.abs(x_e) / jnp.where(std_e > 0, std_e, 1), 0)))
        return x_r @ normal.reduced_gradient + jnp.sum(x_e * normal.point_gradient), ratio

    print("| iterate | cost | relative change | gᵀN⁻¹g | √(gᵀN⁻¹g)/σ̂0 | max |Δ_i|/σ̂_i |")
    print("|---|---|---|---|---|---|")
    before = None
    for k, (y, cost) in enumerate(iterates):
        decrement, ratio = map(float, gauss_newton(y))
        change = "-" if before is None else f"{(before - cost) / before:.2e}"
        before = cost
        print(f"| {k} | {cost:.10f} | {change} | {decrement:.3e} |"
              f" {np.sqrt(max(decrement, 0.0)) / sigma0:.3e} | {ratio:.3e} |", flush=True)


def zhang_errors(tolerances) -> dict:
    project = jaxba.build_project(jaxba.read_project(ZHANG))
    problem = project.problem
    model, row = project.camera_rows["C1"]
    optimum = jaxba.solve(problem, rtol=1e-14, atol=1e-14, step_tolerance=0.0, max_steps=200)
    std = np.asarray(jaxba.precision(problem, optimum.parameters).std.cameras[model][row])
    best = np.asarray(optimum.parameters.cameras[model][row])
    results = {}
    for tau in tolerances:
        solution = jaxba.solve(problem, step_tolerance=tau, on_step=lambda info: None)
        values = np.asarray(solution.parameters.cameras[model][row])
        error = np.max(np.abs(values - best)[std > 0] / std[std > 0])
        results[tau] = (int(solution.steps), float(error))
    return results


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--tolerances", type=float, nargs="+", default=[1e-3, 1e-4, 1e-5, 1e-6])
    args = parser.parse_args()
    with tempfile.TemporaryDirectory() as folder:
        project = write_block(folder, "close-range", seed=0)["project"]
        problem = jaxba.build_project(jaxba.read_project(project)).problem
    structure = bundle_structure(problem)
    bound_table(problem, structure)
    zhang = zhang_errors(args.tolerances)
    print()
    print("| τ | block A steps | block A final cost | Zhang steps | Zhang max |x - x̂|/σ̂ |")
    print("|---|---|---|---|---|")
    for tau in args.tolerances:
        solution = jaxba.solve(problem, Schur(structure), rtol=1e-8, atol=1e-8,
                               step_tolerance=tau, on_step=lambda info: None)
        steps, error = zhang[tau]
        print(f"| {tau:g} | {int(solution.steps)} | {float(solution.cost):.10f} | {steps} |"
              f" {error:.1e} |", flush=True)


if __name__ == "__main__":
    main()
