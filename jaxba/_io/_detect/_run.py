"""Detect the board in many images, in parallel worker processes.

The workers are started fresh ("spawn"), not forked: a fork of a process that runs jax's
threads may deadlock. Each runs OpenCV on one thread; results come back in input order.
"""

import concurrent.futures
import multiprocessing
import pathlib
from collections.abc import Callable, Sequence

import numpy as np

from ._board import Board
from ._image import ImageDetection, detect_image


def detect_images(
    paths: Sequence[pathlib.Path], board: Board, *, jobs: int = 1,
    advance: Callable[[], None] | None = None,
) -> list[ImageDetection]:
    """`detect_image` of every path, in `jobs` processes (1: in this one), in input order.

    `advance()` is called once per image as it is done. A worker that fails (a crash in a
    decoder) gives its image the reason "detection failed: ..."; the others go on.
    """
    advance = advance or (lambda: None)
    if jobs <= 1 or len(paths) <= 1:
        results = []
        for path in paths:
            results.append(detect_image(path, board))
            advance()
        return results
    results: list[ImageDetection | None] = [None] * len(paths)
    context = multiprocessing.get_context("spawn")
    pool = concurrent.futures.ProcessPoolExecutor(min(jobs, len(paths)), mp_context=context)
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
