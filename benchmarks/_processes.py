"""The environment of the processes a benchmark times: the caller's, with one BLAS thread and
Python's bytecode caches kept, as for an installed package (PYTHONDONTWRITEBYTECODE dropped:
with it, every process compiles jaxba's ~160 modules from source, ~0.18 s on 2 cores)."""

import os


def process_environment(base: dict | None = None, **extra: str) -> dict[str, str]:
    """`base` (default: this process's environment) with OPENBLAS_NUM_THREADS=1 and `extra`,
    without PYTHONDONTWRITEBYTECODE."""
    environment = dict(os.environ if base is None else base, OPENBLAS_NUM_THREADS="1", **extra)
    environment.pop("PYTHONDONTWRITEBYTECODE", None)
    return environment
