"""`jaxba detect --board SPEC --camera NAME=GLOB [--camera ...] [--rig NAME] --out DIR`: a
calibration target found in images, written as a project (`jaxba._io._detect`).

Everything is checked before an image is read (the board, the cameras' names and files,
OpenCV, the output folder); the images are then detected in `--jobs` processes under a
progress bar, and the project, detections.csv and the contact sheet written into DIR
together. Exit codes: 0 written, 2 bad input (or no image with the board: detections.csv and
the contact sheet are still written), 3 internal error, 130 interrupted. No jax here.
"""

import argparse
import glob
import os
import pathlib
import re

from ._common import EXIT_BAD_INPUT, EXIT_OK, UsageError, common_options, print_error, say

_NAME = re.compile(r"^[A-Za-z0-9_-]+$")
_LISTED_LEFT_OUT = 10  # images left out named on the console (all are in detections.csv)
FEW_VIEWS = 3  # fewer views of a plane leave a camera's intrinsics undetermined (Zhang)
# The grammar of `jaxba._io._detect._board`, here so that building the parser (every
# command's start) does not import the detection code.
BOARD_HELP = (
    "the target: chessboard:COLSxROWS:SPACING (inner corners), circles:COLSxROWS:SPACING,"
    " acircles:COLSxROWS:SPACING (OpenCV's asymmetric grid) or"
    " charuco:COLSxROWS:SQUARE:MARKER:DICT[:first=N][:legacy] (squares, an ArUco dictionary"
    " such as 5X5_100, marker ids from N); SPACING, SQUARE and MARKER a number with an"
    " optional unit (mm, cm, m, in), e.g. chessboard:9x6:25mm"
)


def add_detect(subparsers) -> None:
    """Register `jaxba detect` with the options of every command."""
    parser = subparsers.add_parser(
        "detect",
        help="find a calibration target in images and write a project",
        description=(
            "Find the target's points in every image (OpenCV: pip install 'jaxba[images]') and"
            " write a project into DIR: one 'opencv' camera per --camera (the image size, fx fy"
            " cx cy k1 k2 p1 p2 k3 free, approximations from Zhang's closed form), the board's"
            " points fixed, the image points in pixels, detections.csv (every image: the points"
            " found, or why it is left out) and detections.png (a contact sheet). With --rig,"
            " images of different cameras whose file names end in the same number (left07.jpg,"
            " right07.jpg) are one frame of the rig; its reference is the first --camera."
            " Exit codes: 0 written, 2 bad input or no image with the board, 3 internal error,"
            " 130 interrupted."
        ),
        parents=[common_options()],
    )
    parser.add_argument("--board", required=True, metavar="SPEC", help=BOARD_HELP)
    parser.add_argument(
        "--camera", required=True, action="append", metavar="NAME=GLOB",
        help="a camera and its images (a file pattern; quote it so that the shell leaves it);"
             " repeat it for several cameras")
    parser.add_argument("--rig", metavar="NAME",
                        help="the cameras are one rig: write rigs.toml and frames.txt")
    parser.add_argument("--board-warp", action="store_true",
                        help="estimate the board's warp: its points bent along the board's"
                             " normal by kx (1 - x^2) + ky (1 - y^2), x, y from -1 to 1 over the"
                             " board (mrcal's model); writes board_warp = true and every"
                             " point of the board")
    parser.add_argument("--out", type=pathlib.Path, required=True, metavar="DIR",
                        help="folder for the project (created if needed; must be empty)")
    parser.add_argument("--name", default="calibration",
                        help="the project's name: NAME.toml (default: calibration)")
    parser.add_argument("--jobs", type=int, default=None, metavar="N",
                        help="processes detecting images (default: one per CPU where the"
                             " images take long enough to pay for starting them, else 1)")
    parser.add_argument("--progress", action=argparse.BooleanOptionalAction, default=None,
                        help="a bar over the images (default: only on a terminal)")
    parser.set_defaults(run=run_detect)



def _natural(path: pathlib.Path) -> list:
    """Sort key: numbers in the name compared as numbers (left2 before left10)."""
    return [int(part) if part.isdigit() else part for part in re.split(r"([0-9]+)", str(path))]


def _cameras(specs: list[str]) -> dict[str, list[pathlib.Path]]:
    """Camera name -> its image files (sorted) of each `--camera NAME=GLOB`. A pattern
    without wildcards is one file, listed as missing if it is; one with wildcards must match
    a file."""
    cameras: dict[str, list[pathlib.Path]] = {}
    for spec in specs:
        name, equals, pattern = spec.partition("=")
        if not equals or not pattern:
            raise UsageError(f"--camera {spec}: expected NAME=GLOB, e.g."
                             " left='img/left*.jpg'")
        if not _NAME.match(name):
            raise UsageError(f"--camera {spec}: the name {name!r} may only have letters,"
                             " digits, '_' and '-'")
        if name in cameras:
            raise UsageError(f"--camera {spec}: camera {name} is given twice")
        pattern = os.path.expanduser(pattern)
        if glob.has_magic(pattern):
            files = [pathlib.Path(f) for f in glob.glob(pattern, recursive=True)
                     if not os.path.isdir(f)]
            if not files:
                raise UsageError(f"--camera {spec}: {pattern} matches no file")
        else:
            files = [pathlib.Path(pattern)]
        cameras[name] = sorted(files, key=_natural)
    return cameras


def _check_out(out_dir: pathlib.Path) -> None:
    from jaxba._files import OutputError, check_folder

    if out_dir.exists() and (not out_dir.is_dir() or any(out_dir.iterdir())):
        raise OutputError(f"{out_dir}: output folder is not empty; jaxba detect writes a new"
                          " project into a new or empty folder (--out)")
    check_folder(out_dir)


def _checked(args: argparse.Namespace):
    """The board and the cameras' files, everything checked before an image is read."""
    from jaxba._io._detect import BoardError, OpenCVMissingError, charuco_board, parse_board

    try:
        board = parse_board(args.board)
        if board.kind == "charuco":
            charuco_board(board)  # imports OpenCV, checks the dictionary
    except (BoardError, OpenCVMissingError) as error:
        raise UsageError(str(error)) from None
    if args.jobs is not None and args.jobs < 1:
        raise UsageError(f"--jobs {args.jobs}: must be at least 1")
    cameras = _cameras(args.camera)
    if args.rig is not None:
        if not _NAME.match(args.rig):
            raise UsageError(f"--rig {args.rig}: the name may only have letters, digits,"
                             " '_' and '-'")
        if len(cameras) < 2:
            raise UsageError(f"--rig {args.rig}: a rig needs two --camera or more")
        if args.rig in cameras:
            raise UsageError(f"--rig {args.rig}: a camera has that name")
    if not _NAME.match(args.name):
        raise UsageError(f"--name {args.name}: may only have letters, digits, '_' and"
                         " '-'")
    _check_out(args.out)
    return board, cameras


def run_detect(args: argparse.Namespace) -> int:
    """`jaxba detect` (module docstring); returns the exit code."""
    from jaxba._files import output_lock
    from jaxba._io._detect import OpenCVMissingError, import_cv2

    board, cameras = _checked(args)
    try:
        import_cv2()
    except OpenCVMissingError as error:
        raise UsageError(str(error)) from None
    with output_lock(args.out):
        return _detect_locked(args, board, cameras)


def _detect_locked(args, board, cameras: dict[str, list[pathlib.Path]]) -> int:
    from jaxba._cli._progress_bar import project_progress
    from jaxba._io._detect import DetectError, detect_images, detected_project, write_detected

    paths = [path for files in cameras.values() for path in files]
    say(f"detecting {board.text()} in {len(paths)} images of {len(cameras)} camera"
        f"{'s' if len(cameras) > 1 else ''}")
    with project_progress(len(paths), say, bar=args.progress, noun="images") as progress:
        found = iter(detect_images(paths, board, jobs=args.jobs, advance=progress.advance))
    detections = {camera: [next(found) for _ in files] for camera, files in cameras.items()}
    error = None
    try:
        project = detected_project(board, detections, rig=args.rig)
    except DetectError as detect_error:  # still list the detections
        error, project = str(detect_error), detect_error.project
    try:
        written = write_detected(project, args.out, args.name, board_warp=args.board_warp)
    except OSError as write_error:
        print_error(f"{args.out}: {write_error}")
        return EXIT_BAD_INPUT
    few = []
    for camera, files in cameras.items():
        used = project.used(camera)
        start = project.starts.get(camera)
        how = f"; approximations: {start.method}" if start else ""
        say(f"  {camera}: the board in {len(used)} of {len(files)} images{how}")
        few += [f"{camera} ({len(used)})"] if start and len(used) < FEW_VIEWS else []
    left_out = [image for image in project.images if not image.detection.found]
    for image in left_out[:_LISTED_LEFT_OUT]:
        say(f"  left out {image.detection.path}: {image.detection.reason}")
    if len(left_out) > _LISTED_LEFT_OUT:
        say(f"  ... and {len(left_out) - _LISTED_LEFT_OUT} more (detections.csv)")
    say(f"wrote {args.out}: {', '.join(path.name for path in written)}")
    if few:
        print_error(f"the board in fewer than {FEW_VIEWS} images of {', '.join(few)}: a camera's"
                    " focal lengths and principal point need three views of the board or more,"
                    " at different angles", "warning")
    if error is None and not project.starts:
        error = "the board was found in no image (detections.csv, detections.png)"
    if error is not None:
        print_error(str(error))
        return EXIT_BAD_INPUT
    say(f"adjust it with: jaxba adjust {written[0]}")
    return EXIT_OK
