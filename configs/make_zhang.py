"""Regenerate the bundled example project `configs/zhang/` from `tests/data/zhang/`.

Zhang's planar calibration data (5 images of a 256-corner target, 640 x 480 pixels) as a
project with one "opencv" camera: rounded starting intrinsics, starting EOPs from Zhang's
closed form, target points fixed. Run from anywhere: `python configs/make_zhang.py`.
"""

import pathlib
import sys

HERE = pathlib.Path(__file__).resolve().parent
sys.path.insert(0, str(HERE.parent))  # a checkout works without installing jaxba

from jaxba import write_zhang_project  # noqa: E402


def main():
    written = write_zhang_project(HERE.parent / "tests" / "data" / "zhang", HERE / "zhang")
    print(f"wrote {written.project_file.relative_to(HERE.parent)}")
    print("  closed form (no distortion): "
          + ", ".join(f"{k}={v:.3f}" for k, v in written.closed_form.items()))
    for image_id, eop in written.images.items():
        print(f"  {image_id}: X0 {eop[0]:8.3f} {eop[1]:8.3f} {eop[2]:8.3f} inch, "
              f"opk {eop[3]:9.3f} {eop[4]:8.3f} {eop[5]:8.3f} deg")


if __name__ == "__main__":
    main()
