"""Detect the board in many images, in parallel worker processes where that pays.

The workers are started fresh ("spawn"), not forked: a fork of a process that runs jax's
threads may deadlock. Starting one costs about half a second of CPU (Python, OpenCV), more
than detecting a small image takes (OpenCV's 640 x 480 sample: 10-20 ms): unless told how
many, the images are detected here until `PROBE_S` seconds have passed, and the rest go to one
process per CPU only where they would take longer than `PROCESS_START_S` per process. Each
worker runs OpenCV on one thread; results come back in input order.
"""

import concurrent.futures
import multiprocessing
import os
import pathlib
import time
from collections.abc import Callable, Sequence

import numpy as np

from ._board import Board
from ._image import ImageDetection, detect_image

PROBE_S = 0.5  # seconds of detection in this process before deciding on workers
PROCESS_START_S = 1.0  # seconds a worker must save to be worth starting


def detect_images(
    paths: Sequence[pathlib.Path], board: Board, *, jobs: int | None = None,
    advance: Callable[[], None] | None = None,
) -> list[ImageDetection]:
    """`detect_image` of every path, in input order: in `jobs` processes (1: in this one;
    None: decided on the time the first images take, module docstring).

    `advance()` is called once per image as it is done. A worker that fails (a crash in a
    decoder) gives its image the reason "detection failed: ..."; the others go on.
    """
    advance = advance or (lambda: None)
    results: list[ImageDetection] = []
    start = time.perf_counter()
    while len(results) < len(paths) and (
            jobs == 1 or (jobs is None and time.perf_counter() - start < PROBE_S)):
        results.append(detect_image(paths[len(results)], board))
        advance()
    rest = paths[len(results):]
    if jobs is None and rest:
        per_image = (time.perf_counter() - start) / len(results)
        cpus = min(os.cpu_count() or 1, len(rest))
        jobs = cpus if per_image * len(rest) / cpus > PROCESS_START_S else 1
    if jobs == 1:
        for path in rest:
            results.append(detect_image(path, board))
            advance()
        return results
    return results + _in_processes(rest, board, min(jobs, len(rest)), advance) if rest else results


def _in_processes(paths: Sequence[pathlib.Path], board: Board, jobs: int,
                  advance: Callable[[], None]) -> list[ImageDetection]:
    results: list[ImageDetection | None] = [None] * len(paths)
    context = multiprocessing.get_context("spawn")
    pool = concurrent.futures.ProcessPoolExecutor(jobs, mp_context=context)
    try:
        futures = {pool.submit(detect_image, path, board): k for k, path in enumerate(paths)}
        for future in concurrent.futures.as_completed(futures):
            k = futures[future]
            try:
                results[k] = future.result()
            except Exception as error:  # the worker died or raised: this image only
                results[k] = ImageDetection(paths[k], None, np.zeros(0, dtype=np.int64),
                                            np.zeros((0, 2)),
                                            f"detection failed: {type(error).__name__}: {error}")
            advance()
    except BaseException:  # Ctrl-C: the images not started yet are not detected
        pool.shutdown(wait=False, cancel_futures=True)
        raise
    pool.shutdown()
    return results
