"""BASC-style text reports: NAME.out (parameters with σ), NAME.res (image residuals), NAME.sigma.

Columns are separated by at least two spaces and aligned (`_text_tables`); lines starting
with `#` in .res and .sigma are comments, so the data lines read back with any whitespace
splitter.
"""

import math

import numpy as np

from .._project._build import Project
from .._statistics._adjustment import Adjustment
from .._statistics._summary import aligned, statistical_items
from ._board_warp import board_warp
from ._collect import (
    MM,
    PIXEL,
    STATUS_CODE,
    ImageResiduals,
    ParameterTable,
    camera_correlations,
    camera_tables,
    camera_units,
    datum_text,
    describe,
    group_statistics,
    image_residuals,
    image_table,
    in_pixel_frame,
    outlier_check,
    point_ellipsoids,
    point_table,
    project_ids,
    project_units,
    rejections,
    reliability_summary,
    variance_check,
)
from ._no_sigma import no_sigma_lines
from ._rigs import frame_table, mount_correlations, mount_table, rig_baselines
from ._summaries import group_summaries, image_residual_summaries, residual_summaries
from ._text_tables import column_table, decimals_for, fixed, number_table, scientific, table

_MM_DECIMALS = 6  # image coordinates and residuals in mm (1 nm)
_PX_DECIMALS = 3  # residuals in pixels


def _flag(value: bool) -> str:
    return "yes" if value else "NO"


# --- NAME.out -------------------------------------------------------------------------------


def _header(project: Project, result: Adjustment) -> list[str]:
    from .. import __version__  # at call time: the report package may be imported by jaxba

    precision = result.precision
    items = [
        ("project", project.spec.name),
        ("project file", str(project.spec.path)),
        ("program", f"jaxba {__version__}"),
        ("converged", f"{_flag(result.converged)} ({result.message})"),
        ("iterations", f"{result.n_iterations} (solver steps {result.steps})"),
        ("a priori sigma0", f"{project.spec.settings.sigma0:g}"),
        ("a posteriori sigma0", f"{math.sqrt(precision.sigma0_squared):.6f}"),
        ("sigma0^2", f"{precision.sigma0_squared:.6f}"),
        ("observations", str(precision.n_observations)),
        ("unknowns", str(precision.n_unknowns)),
        ("redundancy", str(precision.redundancy)),
        ("solver backend", result.backend),
        *statistical_items(result, project_ids(project), group_statistics(project, result),
                           datum_text(project, result), variance_check(project, result),
                           outlier_check(project, result)),
    ]
    return [f"jaxba bundle adjustment: {project.spec.name}", "", *aligned(items, "  ")]


def _datum_section(project: Project) -> list[str]:
    """The points of a free network's inner constraints; none for other datums (the
    header's datum line describes them)."""
    datum = project.datum
    if datum["kind"] == "free":
        points = datum["points"]
        which = "all points" if points == "all" else f"points {' '.join(points)}"
        return ["datum: free network", f"  inner constraints over {which}"]
    return []


def _initialisation_section(project: Project) -> list[str]:
    """What the initialisation computed, deferred and left out (`Completion.summary()`,
    `Deferral.summary()`); none when the files held every approximation."""
    section = project.initialisation
    if section is None:
        return []
    lines = ["initialisation: approximations computed for"
             f" {len(section['computed_images'])} images and"
             f" {len(section['computed_points'])} points"]
    deferred = section.get("deferred_points", {})
    if deferred:
        lines.append(f"  deferred until the block was adjusted: {len(deferred)} points")
        for pid, reason in deferred.items():
            lines.append(f"    {pid}: {reason}")
    added = section.get("added_points", [])
    if added:
        lines.append(f"  intersected from the adjusted block and adjusted: {len(added)} points")
    left_out = section.get("left_out_points", {})
    if left_out:
        lines.append(f"  left out, with their image points: {len(left_out)} points")
        for pid, reason in left_out.items():
            lines.append(f"    {pid}: {reason}")
    return lines


def _camera_section(project: Project, cid: str, camera: ParameterTable) -> list[str]:
    spec = project.spec.cameras[cid]
    model = project.camera_rows[cid][0]
    pixel_model = camera_units(project, cid) == PIXEL
    details = [f"model {model}"]
    if spec.pixel_size is not None and not pixel_model:
        details.append(f"pixel size {spec.pixel_size[0]:g} x {spec.pixel_size[1]:g} mm")
    if spec.sensor is not None:
        details.append(f"sensor {spec.sensor[0]} x {spec.sensor[1]} px")
    details.append("pixel units" if pixel_model else "mm based units")
    rows = [
        [name, scientific(camera.values[0, k], 9), scientific(camera.stds[0, k], 3),
         camera.status[0][k]]
        for k, name in enumerate(camera.names)
    ]
    return [
        f"Camera {cid} ({', '.join(details)})",
        *table(["parameter", "value", "std", "status"], rows, "lrrl"),
    ]


def _correlation_section(cid: str, names: list[str], matrix: np.ndarray,
                         title: str = "IOP correlations of camera") -> list[str]:
    """Lower triangle of the correlation matrix of the estimated IOPs (or of what `title`
    names), two decimals."""
    if not names:
        return [f"{title} {cid}: no estimated parameters"]
    rows = [
        [name, *(f"{matrix[i, j]:.2f}" for j in range(i + 1)), *([""] * (len(names) - i - 1))]
        for i, name in enumerate(names)
    ]
    return [
        f"{title} {cid} (estimated parameters; |rho| near 1: hard to separate)",
        *table(["", *names], rows, "l" + "r" * len(names)),
    ]


def board_warp_section(project: Project, result: Adjustment) -> list[str]:
    """The boards' warp kx, ky with σ and ρ(kx, ky), and their correlations with every
    camera's estimated IOPs; [] where no board is warped."""
    warp = board_warp(project, result)
    if warp is None:
        return []
    decimals = decimals_for(warp.stds, low=4)
    lines = [
        "Board warp (object units; each point moved along the board's normal by"
        " kx (1 - x^2) + ky (1 - y^2), x, y from -1 to 1 over the board)",
        *column_table(["board", "kx", "ky", "skx", "sky", "rho"], [list(warp.ids)],
                      np.column_stack([warp.values, warp.stds, warp.rho]), [decimals] * 4 + [2]),
    ]
    for cid, (names, rho) in warp.cameras.items():
        if not names:
            continue
        lines += ["", f"Correlations of the board warp with the IOPs of camera {cid}",
                  *table(["", *names],
                         [[f"{board} {name}", *(f"{r:.2f}" for r in rho[b, k])]
                          for b, board in enumerate(warp.ids)
                          for k, name in enumerate(("kx", "ky"))], "l" + "r" * len(names))]
    return lines


def _variance_component_section(result: Adjustment) -> list[str]:
    components = result.variance_components
    rows = [
        [name, str(c.n_observations), f"{c.redundancy:.2f}", f"{c.sigma0:.4f}",
         f"{c.sigma0**2:.4f}"]
        for name, c in components.items()
    ]
    return [
        f"Variance components ({result.variance_iterations} iterations; sigma0 of a group ="
        " its estimated sigma / a priori sigma, 1 = prior right)",
        *table(["group", "n", "redundancy", "sigma0", "sigma0^2"], rows, "lrrrr"),
    ]


def _rejection_section(project: Project, result: Adjustment) -> list[str]:
    found = rejections(project, result)
    settings = project.spec.settings
    alpha = f"alpha {settings.snooping_alpha:g}"
    if getattr(settings, "snooping_familywise", False):
        alpha += " family-wise"
    if not found:
        return [f"Data snooping ({alpha}): no observation rejected"]
    rows = [
        [str(k + 1), entry["group"],
         describe({key: value for key, value in entry.items() if key not in ("group", "w")}),
         f"{entry['w']:.2f}"]
        for k, entry in enumerate(found)
    ]
    return [
        f"Data snooping ({alpha}): {len(found)} observation(s) rejected, in order of"
        " removal (|w| when rejected; an image point is removed whole)",
        *table(["#", "group", "observation", "|w|"], rows, "rllr"),
    ]


def _reliability_section(project: Project, result: Adjustment) -> list[str]:
    summary = reliability_summary(project, result)
    if summary is None:
        return []
    rows = [
        [name, str(g["n"]), f"{g['redundancy_sum']:.2f}", _optional(g["min_redundancy"], 3),
         _optional(g["mean_redundancy"], 3), _optional(g["max_abs_w"], 2), str(g["n_outliers"])]
        for name, g in summary.groups.items()
    ]
    rows.append([
        "all", str(summary.n), f"{summary.redundancy_sum:.2f}",
        _optional(summary.min_redundancy, 3), _optional(summary.mean_redundancy, 3),
        _optional(summary.max_abs_w, 2), str(summary.n_outliers),
    ])
    header = ["group", "n", "sum_r", "min_r", "mean_r", "max_|w|", "|w|>crit"]
    lines = [
        f"Reliability (redundancy numbers r in [0, 1] sum to the redundancy; normalised"
        f" residuals w, critical |w| {summary.critical_value:.2f} at per-test alpha"
        f" {summary.alpha:.3g})",
        *table(header, rows, "lrrrrrr"),
    ]
    if summary.max_abs_w_at:
        lines.append(f"  largest |w| {summary.max_abs_w:.2f}: {summary.max_abs_w_at}")
    return lines


def _ellipsoid_section(project: Project, result: Adjustment) -> list[str]:
    """The 1σ semi-axes of every point with a free coordinate; [] where there is none (a
    calibration on a fixed target)."""
    axes, _, has = point_ellipsoids(project, result)
    if not has.any():
        return []
    decimals = decimals_for(axes[has], low=4)
    ids = np.asarray(project.point_ids, dtype=object)[has].tolist()
    return [
        "Error ellipsoids of object points (1 sigma semi-axes, largest first, object units;"
        " points with free coordinates)",
        *column_table(["point", "a1", "a2", "a3"], [ids], axes[has], [decimals] * 3),
    ]


def _parameter_table(header: list[str], texts: list[list[str]], table_: ParameterTable,
                     decimals: list[int]) -> list[str]:
    """Lines of a parameter table: the text columns, values, σ, status codes."""
    status = np.asarray(table_.status, dtype=object).reshape(len(table_.ids), len(table_.names))
    codes = np.array(list(map(STATUS_CODE.__getitem__, status.ravel().tolist())), dtype="U1")
    # The k codes of a row read as one string of k characters.
    status = codes.reshape(status.shape).view(f"U{status.shape[1]}").ravel().tolist()
    numbers = np.column_stack([table_.values, table_.stds]) if len(table_.ids) else np.zeros(0)
    return column_table(header, [list(table_.ids), *texts], numbers, decimals * 2, [status])


def _image_section(project: Project, images: ParameterTable) -> list[str]:
    positions = decimals_for(images.stds[:, :3], low=4)
    angles = decimals_for(images.stds[:, 3:], low=4)
    cameras = [project.spec.images[iid].camera for iid in images.ids]
    header = ["image", "camera", *images.names, *(f"s{n}" for n in images.names), "status"]
    return [
        "Exterior orientation (X0 Y0 Z0 in object units; omega phi kappa in decimal degrees)",
        *_parameter_table(header, [cameras], images, [positions] * 3 + [angles] * 3),
    ]


def rig_section(project: Project, result: Adjustment) -> list[str]:
    """The rig cameras' poses in their rigs with σ, their baselines, the correlations of
    each relative pose, and the frames' poses."""
    mounts = mount_table(project, result)
    positions = decimals_for(mounts.stds[:, :3], low=4)
    angles = decimals_for(mounts.stds[:, 3:], low=4)
    header = ["camera", *mounts.names, *(f"s{n}" for n in mounts.names), "status"]
    baselines = rig_baselines(project, result)
    lengths = np.array(list(baselines.values()), dtype=float).reshape(-1, 2)
    decimals = decimals_for(lengths[:, 1], low=4)
    lines = [
        "Rigs: every camera's pose in its rig's frame (the reference camera's; X0 Y0 Z0 in"
        " object units, omega phi kappa in decimal degrees, rotation rig -> camera)",
        *_parameter_table(header, [], mounts, [positions] * 3 + [angles] * 3),
        "",
        "Baselines (the distance of each camera's perspective centre from its rig's"
        " reference camera's, object units)",
        *column_table(["camera", "baseline", "sbaseline"], [list(baselines)], lengths,
                      [decimals] * 2),
    ]
    for mid, (names, matrix) in mount_correlations(project, result).items():
        lines += ["", *_correlation_section(mid, names, matrix,
                                            "Correlations of the relative pose of")]
    frames = frame_table(project, result)
    positions = decimals_for(frames.stds[:, :3], low=4)
    angles = decimals_for(frames.stds[:, 3:], low=4)
    header = ["frame", *frames.names, *(f"s{n}" for n in frames.names), "status"]
    return lines + [
        "",
        "Frames: one pose per frame, the rig's (its reference camera's)",
        *_parameter_table(header, [], frames, [positions] * 3 + [angles] * 3),
    ]


def _point_section(points: ParameterTable) -> list[str]:
    decimals = decimals_for(points.stds, low=4)
    header = ["point", *points.names, *(f"s{n}" for n in points.names), "status"]
    return [
        "Object points (object units)",
        *_parameter_table(header, [], points, [decimals] * 3),
    ]


def _residual_summary_section(project: Project, result: Adjustment) -> list[str]:
    summaries = image_residual_summaries(project, result)
    in_pixels = project_units(project) == PIXEL
    rows = []
    for name, summary in [*summaries["cameras"].items(), ("all", summaries["all"])]:
        mm = [] if in_pixels else [
            _optional(summary[key], _MM_DECIMALS) for key in ("rms_x_mm", "rms_y_mm")
        ]
        px = [_optional(summary["rms_x_px"]), _optional(summary["rms_y_px"])]
        rows.append([name, str(summary["n"]), *mm, *px])
    header = ["camera", "n", *([] if in_pixels else ["rms_vx_mm", "rms_vy_mm"])]
    header += ["rms_vx_px", "rms_vy_px"]
    removed = summaries["all"]["n_removed"]
    note = f"; {removed} rejected by data snooping left out" if removed else ""
    groups = group_summaries(project, result)
    group_rows = [[name, str(g["n"]), f"{g['vtpv']:.4f}"] for name, g in groups.items()]
    return [
        f"Image residuals (RMS of v = observed - computed{note}; details in the .res file)",
        *table(header, rows, "l" + "r" * (len(header) - 1)),
        "",
        "Observation groups (vTPv with P = sigma0^2 inv(Sigma); the parts add up to"
        " sigma0^2 * redundancy)",
        *table(["group", "n", "vTPv"], group_rows, "lrr"),
    ]


def _optional(value: float, decimals: int = _PX_DECIMALS) -> str:
    return fixed(value, decimals) if math.isfinite(value) else "-"


def out_text(project: Project, result: Adjustment) -> str:
    """NAME.out: run summary, IOPs of every camera, EOPs of all images, object points, all with σ.

    Status: free, fixed (σ 0) or weighted (a prior σ or a GNSS/INS/control observation), and
    "constant" for a camera model's constants (the metrology model's r0); in the
    EOP and point tables one character per coordinate as in the input files: - free, 0 fixed,
    w weighted.
    """
    lines = _header(project, result)
    initialisation = _initialisation_section(project)
    lines += ["", *initialisation] if initialisation else []
    datum = _datum_section(project)
    lines += ["", *datum] if datum else []
    no_sigma = no_sigma_lines(project, result)
    lines += ["", *no_sigma] if no_sigma else []
    correlations = camera_correlations(project, result)
    for cid, camera in camera_tables(project, result).items():
        lines += ["", *_camera_section(project, cid, camera)]
        lines += ["", *_correlation_section(cid, *correlations[cid])]
    warp = board_warp_section(project, result)
    lines += ["", *warp] if warp else []
    lines += ["", *_residual_summary_section(project, result)]
    if result.variance_components is not None:
        lines += ["", *_variance_component_section(result)]
    if project.spec.settings.data_snooping or result.rejections:
        lines += ["", *_rejection_section(project, result)]
    reliability = _reliability_section(project, result)
    if reliability:
        lines += ["", *reliability]
    if project.rigs is not None:
        lines += ["", *rig_section(project, result)]
    lines += ["", *_image_section(project, image_table(project, result))]
    lines += ["", *_point_section(point_table(project, result))]
    ellipsoids = _ellipsoid_section(project, result)
    lines += ["", *ellipsoids] if ellipsoids else []
    lines += ["", "status per coordinate: - free, 0 fixed, w weighted (observed with a prior σ)"]
    return "\n".join(lines) + "\n"


# --- NAME.res -------------------------------------------------------------------------------


def _rms_comment(label: str, summary: dict) -> str:
    """`# RMS label  n ...  vx .. vy .. mm  vx .. vy .. px`, from a `residual_summaries` entry."""
    text = f"# RMS {label}  n {summary['n']}"
    if math.isfinite(summary["rms_x_mm"]):
        text += f"  vx {fixed(summary['rms_x_mm'], _MM_DECIMALS)}"
        text += f"  vy {fixed(summary['rms_y_mm'], _MM_DECIMALS)} mm"
    if math.isfinite(summary["rms_x_px"]):
        text += f"  vx {fixed(summary['rms_x_px'], _PX_DECIMALS)}"
        text += f"  vy {fixed(summary['rms_y_px'], _PX_DECIMALS)} px"
    removed = summary["n_removed"]
    return text + (f"  ({removed} rejected, not counted)" if removed else "")


def res_text(project: Project, result: Adjustment) -> str:
    """NAME.res: one line per measured image point, then RMS per image and overall.

    Columns: image_id point_id x y vx vy, in mm (or in pixels (col, row) when the project's
    image units are pixels or every camera model works in pixels, e.g. "opencv"; the vx_px
    vy_px columns are then left out), vx_px vy_px (v / pixel
    size, same axes as x, y; `-` for a camera without a pixel size), rx ry (redundancy
    numbers), wx wy (normalised residuals), outlier (1: rejected by data snooping or |w| above
    the critical value). v = observed - computed; `-` where a statistic is not available.
    """
    residuals = image_residuals(project, result)
    units = project_units(project)
    if project.spec.image_units == PIXEL and units != PIXEL:  # as the image points were given
        residuals, units = in_pixel_frame(project, residuals), PIXEL
    in_pixels = units == PIXEL
    if in_pixels:
        unit_line = "x y vx vy in pixels (col, row: row down)"
    elif units == MM:
        unit_line = "x y vx vy in mm, vx_px vy_px in pixels (x right, y up)"
    else:
        unit_line = (
            "x y vx vy in mm (x right, y up), or pixels (col, row) for cameras "
            + ", ".join(cid for cid in project.camera_rows if camera_units(project, cid) == PIXEL)
            + "; vx_px vy_px in pixels"
        )
    reliability = result.reliability
    test = (
        f"critical |w| {reliability.critical_value:.2f} at per-test alpha {reliability.alpha:.3g}"
        if reliability is not None else "no reliability computed"
    )
    head = [
        f"# jaxba image residuals: {project.spec.name}",
        f"# v = observed - computed; {unit_line}",
        f"# r redundancy numbers, w normalised residuals ({test}); outlier 1: rejected by data"
        " snooping (its v at the final solution, which did not use it) or |w| > critical",
    ]
    converted = residuals is not image_residuals(project, result)
    summaries = (residual_summaries(residuals) if converted
                 else image_residual_summaries(project, result))
    tail = ["#", *(_rms_comment(f"image {iid}", summary)
                   for iid, summary in summaries["images"].items())]
    tail.append(_rms_comment("all", summaries["all"]))
    return ("\n".join(head) + "\n" + _residual_table(residuals, project, with_px=not in_pixels)
            + "\n".join(tail) + "\n")


def _residual_table(residuals: ImageResiduals, project: Project, *, with_px: bool = True) -> str:
    """The rows of NAME.res (see `res_text`) with their header line, each ending in a newline."""
    header = ["image_id", "point_id", "x", "y", "vx", "vy"]
    header += ["vx_px", "vy_px"] if with_px else []
    header += ["rx", "ry", "wx", "wy", "outlier"]
    columns = [residuals.xy, residuals.v, *([residuals.v_px] if with_px else [])]
    columns += [residuals.redundancy, residuals.w, residuals.outlier[:, None]]
    statistics = [_PX_DECIMALS] * (2 * with_px) + [3, 3, 2, 2, 0]
    decimals = [[_MM_DECIMALS] * 4 + statistics, [_PX_DECIMALS + 1] * 4 + statistics]
    labels = [(list(project.image_ids), residuals.image),
              (list(project.point_ids), residuals.point)]
    kind = (residuals.units != MM).astype(int)
    return number_table(header, labels, np.column_stack(columns).astype(float), decimals, kind)


# --- NAME.sigma -----------------------------------------------------------------------------


def sigma_text(project: Project, result: Adjustment) -> str:
    """NAME.sigma: σ̂0² and cost ½ Σ (v/σ)² of every accepted iterate (0 = approximations)."""
    rows = [
        [str(it.iteration), f"{it.sigma0_squared:.10e}", f"{it.cost:.10e}"]
        for it in result.iterations
    ]
    lines = [
        f"# jaxba variance factor per iteration: {project.spec.name}",
        *table(["iteration", "sigma0_squared", "cost"], rows, "rrr", prefix="# "),
    ]
    return "\n".join(lines) + "\n"
