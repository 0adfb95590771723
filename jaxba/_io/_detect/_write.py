"""A `DetectedProject` as files: the project (docs/project-files.md), detections.csv and the
contact sheet. The project has image_units "pixel", one "opencv" camera per camera with OpenCV's
default free set, the board's points fixed (only those seen), Zhang's approximations and, for
a rig, rigs.toml and frames.txt; with a board warp, `board_warp = true` and every point of the
board (the extent its warp is normalised over). Numbers are written in full (`repr`)."""

import csv
import io
import json
import pathlib

from ..._files._atomic import replace_files
from ..._models._cameras._names import CAMERA_PARAMETER_NAMES
from ..._project._spec import MOUNT_NAMES
from .._project._project_file import project_toml, toml_text
from .._zhang import table_text
from ._project import DetectedProject
from ._sheet import contact_sheet

FREE = ("fx", "fy", "cx", "cy", "k1", "k2", "p1", "p2", "k3")  # OpenCV's calibrateCamera
DETECTIONS_FILE, SHEET_FILE = "detections.csv", "detections.png"
FILES = {"cameras": "cameras.toml", "images": "orientation.txt",
         "image_points": "image_coordinates.txt", "points": "board_points.txt"}
RIG_FILES = {"rigs": "rigs.toml", "frames": "frames.txt"}
IMAGE_SIGMA = 1.0  # pixel: σ̂0 is then about the RMS residual per coordinate


def _unit(project: DetectedProject) -> str:
    return project.board.unit or "board units"


def _cameras_toml(project: DetectedProject) -> str:
    lines = []
    for camera, start in project.starts.items():
        values = {"fx": start.fx, "fy": start.fy, "cx": start.cx, "cy": start.cy}
        n_used = len(project.used(camera))
        lines += [
            f"[{camera}]  # {n_used} images; approximations: {start.method}",
            'model = "opencv"  # pixels, distortion applied forward (computer-vision convention)',
            f"sensor = {toml_text(list(project.sizes[camera]))}",
            *(f"{p} = {float(values.get(p, 0.0))!r}" for p in CAMERA_PARAMETER_NAMES["opencv"]),
            f"free = {json.dumps(list(FREE))}",
            "",
        ]
    return "\n".join(lines)


def _rigs_toml(project: DetectedProject) -> str:
    reference = next(iter(project.starts))
    lines = [f"# The rig's frame is {reference}'s; approximations: the mean relative pose of the"
             " images of common frames", f"[{project.rig}]", f"reference = {toml_text(reference)}"]
    for camera, pose in project.relative.items():
        lines += ["", f"[{project.rig}.{camera}]"]
        lines += [f"{name} = {float(value)!r}" for name, value in zip(MOUNT_NAMES, pose)]
        lines.append(f"free = {json.dumps(list(MOUNT_NAMES))}")
    return "\n".join(lines) + "\n"


def _project_toml(project: DetectedProject, name: str, files: dict[str, str],
                  board_warp: bool) -> str:
    n_used = len(project.used())
    comment = [f"Written by jaxba detect: board {project.board.text()}, {n_used} of"
               f" {len(project.images)} images used ({DETECTIONS_FILE}, {SHEET_FILE}).",
               f"Board points in {_unit(project)}, fixed; image points in pixels."]
    adjustment = {"sigma0": 1.0, "image_sigma": IMAGE_SIGMA, "max_iterations": 100,
                  **({"board_warp": True} if board_warp else {})}
    notes = {"image_sigma": "pixel",
             "board_warp": "the board's warp kx, ky estimated (its points bent along Z)"}
    return project_toml(name, "pixel", files, adjustment, comment=comment, notes=notes)


def project_texts(project: DetectedProject, name: str, *, board_warp: bool = False
                  ) -> dict[str, str]:
    """File name -> text of the project files (`NAME.toml` and its tables); the project must
    use at least one image. `board_warp`: the board's warp estimated, and every point of
    the board in the points table (only those seen otherwise)."""
    if not project.starts:
        raise ValueError("no image with the board: no project to write")
    files = {**FILES, **(RIG_FILES if project.rig is not None else {})}
    used = project.used()
    points = project.board.points()
    seen = sorted({int(i) for image in used for i in image.detection.ids})
    if board_warp:  # the whole board: its extent normalises the warp
        seen = list(range(len(points)))
    eops = {image.id: eop for camera, start in project.starts.items()
            for image, eop in zip(project.used(camera), start.eops)}
    texts = {
        f"{name}.toml": _project_toml(project, name, files, board_warp),
        FILES["cameras"]: _cameras_toml(project),
        FILES["images"]: table_text(
            "image_id camera_id X0 Y0 Z0 (board frame) omega phi kappa (deg): Zhang's closed form",
            [[image.id, image.camera, *(repr(float(v)) for v in eops[image.id])]
             for image in used]),
        FILES["image_points"]: table_text(
            "image_id point_id col row (pixel; the centre of the top-left pixel at 0, 0)",
            [[image.id, str(i), repr(float(u)), repr(float(v))] for image in used
             for i, (u, v) in zip(image.detection.ids, image.detection.pixels)]),
        FILES["points"]: table_text(
            f"point_id X Y Z ({_unit(project)}; the board's plane Z = 0) sX sY sZ (0 = fixed)",
            [[str(i), *(repr(float(v)) for v in points[i]), "0", "0", "0"] for i in seen]),
    }
    if project.rig is not None:
        texts[RIG_FILES["rigs"]] = _rigs_toml(project)
        texts[RIG_FILES["frames"]] = table_text(
            "image_id frame_id (the number the image's file name ends in)",
            [[image.id, project.frames[image.id]] for image in used])
    return texts


def detections_csv(project: DetectedProject) -> str:
    """detections.csv: one row per image file, `camera,image_id,file,width,height,points,
    used,reason` (points: how many were found; used: yes or no; reason: why not)."""
    stream = io.StringIO()
    writer = csv.writer(stream, lineterminator="\n")
    writer.writerow(["camera", "image_id", "file", "width", "height", "points", "used",
                     "reason"])
    for image in project.images:
        detection = image.detection
        width, height = detection.size or ("", "")
        writer.writerow([image.camera, image.id, str(detection.path), width, height,
                         len(detection.ids), "yes" if detection.found else "no",
                         detection.reason])
    return stream.getvalue()


def detection_texts(project: DetectedProject) -> dict[str, str | bytes]:
    """File name -> contents of detections.csv and the contact sheet (PNG)."""
    return {DETECTIONS_FILE: detections_csv(project), SHEET_FILE: contact_sheet(project.images)}


def write_detected(project: DetectedProject, out_dir, name: str, *, board_warp: bool = False
                   ) -> list[pathlib.Path]:
    """Write detections.csv, the contact sheet and (where an image was used) the project into
    `out_dir` (created if needed), all files together; returns their paths, the project file
    first when there is one. `board_warp`: as for `project_texts`."""
    texts = {**(project_texts(project, name, board_warp=board_warp) if project.starts else {}),
             **detection_texts(project)}
    out_dir = pathlib.Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    paths = {out_dir / file: text for file, text in texts.items()}
    replace_files(paths)
    return list(paths)
