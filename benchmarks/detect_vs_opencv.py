"""Images per second: `jaxba detect`'s detection against a plain OpenCV loop.

OpenCV's stereo sample (26 grey 640 x 480 JPEGs of a 9 x 6 chessboard; tests/data), and
the same images scaled to `--scale` times their size (INTER_CUBIC, written as JPEG into a
temporary folder). The peer is the loop of OpenCV's calibration sample: `cv2.imread` grey,
`findChessboardCorners`, `cornerSubPix` (11 x 11); jaxba is `detect_images` (read and check
the file, the same two calls with its own window, the order of the board's points, a
thumbnail with the points drawn) in this process (`jobs=1`) and as `jaxba detect` runs it by
default (`jobs=None`: worker processes where they pay). CPU seconds include the workers'
(`RUSAGE_CHILDREN`); the variants alternate, `--repeats` times, and the best of each is shown.

    OPENBLAS_NUM_THREADS=1 python benchmarks/detect_vs_opencv.py [--scale 5] [--repeats 3]
"""

import argparse
import os
import pathlib
import resource
import tempfile
import time

import cv2

from jaxba._io._detect import detect_images, parse_board

ROOT = pathlib.Path(__file__).resolve().parents[1]
DATA = next((folder for folder in (ROOT / "tests" / "data" / "opencv_stereo",
                                   ROOT.parent / "shared" / "data" / "opencv_stereo",
                                   ROOT.parents[1] / "shared" / "data" / "opencv_stereo")
             if folder.is_dir()), ROOT / "tests" / "data" / "opencv_stereo")
BOARD = parse_board("chessboard:9x6:1")


def opencv_loop(paths):
    for path in paths:
        grey = cv2.imread(str(path), cv2.IMREAD_GRAYSCALE)
        found, corners = cv2.findChessboardCorners(grey, (9, 6))
        if found:
            cv2.cornerSubPix(grey, corners, (11, 11), (-1, -1), (3, 30, 0.01))


def cpu_seconds() -> float:
    own = resource.getrusage(resource.RUSAGE_SELF)
    children = resource.getrusage(resource.RUSAGE_CHILDREN)
    return own.ru_utime + own.ru_stime + children.ru_utime + children.ru_stime


def timed(run) -> tuple[float, float]:
    wall, cpu = time.perf_counter(), cpu_seconds()
    run()
    return time.perf_counter() - wall, cpu_seconds() - cpu


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--scale", type=float, default=5.0)
    parser.add_argument("--repeats", type=int, default=3)
    args = parser.parse_args()
    cv2.setNumThreads(1)
    small = sorted(DATA.glob("*.jpg"))
    with tempfile.TemporaryDirectory() as folder:
        large = []
        for path in small:
            image = cv2.imread(str(path), cv2.IMREAD_GRAYSCALE)
            large.append(pathlib.Path(folder) / path.name)
            cv2.imwrite(str(large[-1]), cv2.resize(image, None, fx=args.scale, fy=args.scale,
                                                   interpolation=cv2.INTER_CUBIC))
        size = cv2.imread(str(large[0]), cv2.IMREAD_GRAYSCALE).shape[::-1]
        variants = {
            "OpenCV loop": opencv_loop,
            "jaxba, jobs=1": lambda paths: detect_images(paths, BOARD, jobs=1),
            "jaxba, default": lambda paths: detect_images(paths, BOARD),
        }
        print(f"load average {os.getloadavg()[0]:.2f}, {os.cpu_count()} CPUs")
        print("| images | variant | wall s | CPU s | ms CPU per image | CPU / OpenCV |")
        print("|---|---|---|---|---|---|")
        for label, paths in (("26 x 640x480", small), (f"26 x {size[0]}x{size[1]}", large)):
            best = {name: (float("inf"), float("inf")) for name in variants}
            for _ in range(args.repeats):
                for name, run in variants.items():
                    wall, cpu = timed(lambda: run(paths))
                    best[name] = (min(best[name][0], wall), min(best[name][1], cpu))
            for name, (wall, cpu) in best.items():
                print(f"| {label} | {name} | {wall:.2f} | {cpu:.2f} |"
                      f" {1e3 * cpu / len(paths):.1f} | {cpu / best['OpenCV loop'][1]:.2f} |")


if __name__ == "__main__":
    main()
