"""BASC-style text reports: NAME.out (parameters with σ), NAME.res (image residuals), NAME.sigma.

Columns are separated by at least two spaces and aligned; lines starting with `#` in .res
and .sigma are comments, so the data lines read back with any whitespace splitter.
"""

import math

import numpy as np

from .._project import Project
from .._solve import Adjustment
from ._collect import (
    STATUS_CODE,
    ImageResiduals,
    ParameterTable,
    camera_tables,
    group_summaries,
    image_residuals,
    image_table,
    point_table,
    residual_summaries,
)

_MM_DECIMALS = 6  # image coordinates and residuals in mm (1 nm)
_PX_DECIMALS = 3  # residuals in pixels


def table(header: list[str], rows: list[list[str]], align: str, *, prefix: str = "  ") -> list[str]:
    """Aligned lines: `align` has one "l" or "r" per column; the header gets `prefix` too."""
    widths = [max(len(row[k]) for row in [header, *rows]) for k in range(len(header))]

    def line(cells):
        padded = [
            cell.ljust(width) if side == "l" else cell.rjust(width)
            for cell, width, side in zip(cells, widths, align)
        ]
        return "  ".join(padded).rstrip()

    return [prefix + line(header), *("  " + line(row) for row in rows)]


def decimals_for(stds: np.ndarray, *, digits: int = 2, low: int = 3, high: int = 12) -> int:
    """Decimals that show the smallest positive σ with `digits` significant digits."""
    positive = np.asarray(stds, dtype=float)
    positive = positive[np.isfinite(positive) & (positive > 0)]
    if positive.size == 0:
        return low + 3
    wanted = math.ceil(-math.log10(positive.min())) + digits - 1
    return int(min(max(wanted, low), high))


def fixed(value: float, decimals: int) -> str:
    return f"{value:.{decimals}f}" if math.isfinite(value) else "nan"


def scientific(value: float, digits: int) -> str:
    return f"{value:.{digits}e}" if math.isfinite(value) else "nan"


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
        ("iterations", f"{max(len(result.iterations) - 1, 0)} (solver steps {result.steps})"),
        ("a priori sigma0", f"{project.spec.settings.sigma0:g}"),
        ("a posteriori sigma0", f"{math.sqrt(precision.sigma0_squared):.6f}"),
        ("sigma0^2", f"{precision.sigma0_squared:.6f}"),
        ("observations", str(precision.n_observations)),
        ("unknowns", str(precision.n_unknowns)),
        ("redundancy", str(precision.redundancy)),
    ]
    width = max(len(key) for key, _ in items)
    return [
        f"jaxba bundle adjustment: {project.spec.name}",
        "",
        *(f"  {key.ljust(width)}  {value}" for key, value in items),
    ]


def _camera_section(project: Project, cid: str, camera: ParameterTable) -> list[str]:
    spec = project.spec.cameras[cid]
    model = project.camera_rows[cid][0]
    details = [f"model {model}"]
    if spec.pixel_size is not None:
        details.append(f"pixel size {spec.pixel_size[0]:g} x {spec.pixel_size[1]:g} mm")
    if spec.sensor is not None:
        details.append(f"sensor {spec.sensor[0]} x {spec.sensor[1]} px")
    rows = [
        [name, scientific(camera.values[0, k], 9), scientific(camera.stds[0, k], 3),
         camera.status[0][k]]
        for k, name in enumerate(camera.names)
    ]
    return [
        f"Camera {cid} ({', '.join(details)}; mm based units)",
        *table(["parameter", "value", "std", "status"], rows, "lrrl"),
    ]


def _parameter_rows(table_: ParameterTable, decimals: list[int]) -> list[list[str]]:
    rows = []
    for k, pid in enumerate(table_.ids):
        values = [fixed(table_.values[k, j], d) for j, d in enumerate(decimals)]
        stds = [fixed(table_.stds[k, j], d) for j, d in enumerate(decimals)]
        status = "".join(STATUS_CODE[s] for s in table_.status[k])
        rows.append([pid, *values, *stds, status])
    return rows


def _image_section(project: Project, images: ParameterTable) -> list[str]:
    positions = decimals_for(images.stds[:, :3], low=4)
    angles = decimals_for(images.stds[:, 3:], low=4)
    rows = _parameter_rows(images, [positions] * 3 + [angles] * 3)
    for row, iid in zip(rows, images.ids):
        row.insert(1, project.spec.images[iid].camera)
    header = ["image", "camera", *images.names, *(f"s{n}" for n in images.names), "status"]
    return [
        "Exterior orientation (X0 Y0 Z0 in object units; omega phi kappa in decimal degrees)",
        *table(header, rows, "ll" + "r" * 12 + "l"),
    ]


def _point_section(points: ParameterTable) -> list[str]:
    decimals = decimals_for(points.stds, low=4)
    rows = _parameter_rows(points, [decimals] * 3)
    header = ["point", *points.names, *(f"s{n}" for n in points.names), "status"]
    return [
        "Object points (object units)",
        *table(header, rows, "l" + "r" * 6 + "l"),
    ]


def _residual_summary_section(project: Project, result: Adjustment) -> list[str]:
    summaries = residual_summaries(image_residuals(project, result))
    rows = []
    for name, summary in [*summaries["cameras"].items(), ("all", summaries["all"])]:
        rows.append([
            name, str(summary["n"]),
            fixed(summary["rms_x_mm"], _MM_DECIMALS), fixed(summary["rms_y_mm"], _MM_DECIMALS),
            _optional(summary["rms_x_px"]), _optional(summary["rms_y_px"]),
        ])
    header = ["camera", "n", "rms_vx_mm", "rms_vy_mm", "rms_vx_px", "rms_vy_px"]
    groups = group_summaries(project, result)
    group_rows = [[name, str(g["n"]), f"{g['vtpv']:.4f}"] for name, g in groups.items()]
    return [
        "Image residuals (RMS of v = observed - computed; details in the .res file)",
        *table(header, rows, "lrrrrr"),
        "",
        "Observation groups (vTPv with P = sigma0^2 inv(Sigma); the parts add up to"
        " sigma0^2 * redundancy)",
        *table(["group", "n", "vTPv"], group_rows, "lrr"),
    ]


def _optional(value: float, decimals: int = _PX_DECIMALS) -> str:
    return fixed(value, decimals) if math.isfinite(value) else "-"


def out_text(project: Project, result: Adjustment) -> str:
    """NAME.out: run summary, IOPs of every camera, EOPs of all images, object points, all with σ.

    Status: free, fixed (σ 0) or weighted (a prior σ or a GNSS/INS/control observation); in the
    EOP and point tables one character per coordinate as in the input files: - free, 0 fixed,
    w weighted.
    """
    lines = _header(project, result)
    for cid, camera in camera_tables(project, result).items():
        lines += ["", *_camera_section(project, cid, camera)]
    lines += ["", *_residual_summary_section(project, result)]
    lines += ["", *_image_section(project, image_table(project, result))]
    lines += ["", *_point_section(point_table(project, result))]
    lines += ["", "status per coordinate: - free, 0 fixed, w weighted (observed with a prior σ)"]
    return "\n".join(lines) + "\n"


# --- NAME.res -------------------------------------------------------------------------------


def _rms_comment(label: str, v: np.ndarray, v_px: np.ndarray) -> str:
    rms_mm = np.sqrt(np.mean(v**2, axis=0)) if len(v) else np.full(2, math.nan)
    text = f"# RMS {label}  n {len(v)}  vx {fixed(rms_mm[0], _MM_DECIMALS)}"
    text += f"  vy {fixed(rms_mm[1], _MM_DECIMALS)} mm"
    if len(v_px) and np.all(np.isfinite(v_px)):
        rms_px = np.sqrt(np.mean(v_px**2, axis=0))
        text += f"  vx {fixed(rms_px[0], _PX_DECIMALS)}  vy {fixed(rms_px[1], _PX_DECIMALS)} px"
    return text


def res_text(project: Project, result: Adjustment) -> str:
    """NAME.res: one line per measured image point, then RMS per image and overall.

    Columns: image_id point_id x y vx vy (mm) vx_px vy_px (v / pixel size, same axes as x, y;
    `-` for a camera without a pixel size). v = observed - computed.
    """
    residuals = image_residuals(project, result)
    rows = _residual_rows(residuals)
    header = ["image_id", "point_id", "x", "y", "vx", "vy", "vx_px", "vy_px"]
    lines = [
        f"# jaxba image residuals: {project.spec.name}",
        "# v = observed - computed; x y vx vy in mm, vx_px vy_px in pixels (x right, y up)",
        *table(header, rows, "llrrrrrr", prefix="# "),
        "#",
    ]
    images = np.asarray(residuals.image_ids, dtype=object)
    for iid in dict.fromkeys(residuals.image_ids):
        selected = images == iid
        lines.append(_rms_comment(f"image {iid}", residuals.v[selected], residuals.v_px[selected]))
    lines.append(_rms_comment("all", residuals.v, residuals.v_px))
    return "\n".join(lines) + "\n"


def _residual_rows(residuals: ImageResiduals) -> list[list[str]]:
    rows = []
    for k, (iid, pid) in enumerate(zip(residuals.image_ids, residuals.point_ids)):
        rows.append([
            iid, pid,
            *(fixed(value, _MM_DECIMALS) for value in residuals.xy[k]),
            *(fixed(value, _MM_DECIMALS) for value in residuals.v[k]),
            *(_optional(value) for value in residuals.v_px[k]),
        ])
    return rows


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
