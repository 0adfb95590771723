"""Regenerate the bundled example project `configs/dbat_camcal.toml` from `tests/data/dbat_camcal/`.

DBAT's camera-calibration demo (data/script/camcaldemo of niclasborlin/dbat): 21 images of the
PhotoModeler calibration sheet, 96 targets and 4 fixed control points at the sheet corners, one
"photomodeler" camera (DBAT's lens model 3) with xp yp c K1 K2 K3 P1 P2 aspect free. The tables
go to `configs/dbat_camcal/`. Run from anywhere: `python configs/make_dbat_camcal.py`
(`--weighted` uses DBAT's weighted control points, σ = 1 mm, instead).
"""

import pathlib
import sys

HERE = pathlib.Path(__file__).resolve().parent
sys.path.insert(0, str(HERE.parent))  # a checkout works without installing jaxba

from jaxba import write_dbat_project  # noqa: E402


def main():
    weighted = "--weighted" in sys.argv[1:]
    written = write_dbat_project(
        HERE.parent / "tests" / "data" / "dbat_camcal" / "camcaldemo.xml",
        HERE / "dbat_camcal",
        project_file=HERE / "dbat_camcal.toml",
        control_file="reference/camcal-weighted.txt" if weighted else None,
    )
    n_control = len(written.control)
    print(f"wrote {written.project_file.relative_to(HERE.parent)} and configs/dbat_camcal/")
    print(f"  images: {len(written.images)}, points: {written.n_points} ({n_control} control), "
          f"image points: {written.n_image_points} ({2 * written.n_image_points} observations)")
    print(f"  camera: {written.camera.name}, pixel size {written.camera.pixel_size[0]:.8f} mm")
    for image_id, eop in written.images.items():
        print(f"  {image_id}: X0 {eop[0]:7.3f} {eop[1]:7.3f} {eop[2]:7.3f} m, "
              f"opk {eop[3]:9.3f} {eop[4]:8.3f} {eop[5]:9.3f} deg")


if __name__ == "__main__":
    main()
