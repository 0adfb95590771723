"""How a jaxba process sets jax up: the command line at start-up, and every Dask worker
before its first task (`jaxba._dask`). Never called at import: the library leaves global
configuration to its caller."""

import os
import pathlib

CACHE_DIR = pathlib.Path("~/.cache/jaxba/jax")


def setup_jax() -> None:
    """float64 (never set by the library at import), one BLAS thread, a persistent
    compilation cache and a C heap that gives freed memory back (`jaxba._memory`).

    OpenBLAS threads and XLA's own threads oversubscribe small machines (the dense QR of
    the LM step ran 3x slower), so BLAS is limited to one thread for the run. The cache is
    `~/.cache/jaxba/jax`, or jax's own `JAX_COMPILATION_CACHE_DIR` where that is set; best
    effort: if its folder cannot be made or written, jax runs without it.
    """
    import jax
    import threadpoolctl

    from ._memory import tune_allocator

    tune_allocator()  # freed compiler and buffer memory back to the system, not kept
    threadpoolctl.threadpool_limits(1, user_api="blas")
    jax.config.update("jax_enable_x64", True)
    try:
        cache = pathlib.Path(os.environ.get("JAX_COMPILATION_CACHE_DIR") or CACHE_DIR)
        cache = cache.expanduser()
        cache.mkdir(parents=True, exist_ok=True)
        if not os.access(cache, os.W_OK):
            return
        jax.config.update("jax_compilation_cache_dir", str(cache))
        # Every program, however small: loading one is several times faster than compiling
        # it, even for the few small eager operations of a run.
        jax.config.update("jax_persistent_cache_min_compile_time_secs", 0.0)
        jax.config.update("jax_persistent_cache_min_entry_size_bytes", 0)
    except (OSError, RuntimeError, ValueError):
        pass
