"""DBAT cameras (`<camera>` blocks of a script or of a DBAT camera file) for jaxba.

Conventions (docs/dbat.md): DBAT's pixel coordinates have their origin at the top-left
*corner* of the image; jaxba's at the centre of the top-left pixel. DBAT's principal point
is in mm from that corner, y down; jaxba's from the sensor centre, y up:

    xp_dbat = xp + (W/2) ps_x,   yp_dbat = (H/2) ps_y - yp.

A `<pp>` with a negative y is in DBAT's internal frame (y up from the corner, as hand-written
camera files have it) and is read as -y. Plain Python.
"""

import dataclasses
import os
import pathlib
import xml.etree.ElementTree as ET

CAMERA_ELEMENTS = ("id", "name", "unit", "sensor", "image", "aspect", "focal", "model", "nK",
                   "nP", "cc", "pp", "skew", "K", "P", "calibrated", "calibration_info", "c")


@dataclasses.dataclass(frozen=True)
class DbatCamera:
    """A DBAT camera: sensor size (mm; width None for DBAT's "auto": square pixels of height /
    rows), image size (W, H) pixels, focal length (mm), lens model, nK and nP, and the loaded
    values where the file gives them (cc, pp in DBAT's frame, aspect, skew, K, P)."""

    id: str
    name: str
    sensor_height: float
    image_size: tuple[int, int]
    focal: float
    lens_model: int
    n_k: int
    n_p: int
    sensor_width: float | None = None
    aspect: float = 1.0
    cc: float | None = None
    pp: tuple[float, float] | None = None
    skew: float = 0.0
    k: tuple[float, ...] = ()
    p: tuple[float, ...] = ()

    @property
    def pixel_size(self) -> tuple[float, float]:
        """(ps_x, ps_y) mm per pixel."""
        ps_y = self.sensor_height / self.image_size[1]
        ps_x = ps_y if self.sensor_width is None else self.sensor_width / self.image_size[0]
        return ps_x, ps_y

    def principal_point_to_dbat(self, xp: float, yp: float) -> tuple[float, float]:
        """jaxba (xp, yp) (sensor centre, y up) -> DBAT's (top-left image corner, y down), mm."""
        (width, height), (ps_x, ps_y) = self.image_size, self.pixel_size
        return xp + width / 2 * ps_x, height / 2 * ps_y - yp

    def principal_point_from_dbat(self, xp: float, yp: float) -> tuple[float, float]:
        """DBAT's (xp, yp) (top-left image corner, y down) -> jaxba's (sensor centre, y up), mm."""
        (width, height), (ps_x, ps_y) = self.image_size, self.pixel_size
        return xp - width / 2 * ps_x, height / 2 * ps_y - yp


def _numbers(text: str, count: int | None, where: str) -> list[float]:
    try:
        values = [float(v) for v in text.split(",")] if text.strip() else []
    except ValueError:
        raise ValueError(f"{where}: expected comma-separated numbers, got {text!r}") from None
    if count is not None and len(values) != count:
        raise ValueError(f"{where}: expected {count} numbers, got {text!r}")
    return values


def _scalar(text: str, where: str) -> float:
    """The first number of `text`, as DBAT's sscanf("%f") reads a scalar (`0,0` is 0)."""
    return _numbers(text.split(",")[0], 1, where)[0]


def parse_camera(element: ET.Element, where: str, number: int) -> DbatCamera:
    """One `<camera>` element; `where` names the file for messages, `number` (1, 2, ...) is
    the ID of a camera without `<id>`."""
    texts = {}
    for child in element:
        if child.tag not in CAMERA_ELEMENTS:
            raise ValueError(f"{where}: <camera>: unsupported element <{child.tag}>")
        texts[child.tag] = (child.text or "").strip()

    def text(tag: str) -> str:
        if not texts.get(tag):
            raise ValueError(f"{where}: <camera>: missing <{tag}>")
        return texts[tag]

    at = f"{where}: <camera>"
    if text("unit") != "mm":
        raise ValueError(f"{at} <unit>: only mm is supported, got {texts['unit']!r}")
    sensor = [s.strip() for s in text("sensor").split(",")]
    if len(sensor) != 2:
        raise ValueError(f"{at} <sensor>: expected WIDTH,HEIGHT or auto,HEIGHT, got "
                         f"{texts['sensor']!r}")
    width = None if sensor[0] == "auto" else _numbers(sensor[0], 1, f"{at} <sensor>")[0]
    height = _numbers(sensor[1], 1, f"{at} <sensor>")[0]
    columns, rows = (int(v) for v in _numbers(text("image"), 2, f"{at} <image>"))
    if texts.get("aspect") == "auto":
        raise ValueError(f"{at} <aspect>: auto is not supported; give the aspect (1: square)")
    k = tuple(_numbers(texts.get("K", ""), None, f"{at} <K>"))
    p = tuple(_numbers(texts.get("P", ""), None, f"{at} <P>"))
    n_k = int(_numbers(texts["nK"], 1, f"{at} <nK>")[0]) if "nK" in texts else len(k)
    n_p = int(_numbers(texts["nP"], 1, f"{at} <nP>")[0]) if "nP" in texts else len(p)
    if (k and len(k) != n_k) or (p and len(p) != n_p):
        raise ValueError(f"{at}: <K> or <P> does not have <nK> = {n_k}, <nP> = {n_p} values")
    focal = _numbers(text("focal"), 1, f"{at} <focal>")[0]
    cc = texts.get("cc")
    cc = focal if cc == "focal" else (_scalar(cc, f"{at} <cc>") if cc else None)
    pp = texts.get("pp")
    if pp == "default" or not pp:
        pp = None
    else:
        x, y = _numbers(pp, 2, f"{at} <pp>")
        pp = (x, abs(y))  # a negative y: DBAT's internal frame, y up (module docstring)
    camera = DbatCamera(
        id=str(int(_numbers(texts["id"], 1, f"{at} <id>")[0])) if texts.get("id") else str(number),
        name=texts.get("name", ""),
        sensor_height=height,
        image_size=(columns, rows),
        focal=focal,
        lens_model=int(_numbers(text("model"), 1, f"{at} <model>")[0]),
        n_k=n_k,
        n_p=n_p,
        sensor_width=width,
        aspect=_scalar(texts["aspect"], f"{at} <aspect>") if texts.get("aspect") else 1.0,
        cc=cc,
        pp=pp,
        skew=_scalar(texts["skew"], f"{at} <skew>") if texts.get("skew") else 0.0,
        k=k,
        p=p,
    )
    if texts.get("pp") == "default":  # DBAT's: the sensor centre
        camera = dataclasses.replace(camera, pp=camera.principal_point_to_dbat(0.0, 0.0))
    if camera.lens_model != 3:
        raise ValueError(f"{at} <model>: only DBAT's lens model 3 (PhotoModeler's, jaxba's "
                         f'"photomodeler") is supported, got {camera.lens_model}')
    if not (0 <= n_k <= 3 and 0 <= n_p <= 2):
        raise ValueError(f"{at}: nK <= 3 and nP <= 2 are supported, got {n_k} and {n_p}")
    return camera


def read_xml(path: pathlib.Path, what: str) -> ET.Element:
    """The root element of the XML file `path` (a DBAT `what`: "camera file", "DBAT
    script"); `ValueError` naming the file where it is missing or not valid XML."""
    if not path.is_file():
        raise ValueError(f"{path}: no such {what}")
    try:
        return ET.parse(path).getroot()
    except ET.ParseError as error:
        raise ValueError(f"{path}: not valid XML: {error}") from None


def read_cameras(path: str | os.PathLike) -> tuple[DbatCamera, ...]:
    """The <cameras><camera> blocks of a DBAT camera file or script."""
    path = pathlib.Path(path)
    root = read_xml(path, "camera file")
    elements = [e for block in root.iter("cameras") for e in block.findall("camera")]
    if not elements:
        raise ValueError(f"{path}: no <cameras><camera> block")
    return tuple(parse_camera(e, path.name, k) for k, e in enumerate(elements, start=1))
