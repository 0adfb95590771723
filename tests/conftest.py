"""Test configuration: float64 everywhere (the library never flips it at import), one
OpenBLAS thread (OpenBLAS and XLA threads oversubscribe the cores: 3x slower suite),
compiled programs shared across the session through jax's persistent compilation cache, and
XLA's cheaper compilation.

Most of the suite's time is XLA compiling many small programs once each, not running them:
the tests compile with LLVM's optimisation level 0 and without its expensive passes
(`TEST_XLA_FLAGS`, appended to any XLA_FLAGS given; subprocesses inherit them). That took a
quarter off the CPU time of the compile-bound modules (test_schur_adjust: 46 -> 34 s of user
time). XLA's CPU fusion emitters are off as well (the older LLVM IR emitters): the dense
Levenberg-Marquardt of a 140-unknown calibration compiles in 1.0 s instead of 2.6 s, and the
whole suite's worker CPU fell from 630 to 508 s. Numbers are IEEE double either way (XLA does
not reassociate floating point unless asked to), though the rounding of a sum may differ where
the programs fuse it differently; the benchmarks keep XLA's defaults.

The cache lives in a temporary folder made for this run (or in $JAX_COMPILATION_CACHE_DIR
where that is set), so every run starts as a fresh clone does; each pytest-xdist worker has
its own folder in it. Programs are cached whatever
their compile time; the environment variables carry the cache to subprocesses (the notebook
kernels). Programs that contain a host callback are never cached (jax's rule).

After each test module, and after any test that leaves the process above 1 GiB, jax's
in-memory caches are cleared and the freed memory is handed back to the system: compiled
executables otherwise pile up (7 GB peak on the whole suite once; 2.2 GB per worker within
test_batch); a later test that needs one of them again loads it from the persistent cache
instead of compiling it.
"""

import gc
import os
import shutil
import tempfile

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")  # before numpy is loaded
TEST_XLA_FLAGS = ("--xla_backend_optimization_level=0 --xla_llvm_disable_expensive_passes=true"
                  " --xla_cpu_use_fusion_emitters=false")
if TEST_XLA_FLAGS not in os.environ.get("XLA_FLAGS", ""):  # before jax is loaded
    os.environ["XLA_FLAGS"] = f"{os.environ.get('XLA_FLAGS', '')} {TEST_XLA_FLAGS}".strip()

_CACHE_OWNED = "JAX_COMPILATION_CACHE_DIR" not in os.environ
if _CACHE_OWNED:
    os.environ["JAX_COMPILATION_CACHE_DIR"] = tempfile.mkdtemp(prefix="jaxba-tests-jit-")
if "PYTEST_XDIST_WORKER" in os.environ:
    # One cache per pytest-xdist worker, inside the run's: jax writes cache entries in place,
    # and a worker reading an entry another is writing got a truncated one.
    os.environ["JAX_COMPILATION_CACHE_DIR"] = os.path.join(
        os.environ["JAX_COMPILATION_CACHE_DIR"], os.environ["PYTEST_XDIST_WORKER"])
    os.makedirs(os.environ["JAX_COMPILATION_CACHE_DIR"], exist_ok=True)
os.environ.setdefault("JAX_PERSISTENT_CACHE_MIN_COMPILE_TIME_SECS", "0")
os.environ.setdefault("JAX_PERSISTENT_CACHE_MIN_ENTRY_SIZE_BYTES", "0")

import jax  # noqa: E402
import pytest  # noqa: E402

jax.config.update("jax_enable_x64", True)
jax.config.update("jax_compilation_cache_dir", os.environ["JAX_COMPILATION_CACHE_DIR"])
jax.config.update("jax_persistent_cache_min_compile_time_secs",
                  float(os.environ["JAX_PERSISTENT_CACHE_MIN_COMPILE_TIME_SECS"]))
jax.config.update("jax_persistent_cache_min_entry_size_bytes",
                  int(os.environ["JAX_PERSISTENT_CACHE_MIN_ENTRY_SIZE_BYTES"]))

from helpers import SYNTHETIC_BLOCK  # noqa: E402

import jaxba  # noqa: E402
from jaxba._memory import release_free_memory  # noqa: E402
from jaxba._programs import forget_loaded  # noqa: E402

# Above this resident size a test's compiled programs are dropped when it ends, not only at
# the end of its module: a module of large vmapped programs (test_batch) otherwise climbed
# to 2.2 GB, and two pytest-xdist workers together past 3.8 GB.
CLEAR_ABOVE_BYTES = 1 << 30


def _release_memory():
    jax.clear_caches()
    forget_loaded()  # the executables jaxba's stored programs hold
    gc.collect()
    release_free_memory()  # glibc keeps freed pages resident otherwise


def _resident_bytes() -> int:
    """This process's resident memory (Linux; 0 elsewhere, where only modules clear)."""
    try:
        with open("/proc/self/statm") as statm:
            return int(statm.read().split()[1]) * os.sysconf("SC_PAGE_SIZE")
    except OSError:
        return 0


@pytest.fixture(scope="module", autouse=True)
def _clear_jax_caches_after_module():
    yield
    _release_memory()


@pytest.fixture(autouse=True)
def _clear_jax_caches_when_large():
    yield
    if _resident_bytes() > CLEAR_ABOVE_BYTES:
        _release_memory()


@pytest.fixture(scope="session")
def synthetic_block(tmp_path_factory):
    """(truth, project, result): `SYNTHETIC_BLOCK` written, read and adjusted once per session.

    Shared: read it, never write into its folder (a test that edits the project writes its
    own copy with `write_synthetic_project(directory, **SYNTHETIC_BLOCK)`)."""
    truth = jaxba.write_synthetic_project(tmp_path_factory.mktemp("block"), **SYNTHETIC_BLOCK)
    project = jaxba.build_project(jaxba.read_project(truth.project_file))
    return truth, project, jaxba.adjust_project(project)


# The modules that take longest (CPU seconds of a quiet run on 2 cores, with the notebook
# kernels' and subprocesses'), longest first. pytest-xdist's --dist loadscope hands whole
# modules to the workers in collection order; starting with the longest leaves only short
# ones for the end, so the two workers finish together (alphabetical order left one worker
# ~90 s of CPU behind the other: 6:34 instead of ~5:50).
LONGEST_MODULES = (
    "test_notebooks.py", "test_schur_bundle.py", "test_ties.py", "test_differentiable.py",
    "test_batch.py", "test_initialise.py", "test_statistics.py", "test_free_network.py",
    "test_cv_models.py", "test_cli.py", "test_dask.py", "test_faults.py", "test_bal.py",
    "test_schur_adjust.py",
)


def pytest_collection_modifyitems(items):
    """The longest modules first (`LONGEST_MODULES`), the others after in their order."""
    rank = {name: k for k, name in enumerate(LONGEST_MODULES)}
    items.sort(key=lambda item: rank.get(item.path.name, len(rank)))


def pytest_sessionfinish(session):
    if _CACHE_OWNED:
        shutil.rmtree(os.environ["JAX_COMPILATION_CACHE_DIR"], ignore_errors=True)
