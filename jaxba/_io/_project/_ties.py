"""Ties between camera parameters in cameras.toml (docs/project-files.md): read, checked,
resolved to their first source, and per-image cameras expanded. Plain Python, no jax.

A tie makes a camera parameter its source's unknown: `ties = { fy = "fx" }` within a camera,
`ties = { K1 = "C1.K1" }` or `share = { camera = "C1", parameters = ["K1", "K2"] }` between
cameras, and `per_image = ["c", "xp", "yp"]` gives every image of a camera its own copy of
the camera ("C1@img01", ...) that shares all estimated parameters but the listed ones.
"""

import dataclasses
from collections.abc import Mapping

from ..._project._errors import ProjectError
from ..._project._spec import CameraSpec, ImageSpec

TIE_KEYS = ("ties", "share", "per_image")
PER_IMAGE_SEPARATOR = "@"
"""A per-image camera's ID: "<camera>@<image>"."""


def read_camera_ties(
    table: Mapping, camera_id: str, where: str
) -> tuple[dict[str, tuple[str, str]], tuple[str, ...]]:
    """The `ties`, `share` and `per_image` keys of one camera table (`where`: "file: [ID]"):
    parameter -> (source camera, source parameter) as written, and the per-image names.
    Only their form is checked here (`resolve_ties` checks the names)."""
    raw = table.get("ties", {})
    if not isinstance(raw, dict) or not all(isinstance(v, str) for v in raw.values()):
        raise ProjectError(f'{where} ties: expected a table of parameter = "source" (a '
                           f'parameter of this camera, or "CAMERA.parameter"), got {raw!r}')
    ties = {}
    for name, source in raw.items():
        camera, _, parameter = source.rpartition(".")
        ties[name] = (camera or camera_id, parameter)
    share = table.get("share")
    if share is not None:
        parameters = share.get("parameters") if isinstance(share, dict) else None
        if (not isinstance(share, dict) or set(share) != {"camera", "parameters"}
                or not isinstance(share["camera"], str) or not isinstance(parameters, list)
                or not all(isinstance(name, str) for name in parameters)):
            raise ProjectError(f'{where} share: expected {{ camera = "ID", parameters = '
                               f'["K1", ...] }}, got {share!r}')
        for name in parameters:
            if name in ties:
                raise ProjectError(f"{where} share: {name!r} is also in ties; tie it once")
            ties[name] = (share["camera"], name)
    per_image = table.get("per_image", [])
    if not isinstance(per_image, list) or not all(isinstance(n, str) for n in per_image):
        raise ProjectError(f"{where} per_image: expected a list of parameter names, "
                           f"got {per_image!r}")
    return ties, tuple(per_image)


def _text(camera: str, name: str) -> str:
    return f"{camera}.{name}"


def resolve_ties(cameras: dict[str, CameraSpec], document: Mapping, file: str
                 ) -> dict[str, CameraSpec]:
    """`cameras` with every tie checked and pointing at its chain's first source, and a tied
    parameter's value set to its source's. `ProjectError` naming the file, camera and
    parameter for: an unknown parameter or camera, a tie between cameras of two parameter
    names, a tied parameter also free or weighted (it takes its source's status) or given
    another value than its source's, a cycle, or a per-image parameter tied to a shared one."""
    for camera in cameras.values():
        _check_camera_ties(camera, cameras, file)

    def root(camera: str, name: str) -> tuple[str, str]:
        chain = [(camera, name)]
        while chain[-1][1] in cameras[chain[-1][0]].ties:
            chain.append(cameras[chain[-1][0]].ties[chain[-1][1]])
            if chain[-1] in chain[:-1]:
                cycle = " = ".join(_text(*link) for link in chain)
                raise ProjectError(f"{file}: the ties form a cycle: {cycle}")
        return chain[-1]

    out = {}
    for cid, camera in cameras.items():
        ties = {name: root(cid, name) for name in camera.ties}
        values = dict(camera.values)
        for name, (source, source_name) in ties.items():
            values[name] = cameras[source].values[source_name]
            given = document[cid].get(name)
            if given is not None and given != values[name]:
                raise ProjectError(
                    f"{file}: [{cid}] {name} = {given!r}: {name} is tied to "
                    f"{_text(source, source_name)} = {values[name]!r}; give the value once, "
                    "at the source")
        out[cid] = dataclasses.replace(camera, ties=ties, values=values)
    return out


def _check_camera_ties(camera: CameraSpec, cameras: Mapping[str, CameraSpec], file: str
                       ) -> None:
    """The checks of `resolve_ties` on one camera's own ties and per-image names."""
    where = f"{file}: [{camera.id}]"

    def parameter(of: CameraSpec, name: str, key: str) -> None:
        if name in of.constants:
            raise ProjectError(f"{where} {key}: {name!r} is a constant of camera {of.id} "
                               f"(model {of.model!r}), not an unknown")
        if name not in of.values:
            raise ProjectError(f"{where} {key}: unknown parameter {name!r} of camera {of.id} "
                               f"(model {of.model!r}); allowed: {', '.join(of.values)}")

    for name in camera.per_image:
        parameter(camera, name, "per_image")
        if name not in camera.free and name not in camera.sigma:
            raise ProjectError(f"{where} per_image: {name!r} is fixed; a per-image parameter "
                               "is estimated in every image: make it free or weighted")
    for name, (source, source_name) in camera.ties.items():
        key = f"ties {name}"
        parameter(camera, name, key)
        if source not in cameras:
            raise ProjectError(f"{where} {key}: unknown camera {source!r} in "
                               f"{_text(source, source_name)!r}; known: {', '.join(cameras)}")
        parameter(cameras[source], source_name, key)
        if (source, source_name) == (camera.id, name):
            raise ProjectError(f"{where} {key}: {name} is tied to itself")
        if source != camera.id and source_name != name:
            raise ProjectError(
                f"{where} {key}: a tie between cameras joins parameters of one name, got "
                f"{name} = {_text(source, source_name)} (within a camera, name the parameter "
                "alone)")
        status = "free" if name in camera.free else "[sigma]" if name in camera.sigma else None
        if status:
            raise ProjectError(
                f"{where} {key}: {name!r} is also {status}; a tied parameter is its source's "
                f"unknown and takes the status of {_text(source, source_name)}")
        if name in camera.per_image and (source != camera.id
                                         or source_name not in camera.per_image):
            raise ProjectError(f"{where} {key}: {name!r} is per_image, so it can be tied only "
                               "to another per_image parameter of this camera")
        if source != camera.id and source_name in cameras[source].per_image:
            raise ProjectError(f"{where} {key}: {_text(source, source_name)} is per_image, one "
                               f"per image of camera {source}: tie to a shared parameter")


def expand_per_image(
    cameras: dict[str, CameraSpec], images: dict[str, ImageSpec], file: str
) -> tuple[dict[str, CameraSpec], dict[str, ImageSpec]]:
    """Every camera with `per_image` names replaced by one camera per image using it
    ("<camera>@<image>", in image order): the first keeps the camera's ties, free and σ; the
    others tie every estimated or tied parameter but the per-image ones to the first's, and
    the images use their own copy. Ties to an expanded camera go to its first copy. Then
    every tie's source must be a camera some image uses (`ProjectError` otherwise)."""
    users: dict[str, list[str]] = {}
    for image in images.values():
        users.setdefault(image.camera, []).append(image.id)
    copies = {cid: [f"{cid}{PER_IMAGE_SEPARATOR}{iid}" for iid in users.get(cid, [])]
              for cid, camera in cameras.items() if camera.per_image and cid in users}

    def retarget(link: tuple[str, str], own: str, copy: str) -> tuple[str, str]:
        camera, name = link
        if camera == own:
            return copy, name
        return (copies[camera][0], name) if camera in copies else link

    out: dict[str, CameraSpec] = {}
    for cid, camera in cameras.items():
        if cid not in copies:
            ties = {n: retarget(link, cid, cid) for n, link in camera.ties.items()}
            out[cid] = dataclasses.replace(camera, ties=ties)
            continue
        first = copies[cid][0]
        first_ties = {n: retarget(link, cid, first) for n, link in camera.ties.items()}
        out[first] = dataclasses.replace(camera, id=first, ties=first_ties, per_image=())
        shared = [n for n in camera.values if n not in camera.per_image
                  and (n in camera.free or n in camera.sigma or n in camera.ties)]
        for copy in copies[cid][1:]:
            ties = {n: first_ties.get(n, (first, n)) for n in shared}
            ties |= {n: (copy, link[1]) for n, link in camera.ties.items()
                     if n in camera.per_image}
            out[copy] = dataclasses.replace(
                camera, id=copy, ties=ties, per_image=(),
                free=camera.free & frozenset(camera.per_image),
                sigma={n: s for n, s in camera.sigma.items() if n in camera.per_image})
    images = {iid: (dataclasses.replace(image, camera=copies[image.camera][
        users[image.camera].index(iid)]) if image.camera in copies else image)
        for iid, image in images.items()}
    used = {image.camera for image in images.values()}
    for camera in (out[cid] for cid in out if cid in used):
        for name, (source, source_name) in camera.ties.items():
            if source not in used:
                raise ProjectError(
                    f"{file}: [{camera.id}] ties {name}: camera {source} of "
                    f"{_text(source, source_name)} is used by no image, so its parameters are"
                    " not adjusted")
    return out, images
