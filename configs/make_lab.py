"""Regenerate the bundled example project `configs/lab/`.

A synthetic replica of the BASC self-calibration lab (`jaxba.write_synthetic_project`, seed
2018, defaults): 18 convergent and rolled images of an 80-target 3D field, datum of six fixed
coordinates of three targets, scale from four measured distances. Run from anywhere:
`python configs/make_lab.py`.
"""

import pathlib
import sys
import tomllib

HERE = pathlib.Path(__file__).resolve().parent
sys.path.insert(0, str(HERE.parent))  # a checkout works without installing jaxba

from jaxba import write_synthetic_project  # noqa: E402


def table_rows(path):
    """The data rows of a text table as lists of fields (comments and blank lines dropped)."""
    lines = (line.split("#", 1)[0].split() for line in path.read_text().splitlines())
    return [fields for fields in lines if fields]


def main():
    truth = write_synthetic_project(HERE / "lab", name="lab", seed=2018)
    directory = truth.project_file.parent
    n_observations = len(table_rows(directory / "image_coordinates.txt"))
    points = table_rows(directory / "ground_points.txt")
    n_fixed = sum(sigma == "0" for row in points for sigma in row[4:7])
    n_distances = len(table_rows(directory / "distances.txt"))
    cameras = tomllib.loads((directory / "cameras.toml").read_text())
    n_free_iops = sum(len(camera["free"]) for camera in cameras.values())
    # r = n - u: 2 per image point + distances, minus EOPs, free point coordinates, free IOPs.
    n = 2 * n_observations + n_distances
    u = 6 * len(truth.images) + 3 * len(points) - n_fixed + n_free_iops
    print(f"wrote {truth.project_file.relative_to(HERE.parent)}")
    print(f"  images: {len(truth.images)}, cameras: {len(truth.cameras)}, targets: {len(points)}")
    print(f"  image observations: {n_observations} points ({2 * n_observations} coordinates)")
    print(f"  distances: {n_distances}, fixed coordinates: {n_fixed}, free IOPs: {n_free_iops}")
    print(f"  redundancy estimate: n - u = {n} - {u} = {n - u}")
    for camera_id, iops in truth.cameras.items():
        print(f"  true {camera_id}: " + ", ".join(f"{k}={v:g}" for k, v in iops.items() if v))


if __name__ == "__main__":
    main()
