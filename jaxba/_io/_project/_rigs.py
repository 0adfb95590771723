"""Rigs and frames of a project (docs/project-files.md, "Rigs"): rigs.toml, one table per
rig, and the frames table, `image_id frame_id`; validated against the cameras and images.
A camera's `[ID.mount]` on a GNSS/INS platform (lever arm and boresight) is read here too.

Plain Python: `_readers.py` loads the TOML document and the frames table (`TextTable`),
this module checks what they say. Angles stay in degrees, as in the files.
"""

from collections.abc import Iterable, Mapping
from typing import Any

from ..._project._errors import ProjectError
from ..._project._spec import MOUNT_NAMES, CameraSpec, ImageSpec, MountSpec, RigSpec
from ._toml import check_keys, check_not_weighted, prior_table, toml_float

FRAME_COLUMNS = ("image_id", "frame_id")
_RIG_KEYS = ("reference",)
_MOUNT_KEYS = (*MOUNT_NAMES, "free", "sigma")


def read_rigs(document: dict, file: str, cameras: Mapping[str, CameraSpec]
              ) -> dict[str, RigSpec]:
    """The rigs of a parsed rigs.toml (`file` names it in messages): every table a rig with a
    `reference` camera and a sub-table per other camera (`MountSpec`; `free` defaults to
    all six, values left out are None). A camera belongs to one rig at most."""
    rigs, owner = {}, {}
    for rig_id, table in document.items():
        where = f"{file}: [{rig_id}]"
        if not isinstance(table, dict):
            raise ProjectError(f"{where}: expected a table of the rig's cameras, got {table!r}")
        reference = table.get("reference")
        if not isinstance(reference, str):
            raise ProjectError(f"{where} reference: expected the reference camera's ID, got "
                               f"{reference!r}")
        mounts = {}
        for key, value in table.items():
            if key in _RIG_KEYS:
                continue
            if not isinstance(value, dict):
                raise ProjectError(f"{where}: unknown key {key!r}; a rig has `reference` and "
                                   "one table per other camera")
            if key == reference:
                raise ProjectError(f"{where}.{key}: the reference camera has no pose of its "
                                   "own in the rig (it is the rig frame)")
            mounts[key] = _read_mount(key, value, f"{file}: [{rig_id}.{key}]")
        for camera in (reference, *mounts):
            if camera not in cameras:
                raise ProjectError(f"{where}: unknown camera {camera!r} (known: "
                                   f"{', '.join(cameras) or 'none'})")
            if camera in owner:
                raise ProjectError(f"{where}: camera {camera!r} is already in rig "
                                   f"{owner[camera]!r}; a camera belongs to one rig")
            owner[camera] = rig_id
        rigs[rig_id] = RigSpec(rig_id, reference, mounts)
    return rigs


def _read_mount(camera: str, table: dict, where: str) -> MountSpec:
    check_keys(table, _MOUNT_KEYS, where)
    values = {name: None if name not in table else toml_float(table[name], f"{where} {name}")
              for name in MOUNT_NAMES}
    free = table.get("free", list(MOUNT_NAMES))
    if not isinstance(free, list) or not all(name in MOUNT_NAMES for name in free):
        raise ProjectError(f"{where} free: expected a list of {', '.join(MOUNT_NAMES)}, got "
                           f"{free!r}")
    sigma_table = prior_table(table.get("sigma", {}), f"{where} sigma")
    sigma = {}
    for name, value in sigma_table.items():
        if name not in MOUNT_NAMES:
            raise ProjectError(f"{where[:-1]}.sigma]: unknown key {name!r}; allowed keys: "
                               f"{', '.join(MOUNT_NAMES)}")
        sigma[name] = toml_float(value, f"{where[:-1]}.sigma] {name}", positive=True)
        if "free" in table:
            check_not_weighted(name, free, f"{where[:-1]}.sigma]")
    return MountSpec(camera, values, frozenset(free) - set(sigma), sigma)


_PLATFORM_KEYS = ("lever_arm", "boresight", "free", "sigma")
_PLATFORM_PARTS = {"lever_arm": MOUNT_NAMES[:3], "boresight": MOUNT_NAMES[3:]}


def read_platform_mount(camera: str, table: Any, where: str) -> MountSpec:
    """`[ID.mount]` of cameras.toml: `lever_arm = [dx, dy, dz]` (the perspective centre in
    the body frame, object units) and `boresight = [domega, dphi, dkappa]` (degrees, body ->
    camera), each 0 where left out; `free` lists "lever_arm" and/or "boresight" (default:
    neither, both known), `[ID.mount.sigma]` gives a σ (one number, or three) to weight
    either instead."""
    if not isinstance(table, dict):
        raise ProjectError(f"{where}: expected a table [.mount], got {table!r}")
    for key in table:
        if key not in _PLATFORM_KEYS:
            raise ProjectError(f"{where}: unknown key {key!r}; allowed keys: "
                               f"{', '.join(_PLATFORM_KEYS)}")
    values = {}
    for part, names in _PLATFORM_PARTS.items():
        given = table.get(part, [0.0, 0.0, 0.0])
        if not isinstance(given, list) or len(given) != 3:
            raise ProjectError(f"{where} {part}: expected a list of three numbers, got {given!r}")
        values.update({n: toml_float(v, f"{where} {part}") for n, v in zip(names, given)})
    free = table.get("free", [])
    if not isinstance(free, list) or not all(part in _PLATFORM_PARTS for part in free):
        raise ProjectError(f"{where} free: expected a list of lever_arm, boresight, got {free!r}")
    sigma_table = table.get("sigma", {})
    if not isinstance(sigma_table, dict) or not set(sigma_table) <= set(_PLATFORM_PARTS):
        raise ProjectError(f"{where} sigma: expected a table of lever_arm and/or boresight σ, "
                           f"got {sigma_table!r}")
    sigma = {}
    for part, given in sigma_table.items():
        if part in free:
            raise ProjectError(f"{where} sigma {part}: {part!r} is also in free; it is either "
                               "free or weighted, not both")
        given = given if isinstance(given, list) else [given] * 3
        if len(given) != 3:
            raise ProjectError(f"{where} sigma {part}: expected one σ or three, got {given!r}")
        sigma.update({n: toml_float(v, f"{where} sigma {part}", positive=True)
                      for n, v in zip(_PLATFORM_PARTS[part], given)})
    return MountSpec(camera, values, frozenset(n for part in free
                                               for n in _PLATFORM_PARTS[part]), sigma)


def read_frames(rows: Iterable, images: Mapping[str, ImageSpec],
                rigs: Mapping[str, RigSpec]) -> dict[str, str]:
    """image ID -> frame ID from the frames table's rows (`_text_table.Row`: `tokens`
    (image_id, frame_id), `error`). Every image is known and listed once; the images of one
    frame are taken with different cameras of one rig."""
    rig_of = {camera: rig.id for rig in rigs.values() for camera in rig.cameras}
    frames, members, first = {}, {}, {}
    for row in rows:
        image_id, frame_id = row.tokens
        if image_id not in images:
            raise row.error(f"unknown image {image_id!r}", 0)
        if image_id in frames:
            raise row.error(f"image {image_id!r} is already in frame {frames[image_id]!r}", 0)
        camera = images[image_id].camera
        if camera not in rig_of:
            raise row.error(f"image {image_id!r} was taken with camera {camera!r}, which is "
                            "in no rig (rigs.toml)", 0)
        taken = members.setdefault(frame_id, {})
        if camera in taken:
            raise row.error(f"frame {frame_id!r} already has an image of camera {camera!r} "
                            f"({taken[camera]!r})", 1)
        rig = rig_of[camera]
        if first.setdefault(frame_id, rig) != rig:
            raise row.error(f"frame {frame_id!r} holds images of rigs {first[frame_id]!r} and "
                            f"{rig!r}: one frame is one rig's", 1)
        taken[camera] = image_id
        frames[image_id] = frame_id
    clash = set(frames.values()) & (set(images) - set(frames))
    if clash:
        raise ProjectError(f"frame ID {sorted(clash)[0]!r} is also the ID of an image in no "
                           "frame (a frame of its own): name the frame otherwise")
    return frames
