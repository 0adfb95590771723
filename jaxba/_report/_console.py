"""Short lines for a terminal: progress per iteration and the summary after an adjustment."""

import math

from .._progress import Iteration
from .._project._build import Project
from .._solve import Adjustment
from .._timing import Timings
from ._collect import FIXED, camera_tables, describe, rejections


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
    """Every free or weighted IOP with its σ, σ̂0 and the convergence state."""
    lines = []
    for cid, camera in camera_tables(project, result).items():
        lines.append(f"camera {cid} ({project.camera_rows[cid][0]})")
        width = max(len(name) for name in camera.names)
        for k, name in enumerate(camera.names):
            status = camera.status[0][k]
            if status == FIXED:
                continue
            note = "  (weighted)" if status != "free" else ""
            lines.append(
                f"  {name.ljust(width)}  {camera.values[0, k]: .8e}"
                f" +/- {camera.stds[0, k]:.2e}{note}"
            )
    precision = result.precision
    lines.append(
        f"sigma0 {math.sqrt(precision.sigma0_squared):.6g}"
        f" (sigma0^2 {precision.sigma0_squared:.6g}, redundancy {precision.redundancy})"
    )
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
    n_iterations = max(len(result.iterations) - 1, 0)
    steps = f"{result.steps} solver steps, {result.backend} backend"
    if result.converged:
        lines.append(f"converged after {n_iterations} iterations ({steps})")
    else:
        lines.append(
            f"NOT converged after {n_iterations} iterations ({steps});"
            " the reports show the last iterate"
        )
        lines.append(f"  solver: {result.message}")
    return lines


def timing_line(timings: Timings) -> str:
    """E.g. `seconds: read 0.02, start-up 1.1, solve 0.03, ...; compile 4.2 (31 programs,
    29 from the cache)`: each phase's run seconds, compilation apart."""
    summary = timings.summary()
    phases = ", ".join(
        f"{name} {seconds:.2f}" for name, seconds in summary.items()
        if name not in ("compile", "total"))
    return (
        f"seconds: {phases}; compile {summary['compile']:.2f} ({timings.compilations}"
        f" programs, {timings.cache_hits} from the cache); total {summary['total']:.2f}")
