"""DBAT XML scripts (`<document dbat_script_version=...>`): the `<input>` block and the
`<operations>` jaxba follows, as a plain record for `write_dbat_project`.

Supported elements (docs/dbat.md): input `ctrl_pts`, `check_pts` (each a `<file format=...>`
and `<filter id="...">keep|remove</filter>`), `images`, `image_pts` (one or more files, each
with its format and `sxy`/`sx`/`sy`), `prior_eo` (format and `units`), `cameras` (`<camera>`
blocks or a camera `<file>`); operations `check_ray_count`, `set_initial_values`,
`set_bundle_estimate_params`, `spatial_resection`, `forward_intersection`, `set_datum`
(`depend`, `ref_cam`, `ref_base` "longest") and `bundle_adjustment`. `<meta>`, `<output>`
and `<c>` comments are not used. Anything else is refused with a message naming the element
and the file: nothing is skipped silently. Plain Python.
"""

import dataclasses
import os
import pathlib
import xml.etree.ElementTree as ET

from ._camera import DbatCamera, parse_camera, read_cameras, read_xml
from ._tables import (
    ControlPoint,
    MarkPoint,
    PriorEo,
    read_control_points,
    read_images,
    read_mark_points,
    read_prior_eo,
)

IO_FIELDS = ("cc", "pp", "K", "P", "aspect", "skew")
EO_NAMES = ("x", "y", "z", "omega", "phi", "kappa")
MARKER_OPERATIONS = ("spatial_resection", "forward_intersection", "bundle_adjustment")


@dataclasses.dataclass(frozen=True)
class DbatOperations:
    """What the `<operations>` ask of the bundle.

    `min_rays`: check_ray_count's (None: not asked); `io_initial`: IO field (`IO_FIELDS`) ->
    "default", "loaded" or its values; `io_free`: jaxba IO parameter -> estimated;
    `eo_estimate` (6: X0 .. kappa), `op_estimate` (3: X Y Z): "true", "false" or "default"
    (DBAT's: estimate where the prior σ is not 0); `datum_image`: the DBAT image ID of
    `set_datum depend` (None: the datum of the control)."""

    min_rays: int | None = None
    io_initial: dict[str, object] = dataclasses.field(default_factory=dict)
    io_free: dict[str, bool] = dataclasses.field(default_factory=dict)
    eo_estimate: tuple[str, ...] = ("true",) * 6
    op_estimate: tuple[str, ...] = ("default",) * 3
    datum_image: str | None = None


@dataclasses.dataclass(frozen=True)
class DbatScript:
    """A DBAT script's input and operations; IDs as jaxba strings (`7`, not `007`)."""

    path: pathlib.Path
    control: dict[str, ControlPoint]
    control_file: pathlib.Path | None
    check: dict[str, ControlPoint]
    images: dict[str, str]
    images_file: pathlib.Path
    marks: list[MarkPoint]
    mark_files: tuple[pathlib.Path, ...]
    prior_eo: dict[str, PriorEo]
    cameras: tuple[DbatCamera, ...]
    operations: DbatOperations


def _children(element: ET.Element, allowed: tuple[str, ...], where: str) -> list[ET.Element]:
    """`element`'s children but `<c>` comments, each one of `allowed`."""
    children = [child for child in element if child.tag != "c"]
    for child in children:
        if child.tag not in allowed:
            raise ValueError(f"{where}: <{element.tag}>: unsupported element <{child.tag}> "
                             f"(supported: {', '.join(f'<{a}>' for a in allowed)})")
    return children


def _attributes(element: ET.Element, allowed: tuple[str, ...], where: str) -> dict[str, str]:
    unknown = [a for a in element.attrib if a not in allowed]
    if unknown:
        raise ValueError(f"{where}: <{element.tag}>: unsupported attribute {unknown[0]!r}")
    return dict(element.attrib)


def _text(element: ET.Element) -> str:
    return (element.text or "").strip()


def _path(text: str, base: pathlib.Path, where: str) -> pathlib.Path:
    """A DBAT path: `$HERE` (the script's folder), `$HOME`, absolute, or relative to `base`."""
    text = text.strip().replace("\\", "/")
    if text.startswith("$DBAT"):
        raise ValueError(f"{where}: {text!r}: $DBAT (DBAT's installation) is not supported")
    if text.startswith("$HOME"):
        return pathlib.Path(text.replace("$HOME", str(pathlib.Path.home()), 1))
    if text.startswith("$HERE"):
        return pathlib.Path(text.replace("$HERE", str(base), 1))
    return base / text


def _files(block: ET.Element, where: str, extra: tuple[str, ...] = ()) -> list[ET.Element]:
    files = [c for c in _children(block, ("file", *extra), where) if c.tag == "file"]
    if not files:
        raise ValueError(f"{where}: <{block.tag}>: no <file>")
    return files


def _points(block: ET.Element, base, where) -> tuple[dict[str, ControlPoint], pathlib.Path]:
    """<ctrl_pts> or <check_pts>: one file and its filters (DBAT's keep/remove by id)."""
    files = _files(block, where, ("filter",))
    if len(files) > 1:
        raise ValueError(f"{where}: <{block.tag}>: one <file>, got {len(files)}")
    attributes = _attributes(files[0], ("format",), f"{where}: <{block.tag}>")
    path = _path(_text(files[0]), base, where)
    points = read_control_points(path, attributes.get("format"))
    for element in block.findall("filter"):
        ids = {str(int(v)) for v in _attributes(element, ("id",), where).get("id", "").split(",")
               if v.strip()}
        action = _text(element)
        if action not in ("keep", "remove"):
            raise ValueError(f"{where}: <{block.tag}><filter>: expected keep or remove, got "
                             f"{action!r}")
        points = {pid: p for pid, p in points.items() if (pid in ids) == (action == "keep")}
    return points, path


def _cameras(block: ET.Element, base, where) -> tuple[DbatCamera, ...]:
    children = _children(block, ("camera", "file"), where)
    if [c.tag for c in children].count("file") > 1 or (
            any(c.tag == "file" for c in children) and len(children) > 1):
        raise ValueError(f"{where}: <cameras>: either <camera> blocks or one <file>")
    if children and children[0].tag == "file":
        return read_cameras(_path(_text(children[0]), base, where))
    if not children:
        raise ValueError(f"{where}: <cameras>: no <camera>")
    return tuple(parse_camera(c, where, k) for k, c in enumerate(children, start=1))


def _read_input(block: ET.Element, script: pathlib.Path) -> dict:
    where = script.name
    allowed = ("ctrl_pts", "check_pts", "images", "prior_eo", "image_pts", "cameras")
    attributes = _attributes(block, ("base_dir",), where)
    base = _path(attributes.get("base_dir", "$HERE"), script.parent, where)
    found = {}
    for child in _children(block, allowed, where):
        if child.tag in found:
            raise ValueError(f"{where}: <input>: <{child.tag}> given twice")
        found[child.tag] = child
    for tag in ("images", "image_pts", "cameras"):
        if tag not in found:
            raise ValueError(f"{where}: <input>: missing <{tag}>")
    control, control_file = ({}, None)
    if "ctrl_pts" in found:
        control, control_file = _points(found["ctrl_pts"], base, where)
    check = _points(found["check_pts"], base, where)[0] if "check_pts" in found else {}
    both = sorted(set(control) & set(check))
    if both:
        raise ValueError(f"{where}: point {both[0]} is both a control and a check point")
    _attributes(found["images"], ("image_base_dir",), where)  # the images are not read
    (image_file,) = _files(found["images"], where)[:1]
    images_path = _path(_text(image_file), base, where)
    images = read_images(images_path,
                         _attributes(image_file, ("format",), where).get("format"))
    marks, mark_files = [], []
    for element in _files(found["image_pts"], where):
        attributes = _attributes(element, ("format", "sxy", "sx", "sy"), f"{where}: <image_pts>")
        try:
            sigma = {k: float(v) for k, v in attributes.items() if k != "format"}
        except ValueError:
            raise ValueError(f"{where}: <image_pts><file>: σ attributes must be numbers, got "
                             f"{attributes}") from None
        mark_files.append(_path(_text(element), base, where))
        marks += read_mark_points(mark_files[-1], attributes.get("format"), sigma)
    prior = {}
    if "prior_eo" in found:
        (element,) = _files(found["prior_eo"], where)[:1]
        attributes = _attributes(element, ("format", "units"), f"{where}: <prior_eo>")
        prior = read_prior_eo(_path(_text(element), base, where), attributes.get("format"),
                              attributes.get("units"))
    return dict(control=control, control_file=control_file, check=check, images=images,
                images_file=images_path, marks=marks, mark_files=tuple(mark_files),
                prior_eo=prior, cameras=_cameras(found["cameras"], base, where))


def _switch(element: ET.Element, fields: dict[str, tuple], values: tuple[str, ...],
            where: str) -> list[tuple[tuple, str]]:
    """A set_bundle_estimate_params/set_initial_values sub-block: its text alone (for "all")
    or one element per field; -> [(what the field covers, value)] in document order."""
    children = _children(element, tuple(fields), where)
    pairs = [(fields["all"], _text(element))] if not children else [
        (fields[c.tag], _text(c)) for c in children]
    for _, value in pairs:
        if values and value not in values:
            raise ValueError(f"{where}: <{element.tag}>: expected one of {', '.join(values)}, "
                             f"got {value!r}")
    return pairs


def _estimate(element, names: tuple[str, ...], groups: dict[str, tuple], current, where):
    result = list(current)
    fields = {"all": tuple(range(len(names))), **groups}
    for cover, value in _switch(element, fields, ("true", "false", "default"), where):
        for k in cover:
            result[k] = value
    return tuple(result)


def _read_operations(block: ET.Element | None, images: dict[str, str], where: str
                     ) -> DbatOperations:
    ops = DbatOperations()
    if block is None:
        return ops
    io_map = {"all": ("xp", "yp", "c", "K1", "K2", "K3", "P1", "P2", "aspect", "skew"),
              "cc": ("c",), "pp": ("xp", "yp"), "px": ("xp",), "py": ("yp",),
              "K": ("K1", "K2", "K3"), "P": ("P1", "P2"), "aspect": ("aspect",),
              "skew": ("skew",), **{f"K{k}": (f"K{k}",) for k in (1, 2, 3)},
              **{f"P{k}": (f"P{k}",) for k in (1, 2)}}
    for operation in _children(block, ("operation",), where):
        at = f"{where}: <operation>"
        children = _children(operation, ("set_initial_values", "set_bundle_estimate_params",
                                         "set_datum"), at)
        if not children:
            name = _text(operation).rstrip(">")
            if name == "check_ray_count":
                rays = _attributes(operation, ("min_rays",), at).get("min_rays", "2")
                ops = dataclasses.replace(ops, min_rays=int(rays))
            elif name not in MARKER_OPERATIONS:
                raise ValueError(f"{at}: unsupported operation {name!r}")
            continue
        if len(children) > 1:
            raise ValueError(f"{at}: one operation per <operation>, got {len(children)}")
        (element,) = children
        at = f"{where}: <{element.tag}>"
        if element.tag == "set_initial_values":
            io_initial = dict(ops.io_initial)
            for part in _children(element, ("io", "eo", "op"), at):
                if part.tag == "io":
                    fields = {"all": IO_FIELDS, **{f: (f,) for f in IO_FIELDS}}
                    for cover, value in _switch(part, fields, (), at):
                        io_initial.update(dict.fromkeys(cover, value))
                else:  # eo, op: only "loaded" (DBAT's only choice)
                    _switch(part, {"all": ()}, ("loaded",), at)
            ops = dataclasses.replace(ops, io_initial=io_initial)
        elif element.tag == "set_bundle_estimate_params":
            for part in _children(element, ("io", "eo", "op"), at):
                if part.tag == "io":
                    free = dict(ops.io_free)
                    for cover, value in _switch(part, io_map, ("true", "false"), at):
                        free.update(dict.fromkeys(cover, value == "true"))
                    ops = dataclasses.replace(ops, io_free=free)
                elif part.tag == "eo":
                    groups = {"pos": (0, 1, 2), "angles": (3, 4, 5), "x": (0,), "y": (1,),
                              "z": (2,)}
                    ops = dataclasses.replace(ops, eo_estimate=_estimate(
                        part, EO_NAMES, groups, ops.eo_estimate, at))
                else:
                    groups = {"x": (0,), "y": (1,), "z": (2,)}
                    ops = dataclasses.replace(ops, op_estimate=_estimate(
                        part, ("x", "y", "z"), groups, ops.op_estimate, at))
        else:  # set_datum
            attributes = _attributes(element, ("ref_cam", "ref_base"), at)
            if _text(element) != "depend":
                raise ValueError(f"{at}: only depend is supported, got {_text(element)!r}")
            if attributes.get("ref_base", "longest") != "longest":
                raise ValueError(f"{at}: ref_base {attributes['ref_base']!r} is not supported"
                                 " (jaxba fixes the largest coordinate of the longest base:"
                                 ' ref_base="longest")')
            ref = str(int(attributes.get("ref_cam", "1")))
            if ref not in images:
                raise ValueError(f"{at}: ref_cam {ref}: no such image")
            ops = dataclasses.replace(ops, datum_image=ref)
    return ops


def read_script(path: str | os.PathLike) -> DbatScript:
    """Read a DBAT XML script and every file its input names (module docstring)."""
    path = pathlib.Path(path)
    root = read_xml(path, "DBAT script")
    if root.tag != "document":
        raise ValueError(f"{path}: expected a DBAT <document>, got <{root.tag}>")
    found = {c.tag: c for c in _children(root, ("meta", "input", "operations", "output"),
                                         path.name)}
    if "input" not in found:
        raise ValueError(f"{path}: no <input> block")
    data = _read_input(found["input"], path)
    operations = _read_operations(found.get("operations"), data["images"], path.name)
    return DbatScript(path=path, operations=operations, **data)
