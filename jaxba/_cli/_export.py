"""`jaxba export OUT_DIR --format opencv|colmap [--camera C1] [--to DIR]`: the calibrated
cameras (and rigs) of an adjustment's results.json in OpenCV's or COLMAP's conventions.

Reads OUT_DIR/results.json (and, for COLMAP, observations.csv beside it), turns every camera
(or those named) into the target's camera (`jaxba._io._export`: exact where the target has
its model, else OpenCV's model fitted over the sensor, its misfit printed and a warning above
0.1 px) and writes, all files replaced together, into DIR (default OUT_DIR/export/FORMAT):

- opencv: CAMERA.yml per camera (cv::FileStorage: camera_matrix, distortion_coefficients,
  image size), RIG_REFERENCE_CAMERA.yml per camera of a rig with its reference (OpenCV's stereo
  YAML: K1, D1, K2, D2, R, T, E, F);
- colmap: cameras.txt, images.txt, points3D.txt (a COLMAP text model), and with rigs
  rigs.txt and frames.txt (COLMAP 3.12's rigs and frames);
- export.json: what was written, and per camera exact or fitted (why, misfit in pixels).

DIR must be new, empty or an earlier export's (it holds export.json): nothing else is ever
replaced, and the earlier export's files that this one does not write are removed (a stale
rigs.txt would put the new images into the old frames). Registered by `jaxba._cli._main`
(`add_export`); jax is loaded only to fit.
"""

import argparse
import json
import math
import pathlib

from ._common import UsageError, common_options, print_error, say

_RESULTS, _OBSERVATIONS, _MANIFEST = "results.json", "observations.csv", "export.json"
_COLMAP_FILES = ("cameras.txt", "images.txt", "points3D.txt")
_DESCRIPTION = (
    "Write the calibrated cameras of an adjustment (OUT_DIR, the folder with its results.json)"
    " in OpenCV's or COLMAP's conventions into DIR (default OUT_DIR/export/FORMAT): opencv:"
    " CAMERA.yml per camera and, per camera of a rig, OpenCV's stereo YAML with the rig's"
    " reference (K1 D1 K2 D2 R T E F); colmap: cameras.txt, images.txt, points3D.txt (and"
    " rigs.txt, frames.txt with rigs); and export.json. A camera without an exact equivalent"
    " is fitted with OpenCV's model over its sensor, and the fit's misfit is reported (a"
    " warning above 0.1 px). Exit codes: 0 written, 2 bad input (or an output folder that"
    " cannot be used), 3 internal error, 130 interrupted."
)


def add_export(subparsers) -> None:
    """Register `jaxba export` with the options of every command."""
    parser = subparsers.add_parser(
        "export", help="write calibrated cameras (and rigs) for OpenCV or COLMAP",
        description=_DESCRIPTION, parents=[common_options()])
    parser.add_argument("out_dir", type=pathlib.Path, metavar="OUT_DIR",
                        help="the output folder of jaxba adjust (with results.json)")
    parser.add_argument("--format", choices=("opencv", "colmap"), required=True,
                        help="the target's conventions")
    parser.add_argument("--camera", action="append", default=None, metavar="C1",
                        help="export only this camera (repeat for more; default: all)")
    parser.add_argument("--to", type=pathlib.Path, default=None, metavar="DIR",
                        help="folder for the files (default OUT_DIR/export/FORMAT)")
    parser.add_argument(
        "--coefficients", type=int, choices=(4, 5, 8), default=5,
        help="OpenCV's distortion terms of a fitted camera: 4 (k1 k2 p1 p2: COLMAP's OPENCV),"
             " 5 (+ k3, OpenCV's default) or 8 (+ k4 k5 k6, the rational model)")
    parser.add_argument(
        "--exact", action="store_true",
        help="refuse a camera without an exact equivalent in the target (naming the parameter"
             " that has none) instead of fitting it")
    parser.set_defaults(run=run_export)




def _read_results(out_dir: pathlib.Path) -> dict:
    path = out_dir / _RESULTS
    if not out_dir.is_dir():
        raise UsageError(f"{out_dir}: no such folder (the output folder of jaxba adjust)")
    if not path.is_file():
        raise UsageError(f"{path}: no such file; OUT_DIR is the folder where jaxba adjust"
                         " wrote its reports")
    try:
        results = json.loads(path.read_text(encoding="utf-8"))
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as error:
        raise UsageError(f"{path}: cannot be read as JSON: {error}") from None
    if not isinstance(results, dict) or not isinstance(results.get("cameras"), dict):
        raise UsageError(f"{path}: not a results.json of jaxba (no \"cameras\")")
    return results


def _destination(args: argparse.Namespace) -> pathlib.Path:
    """DIR, checked: new, empty or an earlier export's (it holds export.json), and writable."""
    from jaxba._files import check_folder

    to = args.to if args.to is not None else args.out_dir / "export" / args.format
    if to.exists() and not to.is_dir():
        raise UsageError(f"{to}: not a folder (--to)")
    if to.is_dir() and any(to.iterdir()) and not (to / _MANIFEST).is_file():
        raise UsageError(f"{to}: the folder holds files that jaxba export did not write (no"
                         f" {_MANIFEST}); choose a new or empty folder (--to)")
    check_folder(to)
    return to


def _selected(cameras: dict, names: list[str] | None, where: pathlib.Path) -> list[str]:
    if names is None:
        return list(cameras)
    unknown = [name for name in names if name not in cameras]
    if unknown:
        raise UsageError(f"--camera {unknown[0]}: {where} has no such camera; its cameras:"
                         f" {', '.join(cameras)}")
    return list(dict.fromkeys(names))


def _earlier_files(to: pathlib.Path) -> set[str]:
    """The files an earlier export wrote into `to` (its export.json's "files"); none where
    there is no such export.json or it cannot be read."""
    try:
        names = json.loads((to / _MANIFEST).read_text(encoding="utf-8"))["files"]
    except (OSError, UnicodeDecodeError, json.JSONDecodeError, KeyError, TypeError):
        return set()
    return {name for name in names if isinstance(name, str) and pathlib.Path(name).name == name
            and name not in ("", ".", "..", _MANIFEST)}


def _file_name(*ids: str) -> str:
    """CAMERA.yml (or RIG_REF_CAMERA.yml) from IDs; refused where an ID is not a file name."""
    for name in ids:
        if not name or "/" in name or "\\" in name or name in (".", ".."):
            raise UsageError(f"{name!r}: cannot name a file; rename the camera or rig")
    return "_".join(ids) + ".yml"


def _describe(camera, target: str) -> str:
    """One line: the camera, its model and the target's, exact or the fit's misfit."""
    from jaxba._io._colmap import camera_to_colmap

    model = (f"OpenCV {camera.model}" if target == "opencv"
             else f"COLMAP {camera_to_colmap(camera.model, camera.values)[0]}")
    if camera.fitted is None:
        return f"{camera.id}: {camera.source_model} -> {model}: exact"
    return (f"{camera.id}: {camera.source_model} -> {model} fitted over {camera.image_size[0]}"
            f" x {camera.image_size[1]} pixels: misfit max {camera.max_misfit_px:.3g} px, RMS"
            f" {camera.rms_misfit_px:.3g} px ({camera.fitted})")


def _misfit_warning(camera, target: str, coefficients: int) -> str:
    from jaxba._io._export import TARGETS, WARN_MISFIT_PX

    hint = "" if coefficients == 8 else "; --coefficients 8 may fit it closer"
    return (f"camera {camera.id}: the exported {TARGETS[target]} camera misses the calibrated"
            f" {camera.source_model} camera by up to {camera.max_misfit_px:.3g} px (RMS"
            f" {camera.rms_misfit_px:.3g} px) over the sensor, above {WARN_MISFIT_PX} px: use"
            f" it only where that is small against the accuracy needed{hint}")


def _opencv_files(results: dict, exported: dict) -> tuple[dict[str, str], dict]:
    """The OpenCV YAML files by name and the rigs' part of export.json."""
    from jaxba._io._export import stereo_pairs
    from jaxba._io._opencv_yaml import opencv_yaml_text, stereo_yaml_text

    files = {}
    for camera in exported.values():
        extra = ({} if camera.fitted is None else
                 {"fit_max_misfit_px": camera.max_misfit_px,
                  "fit_rms_misfit_px": camera.rms_misfit_px})
        files[_file_name(camera.id)] = opencv_yaml_text(camera.model, camera.values,
                                                        camera.image_size, extra)
    rigs = {}
    for pair in stereo_pairs(results, exported):
        name = _file_name(pair.rig, pair.reference, pair.camera)
        if name in files:
            raise UsageError(f"{name}: both a camera's and a rig's file; rename one of them")
        cameras = [(c.id, c.model, c.values, c.image_size)
                   for c in (exported[pair.reference], exported[pair.camera])]
        files[name] = stereo_yaml_text(cameras, {"R": pair.r, "T": pair.t, "E": pair.e,
                                                 "F": pair.f}, {"baseline": pair.baseline})
        rigs.setdefault(pair.rig, {})[pair.camera] = {
            "file": name, "reference": pair.reference, "baseline": pair.baseline}
    return files, rigs


def _colmap_files(args, results: dict, cameras: dict, exported: dict) -> dict[str, str]:
    from jaxba._io._colmap import colmap_model_texts
    from jaxba._io._export import colmap_model
    from jaxba._report import read_observations

    path = args.out_dir / _OBSERVATIONS
    if not path.is_file():
        raise UsageError(f"{path}: no such file; a COLMAP export takes the image points from"
                         " observations.csv beside results.json")
    try:
        observations = read_observations(path)
    except (OSError, ValueError, KeyError) as error:
        raise UsageError(f"{path}: cannot be read: {error}") from None
    return colmap_model_texts(colmap_model(results, observations, cameras, exported))


def _manifest(args, exported: dict, files: list[str], rigs: dict) -> str:
    def number(value: float) -> float | None:
        return value if math.isfinite(value) else None

    entries = {
        camera.id: {
            "source_model": camera.source_model, "model": camera.model,
            "exact": camera.fitted is None, "no_exact_equivalent": camera.fitted,
            "max_misfit_px": number(camera.max_misfit_px),
            "rms_misfit_px": number(camera.rms_misfit_px),
            "image_size": list(camera.image_size),
            **({"file": _file_name(camera.id)} if args.format == "opencv" else {}),
        }
        for camera in exported.values()
    }
    return json.dumps({
        "format": args.format, "results": str((args.out_dir / _RESULTS).resolve()),
        "coefficients": args.coefficients, "files": files, "cameras": entries, "rigs": rigs,
    }, indent=2) + "\n"


def run_export(args: argparse.Namespace) -> int:
    """Export (module docstring); 0 when written. Bad input raises `UsageError`."""
    from jaxba._files import check_targets, output_lock, replace_files
    from jaxba._jax_setup import setup_jax

    results = _read_results(args.out_dir)  # before jax: bad input is reported at once
    where = args.out_dir / _RESULTS
    to = _destination(args)
    setup_jax()
    from jaxba._io._export import WARN_MISFIT_PX, export_camera, results_cameras

    try:
        cameras = results_cameras(results)
        selected = _selected(cameras, args.camera, where)
        exported = {}
        for cid in selected:
            exported[cid] = export_camera(cameras[cid], args.format,
                                          coefficients=args.coefficients, exact=args.exact)
            say(_describe(exported[cid], args.format))
        if args.format == "opencv":
            texts, rigs = _opencv_files(results, exported)
        else:
            texts, rigs = _colmap_files(args, results, cameras, exported), {}
    except (KeyError, TypeError, AttributeError) as error:
        raise UsageError(f"{where}: not a results.json of jaxba: {error!r} is missing or"
                         " malformed") from None
    except ValueError as error:
        raise UsageError(f"{where}: {error}") from None
    texts[_MANIFEST] = _manifest(args, exported, sorted(texts), rigs)
    paths = {to / name: text for name, text in texts.items()}
    with output_lock(to):
        _destination(args)  # again, under the lock
        check_targets(paths, [where, args.out_dir / _OBSERVATIONS], "the export")
        stale = _earlier_files(to) - set(texts)
        replace_files(paths)
        for name in stale:
            (to / name).unlink(missing_ok=True)
    for camera in exported.values():
        if camera.fitted is not None and camera.max_misfit_px > WARN_MISFIT_PX:
            print_error(_misfit_warning(camera, args.format, args.coefficients), "warning")
    say("wrote")
    for path in sorted(paths):
        say(f"  {path}")
    return 0
