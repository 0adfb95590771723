"""The text tables of a project (docs/project-files.md): images, points, image points and
distances, each read by one reader into the records of `jaxba._project._spec`, with the
checks that span them.

Values are not converted: angles stay in decimal degrees and image coordinates (and their σ)
in the project's `image_units`. A σ is `None` (free / no observation), `0.0` (fixed) or a
positive number (weighted); image points have no fixed state: their σ pair is `None` (use the
project's `image_sigma`) or two positive numbers.

Missing approximations are read as such (`ProjectSpec`): `-` in all six EOP columns of an image
(`ImageSpec.eop` None; its σ columns must then be `-`), and a point measured in the image
points but absent from the points table (a tie point, `PointSpec.xyz` None, appended to the
points in the order of first measurement).
"""

import collections
from collections.abc import Mapping

import numpy as np

from ..._project._errors import ProjectError
from ..._project._spec import (
    CameraSpec,
    DistanceSpec,
    ImagePointTable,
    ImageSpec,
    InputFile,
    PointSpec,
)
from ._content import once
from ._text_table import TextTable
from ._toml import read_bytes

IMAGE_COLUMNS = (
    *("image_id", "camera_id", "X0", "Y0", "Z0", "omega", "phi", "kappa"),
    *("sX0", "sY0", "sZ0", "somega", "sphi", "skappa"),
)
POINT_COLUMNS = ("point_id", "X", "Y", "Z", "sX", "sY", "sZ")
IMAGE_POINT_COLUMNS = ("image_id", "point_id", "x", "y", "sx", "sy")
DISTANCE_COLUMNS = ("point_a", "point_b", "distance", "sigma")
_EOP = range(2, 8)  # the columns X0 .. kappa of IMAGE_COLUMNS; their σ follow


def read_images(
    file: InputFile, cameras: Mapping[str, CameraSpec], cameras_file: str
) -> dict[str, ImageSpec]:
    """images: `image_id camera_id X0 Y0 Z0 omega phi kappa [sX0 sY0 sZ0 somega sphi skappa]`;
    `-` in all six EOP columns (or none) for an image without approximation, whose σ
    columns must then be `-` too (a text read before with the same cameras: its images
    again, `once`)."""
    data = read_bytes(file.path, file.name)
    return dict(once(("images", data, file.name, tuple(cameras), cameras_file), data,
                     lambda: _read_images(TextTable(file, IMAGE_COLUMNS, 8, data), cameras,
                                          cameras_file)))


def _read_images(table: TextTable, cameras: Mapping[str, CameraSpec], cameras_file: str
                 ) -> dict[str, ImageSpec]:
    """`read_images` of its table."""
    table.known(1, cameras, lambda camera_id: (
        f"unknown camera {camera_id!r} (not in {cameras_file}; "
        f"known: {', '.join(cameras) or 'none'})"))
    sigma = table.sigmas(tuple(k + 6 for k in _EOP))
    missing = np.array([[token == "-" for token in table.column(k)] for k in _EOP],
                       dtype=bool).reshape(6, -1).T
    given, none = ~missing.any(axis=1), missing.all(axis=1)
    mixed = ~given & ~none
    eop = table.numbers(tuple(_EOP), where=given)
    odd = np.argmax(missing != missing[:, :1], axis=1)  # the first column off X0's pattern
    for k in range(6):
        table.fail(mixed & (odd == k), lambda r: (
            "'-' (no approximation) must stand in all six EOP columns X0 .. kappa or in none;"
            " give the six values, or '-' in all six to have them computed"), 2 + k)
    for k in range(6):
        table.fail(none & ~np.isnan(sigma[:, k]), lambda r: (
            f"the EOPs are '-' (no approximation), but this column makes "
            f"{IMAGE_COLUMNS[2 + k]} {'fixed' if sigma[r, k] == 0 else 'weighted'}: a fixed or"
            " weighted EOP needs its value"), 8 + k)
    ids = table.column(0)
    table.unique((0,), lambda image_id: f"image {image_id!r}")
    table.check()
    if not len(table):
        raise ProjectError(f"{table.name}: no images")
    return {
        image_id: ImageSpec(image_id, camera_id, tuple(eop_k) if given_k else None,
                            sigma_k, line)
        for image_id, camera_id, eop_k, given_k, sigma_k, line in zip(
            ids, table.column(1), eop.tolist(), given.tolist(), _optional(sigma),
            table.lines.tolist())
    }


def read_points(file: InputFile) -> dict[str, PointSpec]:
    """points: `point_id X Y Z [sX sY sZ]`; without σ columns the point is a tie point (a
    text read before: its points again, `once`)."""
    data = read_bytes(file.path, file.name)
    return dict(once(("points", data, file.name), data,
                     lambda: _read_points(TextTable(file, POINT_COLUMNS, 4, data))))


def _read_points(table: TextTable) -> dict[str, PointSpec]:
    """`read_points` of its table."""
    xyz = table.numbers((1, 2, 3))
    sigma = table.sigmas((4, 5, 6))
    ids = table.column(0)
    table.unique((0,), lambda point_id: f"point {point_id!r}")
    table.check()
    return dict(zip(ids, map(PointSpec, ids, map(tuple, xyz.tolist()), _optional(sigma),
                             table.lines.tolist())))


def read_image_points(
    file: InputFile, images: Mapping[str, ImageSpec], images_file: str
) -> ImagePointTable:
    """image points: `image_id point_id x y [sx sy]`, σ both given (> 0) or both `-`/absent.
    A point need not be in the points table (`missing_points`)."""
    table = TextTable(file, IMAGE_POINT_COLUMNS, 4)
    xy = table.numbers((2, 3))
    sigma = table.sigmas((4, 5), fixed=False)
    none = np.isnan(sigma)
    for k in (0, 1):
        table.fail(none[:, k] & ~none[:, 1 - k], lambda r: "give both sx and sy, or '-' for both",
                   4 + k)
    table.known(0, images, lambda image_id: f"unknown image {image_id!r} (not in {images_file})")
    table.unique((0, 1), lambda key: f"measurement of point {key[1]!r} in image {key[0]!r}")
    table.check()
    return ImagePointTable(list(table.column(0)), list(table.column(1)), xy, sigma, table.lines)


def read_distances(
    file: InputFile, points: Mapping[str, PointSpec], points_file: str
) -> list[DistanceSpec]:
    """distances: `point_a point_b distance sigma`, both > 0, two different known points."""
    table = TextTable(file, DISTANCE_COLUMNS, 4)
    distance, sigma = table.numbers((2, 3), positive=True).T
    for k in (0, 1):
        table.known(k, points, lambda point_id: f"unknown point {point_id!r} (not in "
                    f"{points_file})")
    a, b = table.column(0), table.column(1)
    table.fail(np.array(a) == np.array(b), lambda r: (
        f"a distance needs two different points, got {a[r]!r} twice"), 1)
    table.check()
    return list(map(DistanceSpec, a, b, distance.tolist(), sigma.tolist(),
                    table.lines.tolist()))


def missing_points(
    image_points: ImagePointTable, points: Mapping[str, PointSpec]
) -> dict[str, PointSpec]:
    """The measured points absent from the points table: tie points without approximation
    (`xyz` None, free), each at the line of its first measurement, in that order."""
    missing = set(image_points.point) - points.keys()
    first: dict[str, int] = {}
    if missing:
        for point_id, line in zip(image_points.point, image_points.line.tolist()):
            if point_id in missing and point_id not in first:
                first[point_id] = line
    return {point_id: PointSpec(point_id, None, (None, None, None), line)
            for point_id, line in first.items()}


def check_consistency(
    images: Mapping[str, ImageSpec],
    points: Mapping[str, PointSpec],
    image_points: ImagePointTable,
    distances: list[DistanceSpec],
    files: Mapping[str, InputFile],
) -> None:
    """Every image is measured; every used point with a free coordinate is in ≥ 2 images.

    A point used by nothing is allowed (and kept); so is a camera used by no image.
    """
    counts = collections.Counter(image_points.point)
    measured = set(image_points.image)
    for image in images.values():
        if image.id not in measured:
            raise ProjectError(
                f"{files['images'].name}:{image.line}: image {image.id!r} has no measurements "
                f"in {files['image_points'].name}"
            )

    first_distance: dict[str, DistanceSpec] = {}
    for distance in distances:
        first_distance.setdefault(distance.a, distance)
        first_distance.setdefault(distance.b, distance)
    for point in points.values():
        seen = counts.get(point.id, 0)
        if seen >= 2 or None not in point.sigma:
            continue
        where = f"{files['points'].name}:{point.line}"
        if seen:
            image = image_points.image[image_points.point.index(point.id)]
            if point.xyz is None:
                raise ProjectError(
                    f"{files['image_points'].name}:{point.line}: point {point.id!r} is "
                    f"measured in only 1 image ({image}) and is not in "
                    f"{files['points'].name}: a tie point needs 2 images or more"
                )
            raise ProjectError(
                f"{where}: point {point.id!r} is measured in only 1 image ({image}) "
                "but has free coordinates"
            )
        if point.id in first_distance:
            raise ProjectError(
                f"{where}: point {point.id!r} is measured in no image but has free "
                f"coordinates; it is used by {files['distances'].name}:"
                f"{first_distance[point.id].line}"
            )


def _optional(sigma: np.ndarray) -> list[tuple[float | None, ...]]:
    """σ as read, (n, k) with NaN for `-`, as the specs hold them: a tuple per row, None for
    none given."""
    missing = np.isnan(sigma)
    if missing.any():
        sigma = sigma.astype(object)
        sigma[missing] = None
    return list(map(tuple, sigma.tolist()))
