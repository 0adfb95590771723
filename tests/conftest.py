"""Test configuration: float64 everywhere (the library never flips it at import), and one
OpenBLAS thread: OpenBLAS and XLA threads oversubscribe the cores (3x slower suite)."""

import os

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")  # before numpy is loaded

import jax  # noqa: E402

jax.config.update("jax_enable_x64", True)
