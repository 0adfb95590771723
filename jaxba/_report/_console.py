"""Short lines for a terminal: progress per iteration, the summary after an adjustment and
the warnings a user must not miss."""

import math

from .._project._build import Project
from .._solvers._progress import Iteration
from .._statistics._adjustment import Adjustment
from .._statistics._summary import outlier_summary, variance_test
from ._board_warp import board_warp
from ._collect import (
    CONSTANT,
    FIXED,
    camera_tables,
    datum_text,
    describe,
    group_statistics,
    project_ids,
    rejections,
)
from ._no_sigma import no_sigma_lines

LISTED = 5  # observations named in one warning


def iteration_line(iteration: Iteration) -> str:
    """E.g. `iter  3  cost 1.2345e+03  sigma0^2 1.0283`."""
    return (
        f"iter {iteration.iteration:2d}  cost {iteration.cost:.4e}"
        f"  sigma0^2 {iteration.sigma0_squared:.6g}"
    )


def start_line(project: Project) -> str:
    """What is about to be adjusted."""
    problem = project.problem
    n, u = problem.n_observations(), problem.n_unknowns()
    return (
        f"adjusting {project.spec.name}: {len(project.image_ids)} images,"
        f" {len(project.point_ids)} points, {n} observations, {u} unknowns,"
        f" redundancy {n - u}"
    )


def summary_lines(project: Project, result: Adjustment) -> list[str]:
    """Every free or weighted IOP with its σ, a warped board's kx, ky with σ; σ̂0 with its
    χ² test, the datum and the outliers (`jaxba._statistics._summary`); variance components
    and rejections; the convergence state and the backend."""
    lines = []
    for cid, camera in camera_tables(project, result).items():
        lines.append(f"camera {cid} ({project.camera_rows[cid][0]})")
        width = max(len(name) for name in camera.names)
        for k, name in enumerate(camera.names):
            status = camera.status[0][k]
            if status in (FIXED, CONSTANT):
                continue
            note = f"  ({status})" if status != "free" else ""  # weighted, tied to C1.K1
            lines.append(
                f"  {name.ljust(width)}  {camera.values[0, k]: .8e}"
                f" +/- {camera.stds[0, k]:.2e}{note}"
            )
    warp = board_warp(project, result)
    for b, board in enumerate(() if warp is None else warp.ids):
        lines.append(f"board {board} warp (object units)")
        lines += [f"  {name}  {warp.values[b, k]: .8e} +/- {warp.stds[b, k]:.2e}"
                  for k, name in enumerate(("kx", "ky"))]
    precision = result.precision
    lines.append(
        f"sigma0 {math.sqrt(precision.sigma0_squared):.6g}"
        f" (sigma0^2 {precision.sigma0_squared:.6g}, redundancy {precision.redundancy})"
    )
    test = variance_test(result)
    if test is not None:
        lines.append(f"  {test.text()}")
    lines.append(f"datum: {datum_text(project, result)}")  # as NAME.out and results.json
    found_outliers = outlier_summary(result, project_ids(project),
                                     group_statistics(project, result))
    if found_outliers is not None:
        lines.append(f"outliers: {found_outliers.text()}")
    if result.variance_components is not None:
        parts = ", ".join(
            f"{name} {component.sigma0:.3f}"
            for name, component in result.variance_components.items()
        )
        lines.append(f"variance components (sigma / prior sigma): {parts}")
    found = rejections(project, result)
    if found:
        lines.append(f"data snooping rejected {len(found)} observation(s):")
        for entry in found:
            ids = {key: value for key, value in entry.items() if key not in ("group", "w")}
            lines.append(f"  {entry['group']} {describe(ids)}  |w| {entry['w']:.2f}")
    steps = f"{result.steps} solver steps, {result.backend} backend"
    if result.converged:
        lines.append(f"converged after {result.n_iterations} iterations ({steps})")
    else:
        lines.append(
            f"NOT converged after {result.n_iterations} iterations ({steps});"
            " the reports show the last iterate"
        )
        lines.append(f"  solver: {result.message}")
    return lines


def warning_lines(project: Project, result: Adjustment) -> list[str]:
    """What the numbers of a converged adjustment say about the data, one line each (none
    when all is well, or when the adjustment did not converge: its numbers mean nothing):

    - σ̂0 rejected by the two-sided χ² test of the variance factor (`variance_test`: r σ̂0² / σ0²
      against the χ²(r) quantiles at α/2 and 1 - α/2, α 5 %);
    - observations whose normalised residual |w| exceeds the critical value of the
      reliability's w-test (the largest first, named by image, point or camera);
    - observations removed by data snooping;
    - unknowns without a σ (N singular at the solution), and why.
    """
    if not result.converged:
        return []
    return [*_variance_factor(project, result), *_large_residuals(project, result),
            *_removed(project, result), *no_sigma_lines(project, result)]


def _variance_factor(project: Project, result: Adjustment) -> list[str]:
    test = variance_test(result)
    if test is None or test.passed:
        return []
    cause = ("the a priori σ of the observations are too small, or there are blunders"
             if test.statistic > test.high else "the a priori σ of the observations are too large")
    return [
        f"sigma0 {test.sigma0:.4g} differs from its a priori value {test.sigma0_prior:g}: the"
        f" chi-square test of the variance factor rejects it (alpha {test.alpha:g}, redundancy"
        f" {test.redundancy}: {test.sigma0_low:.4g} to {test.sigma0_high:.4g} expected); {cause}"
    ]


def _large_residuals(project: Project, result: Adjustment) -> list[str]:
    found = outlier_summary(result, project_ids(project), group_statistics(project, result))
    if found is None or not found.count:
        return []
    named = ", ".join(f"{name} |w| {abs_w:.1f}" for _, name, abs_w in found.worst)
    more = f" and {found.count - len(found.worst)} more" if found.count > len(found.worst) else ""
    return [
        f"{found.count} observation(s) with a normalised residual |w| above the critical"
        f" value {found.critical_value:.2f} (alpha {found.alpha:.2g} per test): {named}{more};"
        " see the outlier column of observations.csv"
    ]


def _removed(project: Project, result: Adjustment) -> list[str]:
    found = rejections(project, result)
    if not found:
        return []
    named = ", ".join(
        describe({k: v for k, v in entry.items() if k not in ("group", "w")})
        for entry in found[:LISTED])
    more = f" and {len(found) - LISTED} more" if len(found) > LISTED else ""
    return [f"data snooping removed {len(found)} observation(s): {named}{more}; the solution"
            " does not use them"]
