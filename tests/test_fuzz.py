"""Malformed input for the readers (hypothesis): a project's tables and BAL files, as
arbitrary bytes, as lines of plausible and implausible tokens, and as the valid text with
tokens replaced. Reading either succeeds or raises the reader's own error (`ProjectError`,
`BalFormatError`), which names the file: never another exception.
"""

import bz2
import gzip
import pathlib
import tempfile

import pytest
from hypothesis import HealthCheck, given, settings, strategies as st
from test_readers import DEFAULTS

from jaxba._io._bal import BalFormatError, read_bal
from jaxba._io._project import read_project
from jaxba._project import ProjectError

# Derandomised: the same examples every run, so CI never fails on a draw it has not seen
# before (hypothesis' database keeps any failure found locally).
FUZZ = settings(max_examples=150, deadline=None, derandomize=True,
                suppress_health_check=[HealthCheck.function_scoped_fixture])
TOKENS = (
    "img1", "img2", "C1", "C2", "P1", "P2", "P3", "T1", "X", "0", "1", "-1", "2.5", "-", "--",
    "1e400", "-1e400", "1e-400", "nan", "inf", "-inf", "0x10", "1_0", "#", "[", "]", "=",
    '"', "'", "é", "\u00a0", "\x00", "\ufeff", "[C1]", "model", '"smac"', "free", "[files]",
)
lines = st.lists(st.lists(st.sampled_from(TOKENS), max_size=9).map(" ".join), max_size=12)
token_lines = lines.map(lambda rows: "\n".join(rows).encode("utf-8"))


def _mutated(text: str):
    """The valid `text` with some whitespace-separated tokens replaced, dropped or doubled."""
    tokens = text.split(" ")

    def mutate(edits):
        out = list(tokens)
        for position, token, how in edits:
            k = position % len(out)
            if how == 0:
                out[k] = token
            elif how == 1 and len(out) > 1:
                del out[k]
            else:
                out.insert(k, token)
        return " ".join(out).encode("utf-8")

    edit = st.tuples(st.integers(0, 10_000), st.sampled_from(TOKENS), st.integers(0, 2))
    return st.lists(edit, min_size=1, max_size=4).map(mutate)


@pytest.fixture(scope="module")
def folder():
    with tempfile.TemporaryDirectory() as name:
        yield pathlib.Path(name)


def _read_project_with(folder: pathlib.Path, name: str, data: bytes) -> None:
    for file, text in DEFAULTS.items():
        (folder / file).write_text(text, encoding="utf-8")
    (folder / name).write_bytes(data)
    try:
        read_project(folder / "lab1.toml")
    except ProjectError as error:
        assert str(error)


@pytest.mark.parametrize("name", sorted(DEFAULTS))
@FUZZ
@given(data=st.data())
def test_project_readers_raise_only_project_errors(folder, name, data):
    text = DEFAULTS[name]
    blob = data.draw(st.one_of(st.binary(max_size=300), token_lines, _mutated(text)))
    _read_project_with(folder, name, blob)


BAL = "2 3 4\n0 0 1.0 2.0\n0 1 -1.0 0.5\n1 1 3.0 -2.0\n1 2 0.0 0.0\n" + "0.1\n" * 18 + "1.0\n" * 9


@FUZZ
@given(data=st.data())
def test_bal_reader_raises_only_bal_errors(folder, data):
    suffix = data.draw(st.sampled_from(["", ".gz", ".bz2"]))
    header = st.tuples(*[st.integers(-2, 4)] * 3).map(lambda t: " ".join(map(str, t)))
    structured = st.tuples(header, lines).map(
        lambda parts: (parts[0] + "\n" + "\n".join(parts[1])).encode("utf-8"))
    blob = data.draw(st.one_of(st.binary(max_size=300), structured, _mutated(BAL)))
    if suffix and data.draw(st.booleans()):  # a valid stream of the text, or garbage
        blob = {".gz": gzip.compress, ".bz2": bz2.compress}[suffix](blob)
    path = folder / f"problem.txt{suffix}"
    path.write_bytes(blob)
    try:
        read_bal(path)
    except BalFormatError as error:
        assert str(path) in str(error)


def test_bal_index_too_large_for_an_integer(tmp_path):
    """An index beyond int64 (1e20) is refused by line, not cast with a warning (found by
    the fuzz test above)."""
    path = tmp_path / "problem.txt"
    observations = "0 1e20 0 0\n" + "0 0 0 0\n" * 3
    path.write_text("2 3 4\n" + observations + "0\n" * (2 * 9 + 3 * 3))
    with pytest.raises(BalFormatError, match="1e\\+20 is not an integer"):
        read_bal(path)
