"""Write a project (its TOML file and every table) into a folder: `jaxba init`'s output.

No jax here. The tables keep their names (the file names, without their folders) and their
text: cameras, image points and distances are copied byte for byte; the images and points
tables are copied with the computed approximations filled in: an image row's `-` EOPs
replaced by the values (its σ columns and comment kept, a comment saying how they were
found), the computed tie points appended to the points table as `ID X Y Z - - -` rows.
Numbers are written in full (`repr`), so that the project reads back to the same values.
Never over an input: `project_paths` is checked against the project's input files before
anything is computed, and the files are replaced together (`replace_files`).
"""

import pathlib
import tomllib

from ..._files._atomic import replace_files
from ..._files._paths import OutputError, check_folder, check_targets
from ..._project._errors import ProjectError
from ..._project._spec import ProjectSpec
from ._project_file import project_toml

_ANGLES = slice(3, 6)


def project_paths(spec: ProjectSpec, out_dir) -> dict[str, pathlib.Path]:
    """The files of `spec` written into `out_dir`: "project" (the TOML file, its name kept)
    and one per `[files]` key, each under its file name.

    Raises `OutputError` when `out_dir` is the input project's folder, cannot be written
    (`check_folder`), or a target is an input file, a folder, or two tables share a name.
    """
    out_dir = pathlib.Path(out_dir)
    if out_dir.resolve() == spec.path.parent:
        raise OutputError(
            f"{out_dir}: the folder of the input project {spec.path.name}; the completed project"
            " would overwrite it: choose another output folder (--out)")
    check_folder(out_dir)
    paths = {"project": out_dir / spec.path.name}
    for key, path in spec.files.items():
        target = out_dir / path.name
        taken = [k for k, p in paths.items() if p.name == target.name]
        if taken:
            raise OutputError(
                f"{target}: the {key} table {spec.file_names[key]} and the {taken[0]} file have"
                " the same name; rename one to write the project into one folder")
        paths[key] = target
    check_targets(paths.values(), spec.input_files, f"project {spec.name!r}")
    return paths


def project_texts(
    spec: ProjectSpec, paths: dict[str, pathlib.Path], *, source: ProjectSpec | None = None,
    image_methods: dict[str, str] | None = None, point_methods: dict[str, str] | None = None,
    deferred=(),
) -> dict[pathlib.Path, str | bytes]:
    """The contents of `paths` (`project_paths`) for the completed `spec`.

    `source`: the spec as read (its `-` rows and absent points are those written with the
    values of `spec`; default `spec` itself: copies); `image_methods`, `point_methods`: ID ->
    how its approximation was found (`Completion`), said in a comment; `deferred`: points
    left without approximations (absent from the points table, `Completion.deferred`).
    """
    source = spec if source is None else source
    computed = [p for p in source.missing_points if p not in set(deferred)]
    texts: dict[pathlib.Path, str | bytes] = {
        paths["project"]: _project_toml(spec, paths, len(source.missing_images),
                                        len(computed)),
    }
    for key, path in paths.items():
        if key != "project":
            texts[path] = spec.files[key].read_bytes()
    if source.missing_images:
        texts[paths["images"]] = _images_text(spec, source.missing_images, image_methods or {})
    if computed:
        texts[paths["points"]] = _points_text(spec, computed, point_methods or {})
    return texts


def write_project(
    spec: ProjectSpec, out_dir, *, source: ProjectSpec | None = None,
    image_methods: dict[str, str] | None = None, point_methods: dict[str, str] | None = None,
    deferred=(),
) -> list[pathlib.Path]:
    """Write the complete project `spec` into `out_dir` (created if needed): its TOML file
    and every table (module docstring), never over an input (`OutputError`), all files
    together. `source`, `image_methods`, `point_methods`, `deferred`: as `project_texts`
    (the `deferred` points may miss their approximations). The written project is read
    back: returns its paths, the TOML file first.

    Raises `ProjectError` if `spec` still misses approximations (`complete_project` first).
    """
    if spec.missing_images or set(spec.missing_points) - set(deferred):
        raise ProjectError(f"{spec.path.name}: approximations are missing; complete_project"
                           " computes them before the project is written")
    paths = project_paths(spec, out_dir)
    texts = project_texts(spec, paths, source=source, image_methods=image_methods,
                          point_methods=point_methods, deferred=deferred)
    pathlib.Path(out_dir).mkdir(parents=True, exist_ok=True)
    replace_files(texts)
    from ._readers import read_project

    written = read_project(paths["project"])
    same = ({i: image.eop for i, image in written.images.items()}
            == {i: image.eop for i, image in spec.images.items()}
            and {p: point.xyz for p, point in written.points.items()}
            == {p: point.xyz for p, point in spec.points.items()})
    if not same:  # a bug, not bad input
        raise RuntimeError(f"{paths['project']}: the written project does not read back as"
                           " the completed one")
    return list(paths.values())


# --- the files ------------------------------------------------------------------------------


def _project_toml(spec: ProjectSpec, paths, n_images: int, n_points: int) -> str:
    """The project file: [project] and [adjustment] as the input's, [files] the names."""
    with spec.path.open("rb") as stream:
        adjustment = tomllib.load(stream).get("adjustment", {})
    comment = [f"Written by jaxba init from {spec.path}"]
    if n_images or n_points:
        comment.append(f"with the approximations of {n_images} images and {n_points} points"
                       " computed.")
    files = {key: path.name for key, path in paths.items() if key != "project"}
    text = project_toml(spec.name, spec.image_units, files, adjustment, comment=comment)
    if tomllib.loads(text).get("adjustment", {}) != adjustment:  # a bug, not bad input
        raise RuntimeError(f"{spec.path.name}: [adjustment] did not survive being rewritten")
    return text


def _lines(path: pathlib.Path) -> list[str]:
    """The lines of a table as the readers see them (BOM dropped, any line ending)."""
    with path.open(encoding="utf-8-sig") as stream:
        return stream.read().split("\n")


def _images_text(spec: ProjectSpec, missing: list[str], computed: dict[str, str]) -> str:
    """The images table with the computed EOPs (degrees) in the rows that had `-`."""
    lines = _lines(spec.files["images"])
    for image_id in missing:
        image = spec.images[image_id]
        data, _, comment = lines[image.line - 1].partition("#")
        tokens = data.split()
        tokens[2:8] = [repr(float(value)) for value in image.eop]
        note = f"computed by jaxba init ({computed[image_id]})" if image_id in computed else ""
        comment = "; ".join(part for part in (comment.strip(), note) if part)
        lines[image.line - 1] = " ".join(tokens) + (f"  # {comment}" if comment else "")
    return "\n".join(lines)


def _points_text(spec: ProjectSpec, missing: list[str], computed: dict[str, str]) -> str:
    """The points table with the computed tie points appended as free rows."""
    text = "\n".join(_lines(spec.files["points"]))
    if text and not text.endswith("\n"):
        text += "\n"
    methods = sorted({computed[p] for p in missing if p in computed})
    rows = [f"# {len(missing)} tie points computed by jaxba init"
            + (f" ({', '.join(methods)})" if methods else "") + ", free"]
    rows += [" ".join([point_id, *(repr(float(v)) for v in spec.points[point_id].xyz),
                       "-", "-", "-"]) for point_id in missing]
    return text + "\n".join(rows) + "\n"
