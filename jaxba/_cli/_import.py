"""`jaxba import dbat|colmap|zhang|bal SOURCE --out DIR`: a jaxba project from another
program's files, written into a new or empty folder."""

import argparse
import pathlib
import shutil
import tempfile

from ._common import EXIT_OK, UsageError, common_options, print_error, say

_IMPORT_SOURCES = {
    "dbat": "a DBAT XML script",
    "colmap": "a COLMAP model folder (binary or text: cameras, images, points3D; rigs and"
              " frames where it has them)",
    "zhang": "Zhang's data folder (Model.txt, data1.txt .. data5.txt)",
    "bal": "a BAL problem file (plain, .bz2 or .gz)",
}


def add_import(subparsers) -> None:
    parser = subparsers.add_parser(
        "import",
        help="write a jaxba project from another program's files",
        description=(
            "Write a jaxba project (NAME.toml and its tables) into DIR from SOURCE: "
            + "; ".join(f"{kind}: {what}" for kind, what in _IMPORT_SOURCES.items())
            + ". DIR must be new or empty: nothing is ever written over a file. Exit codes:"
            " 0 written, 2 bad input (or an output folder that cannot be used), 3 internal"
            " error, 130 interrupted."
        ),
        parents=[common_options()],
    )
    parser.add_argument("kind", choices=tuple(_IMPORT_SOURCES), help="the source's format")
    parser.add_argument("source", type=pathlib.Path, help="the file or folder to import")
    parser.add_argument(
        "--out", type=pathlib.Path, required=True, metavar="DIR",
        help="folder for the project (created if needed; must be empty)",
    )
    parser.add_argument("--name", default=None,
                        help="the project's name (default: the source's name)")
    parser.set_defaults(run=run)


def _import_folder(out_dir: pathlib.Path) -> None:
    """Refuse an output folder that exists and is not empty, or cannot be written."""
    from jaxba._files import OutputError, check_folder

    if out_dir.exists() and (not out_dir.is_dir() or any(out_dir.iterdir())):
        raise OutputError(f"{out_dir}: output folder is not empty; jaxba import writes a new"
                          " project into a new or empty folder (--out)")
    check_folder(out_dir)


def run(args: argparse.Namespace) -> int:
    from jaxba import _io
    from jaxba._io._bal import BalFormatError, write_bal_project

    if not args.source.exists():
        raise UsageError(f"{args.source}: no such file or folder")
    _import_folder(args.out)
    name = args.name or args.source.name.split(".")[0] or args.kind
    writers = {
        "dbat": lambda out: _io.write_dbat_project(args.source, out, name=name),
        "colmap": lambda out: _io.write_colmap_project(
            args.source, out, name=name, warn=lambda message: print_error(message, "warning")),
        "zhang": lambda out: _io.write_zhang_project(args.source, out, name=name),
        "bal": lambda out: write_bal_project(args.source, out, name=name),
    }
    # Written into a fresh sibling folder, renamed to DIR when complete: a failed import
    # leaves nothing behind.
    args.out.parent.mkdir(parents=True, exist_ok=True)
    staging = pathlib.Path(tempfile.mkdtemp(prefix=f".{args.out.name}.", dir=args.out.parent))
    try:
        written = writers[args.kind](staging)
        if args.out.exists():
            args.out.rmdir()  # empty (`_import_folder`)
        staging.rename(args.out)
    except (OSError, ValueError, BalFormatError) as error:
        raise UsageError(f"{args.kind} import of {args.source}: {error}") from None
    finally:
        shutil.rmtree(staging, ignore_errors=True)
    project_file = args.out / written.project_file.name
    files = sorted(path.name for path in args.out.iterdir())
    say(f"wrote {args.out}: {', '.join(files)}")
    say(f"adjust it with: jaxba adjust {project_file}")
    return EXIT_OK
