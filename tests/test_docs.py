"""The documentation (docs/, README.md, mkdocs.yml) cannot drift from the code unnoticed.

- The site builds with `mkdocs build --strict`: every link and anchor resolves, every page is
  in the navigation (mkdocs.yml's `validation` turns these into warnings, strict into errors).
- Nothing points outside the repository (the team's internal documents) or at private modules.
- The Python examples marked `<!-- run -->` run, in order, as one session per page; a print
  followed by `# → TEXT` prints TEXT.
- Every console and file excerpt marked `<!-- excerpt: NAME -->` is what a fresh run of the
  documented commands prints or writes (tests/doc_excerpts.py, which also rewrites them).
- The command-line page names every subcommand and option the program prints in its --help,
  each option in its subcommand's section; the home page's table of commands names every
  subcommand once.
- The outputs page's table of results.json names every key of the lab's results.json once.
- The API page names every public name; the project-files page every setting and every
  camera parameter.
"""

import dataclasses
import importlib.util
import json
import os
import pathlib
import re
import subprocess
import sys

import doc_excerpts
import pytest

import jaxba

ROOT = pathlib.Path(__file__).resolve().parents[1]
DOCS = ROOT / "docs"
RUN_MARK = "<!-- run -->"
FORBIDDEN = ("../shared", "FORMATS.md", "CONVENTIONS.md", "ARCHITECTURE.md", "jaxba._")
EXAMPLES_TIMEOUT_S = 300  # the API page's examples take ~10 s, most of it compiling
# A command-line option in a --help text: "-h", "--max-steps"; not the "-c" of "Schur-complement".
OPTION = re.compile(r"(?<![\w-])--?[a-zA-Z][\w-]*")


def documentation_files() -> list[pathlib.Path]:
    return [*sorted(DOCS.rglob("*.md")), ROOT / "README.md", ROOT / "mkdocs.yml"]


def runnable_blocks(text: str) -> list[tuple[int, str]]:
    """(line of the code's first line, code) of every ```python block right after a
    `<!-- run -->` line."""
    pattern = re.compile(r"^<!-- run -->[ \t]*\n```python[ \t]*\n(.*?)^```[ \t]*$", re.M | re.S)
    return [(text.count("\n", 0, match.start(1)) + 1, match.group(1))
            for match in pattern.finditer(text)]


def pages_with_examples() -> list[pathlib.Path]:
    return [page for page in sorted(DOCS.glob("*.md")) if RUN_MARK in page.read_text("utf-8")]


@pytest.mark.skipif(importlib.util.find_spec("mkdocs") is None,
                    reason="mkdocs is not installed (pip install 'jaxba[docs]' or '.[dev]')")
def test_site_builds_in_strict_mode(tmp_path):
    site = tmp_path / "site"
    done = subprocess.run(
        [sys.executable, "-m", "mkdocs", "build", "--strict", "--site-dir", str(site)],
        cwd=ROOT, capture_output=True, text=True, timeout=300)
    assert done.returncode == 0, done.stdout + done.stderr
    assert (site / "index.html").is_file()
    assert (site / "api" / "index.html").is_file()


@pytest.mark.parametrize("path", documentation_files(), ids=lambda p: str(p.relative_to(ROOT)))
def test_no_reference_outside_the_repository(path):
    text = path.read_text(encoding="utf-8")
    found = [word for word in FORBIDDEN if word in text]
    assert not found, f"{path.relative_to(ROOT)} mentions {found}"


def test_examples_are_marked():
    pages = pages_with_examples()
    assert DOCS / "api.md" in pages
    for page in pages:
        text = page.read_text("utf-8")
        assert text.count(RUN_MARK) == len(runnable_blocks(text)), (
            f"{page.name}: a {RUN_MARK} line not followed by a ```python block")


# `print(...)  # → TEXT`, or `# → TEXT` on the line after `print(...)`: the page says it prints
# TEXT (compared as the excerpts are: doc_excerpts.same).
PRINTS = re.compile(r"^(?P<indent>[ \t]*)print\((?P<args>.*)\)[ \t]+# → (?P<text>.*)$")
PRINT = re.compile(r"^(?P<indent>[ \t]*)print\((?P<args>.*)\)[ \t]*$")
SAYS = re.compile(r"^[ \t]*# → (?P<text>.*)$")


def checked_prints(code: str, first_line: int) -> str:
    """`code` with each print whose output the page states (PRINTS) calling
    `_printed(TEXT, LINE)` instead, which prints and compares; as many lines as before."""
    lines = code.splitlines()
    for k, line in enumerate(lines):
        match = PRINTS.match(line)
        follows = SAYS.match(lines[k + 1]) if k + 1 < len(lines) else None
        if match is None and follows is not None and (bare := PRINT.match(line)):
            match = {**bare.groupdict(), "text": follows["text"]}
        if match is not None:
            lines[k] = (f"{match['indent']}_printed({match['text']!r}, {first_line + k})"
                        f"({match['args']})")
    return "\n".join(lines) + "\n"


def test_checked_prints():
    code = 'x = 1\nprint(x)  # → 1\nprint(f"{x:.2f}", (x))\n# → 1.00 1\nprint(x)  # one\n'
    assert checked_prints(code, 10) == (
        "x = 1\n_printed('1', 11)(x)\n_printed('1.00 1', 12)(f\"{x:.2f}\", (x))\n# → 1.00 1\n"
        "print(x)  # one\n")


_RUNNER = """
import io, json, sys, traceback
sys.path.insert(0, sys.argv[3])
from doc_excerpts import same

def _printed(expected, line):
    def check(*args, **kwargs):
        text = io.StringIO()
        print(*args, file=text, **kwargs)
        sys.stdout.write(text.getvalue())
        if not same(expected + "\\n", text.getvalue()):
            raise AssertionError(f"{sys.argv[2]}:{line}: prints {text.getvalue().strip()!r},"
                                 f" the page says {expected!r}")
    return check

blocks = json.load(open(sys.argv[1], encoding="utf-8"))
namespace = {"__name__": "__main__", "_printed": _printed}
for line, code in blocks:
    try:
        # Padded so that a traceback gives the line of the page.
        exec(compile("\\n" * (line - 1) + code, sys.argv[2], "exec"), namespace)
    except BaseException:
        traceback.print_exc()
        sys.exit(1)
"""


@pytest.mark.parametrize("page", pages_with_examples(), ids=lambda p: p.name)
def test_examples_run(page, tmp_path):
    """The page's runnable blocks, in order, in one fresh interpreter (float64 on, as a user
    must), from the repository's root (the examples read configs/); what a print prints is
    what the page says where it says it (`# → TEXT`)."""
    blocks_file = tmp_path / "blocks.json"
    blocks = [(line, checked_prints(code, line))
              for line, code in runnable_blocks(page.read_text("utf-8"))]
    blocks_file.write_text(json.dumps(blocks), "utf-8")
    runner = tmp_path / "run_blocks.py"
    runner.write_text(_RUNNER, "utf-8")
    environment = {**os.environ, "JAX_ENABLE_X64": "1", "OPENBLAS_NUM_THREADS": "1",
                   "MPLBACKEND": "Agg", "TMPDIR": str(tmp_path)}  # the examples' temp folders
    done = subprocess.run(
        [sys.executable, str(runner), str(blocks_file), str(page.relative_to(ROOT)),
         str(ROOT / "tests")],
        cwd=ROOT, env=environment, capture_output=True, text=True, timeout=EXAMPLES_TIMEOUT_S)
    assert done.returncode == 0, done.stdout[-4000:] + done.stderr[-4000:]


def _help(*command: str) -> str:
    done = subprocess.run([sys.executable, "-m", "jaxba", *command, "--help"], cwd=ROOT,
                          capture_output=True, text=True, timeout=120)
    assert done.returncode == 0, done.stderr
    return done.stdout


def _section(page: str, heading: str) -> str:
    """The text of `## heading` up to the next level-2 heading."""
    match = re.search(rf"^## {re.escape(heading)}[ \t]*\n(.*?)(?=^## |\Z)", page, re.M | re.S)
    assert match, f"cli.md has no section '## {heading}'"
    return match.group(1)


def _named(word: str, text: str) -> bool:
    return re.search(rf"(?<![\w-]){re.escape(word)}(?![\w-])", text) is not None


def _table_rows(text: str) -> str:
    return "\n".join(line for line in text.splitlines() if line.startswith("|"))


def test_cli_page_names_every_subcommand_and_option():
    """Every option in a table row of its section (the common ones in "Options of every
    command"), every choice of an option in its section, every subcommand a section."""
    page = (DOCS / "cli.md").read_text("utf-8")
    top = _help()
    commands = doc_excerpts.commands(top)
    assert {"adjust", "batch", "bal"} <= set(commands)
    common = _table_rows(_section(page, "Options of every command"))
    missing = [option for option in sorted(set(OPTION.findall(top))) if not _named(option, common)]
    for command in commands:
        text = _help(command)
        section = _section(page, f"jaxba {command}")
        rows = _table_rows(section)
        missing += [f"{command} {option}" for option in sorted(set(OPTION.findall(text)))
                    if option not in ("-h", "--help") and not _named(option, rows)]
        choices = {choice for group in re.findall(r"\{([\w,]+)\}", text)
                   for choice in group.split(",")}
        missing += [f"{command} choice {choice}" for choice in sorted(choices)
                    if not _named(choice, rows)]
    assert not missing, f"not on the command-line page: {missing}"


def test_api_page_names_every_public_name():
    page = (DOCS / "api.md").read_text("utf-8")
    top, advanced = page.split("\n## jaxba.advanced")
    spans = " ".join(re.findall(r"`([^`\n]+)`", top))
    missing = [name for name in jaxba.__all__ if not _named(name, spans)]
    advanced = " ".join(re.findall(r"`([^`\n]+)`", advanced))
    missing += [f"jaxba.advanced.{name}" for name in jaxba.advanced.__all__
                if not _named(name, advanced)]
    assert not missing, f"public names not on the API page: {missing}"
    # The two namespaces do not overlap; an internal name at the top names its new place.
    assert not set(jaxba.__all__) & set(jaxba.advanced.__all__)
    with pytest.raises(AttributeError, match="jaxba.advanced.flatten"):
        jaxba.flatten  # noqa: B018


def test_project_files_page_names_every_setting_and_camera_parameter():
    page = (DOCS / "project-files.md").read_text("utf-8")
    settings = _section(page, "Settings")
    fields = dataclasses.fields(jaxba.AdjustmentSettings)
    missing = [f"[adjustment] {field.name}" for field in fields
               if f"`{field.name}`" not in settings]
    for model, camera in jaxba.CAMERA_MODELS.items():
        row = re.search(rf"^\| `\"{model}\"` \| `([^`]*)`", page, re.M)
        if row is None or row.group(1).split() != list(camera.parameter_names):
            missing.append(f"camera model {model!r}: {' '.join(camera.parameter_names)}")
    assert not missing, f"not (or not so) on the project-files page: {missing}"


# --- excerpts of real runs -------------------------------------------------------------------


@pytest.fixture(scope="module")
def fresh_run(tmp_path_factory):
    """The lab's documented commands, run once for all their excerpts (~20 s CPU, most of it
    compiling)."""
    return doc_excerpts.run_lab(tmp_path_factory.mktemp("excerpts"))


def _stale_blocks(page: pathlib.Path, fresh: dict[str, str]) -> list[str]:
    """The diff of every block of `page` that shows an excerpt of `fresh` and differs."""
    return [doc_excerpts.difference(block, fresh[block.name])
            for block in doc_excerpts.marked_blocks(page)
            if block.name in fresh and not doc_excerpts.same(block.text, fresh[block.name])]


def _assert_fresh(stale: list[str]) -> None:
    assert not stale, ("\n\n".join(stale)
                       + "\n\nupdate them with: python tests/doc_excerpts.py --write")


def test_excerpts_are_marked_and_shown():
    """Every marker is followed by a fenced block, names an excerpt, and every excerpt is
    shown on some page."""
    names = []
    for page in [*sorted(DOCS.rglob("*.md")), ROOT / "README.md"]:
        blocks = doc_excerpts.marked_blocks(page)
        assert page.read_text("utf-8").count("<!-- excerpt:") == len(blocks), (
            f"{page.name}: an excerpt marker not followed by a fenced block")
        names += [block.name for block in blocks]
    known = {name for excerpts in doc_excerpts.EXCERPTS.values() for name in excerpts}
    assert set(names) <= known, set(names) - known
    assert known <= set(names), known - set(names)


@pytest.mark.parametrize("page", doc_excerpts.pages(), ids=lambda p: p.name)
def test_excerpts_match_a_fresh_run(page, fresh_run):
    fresh = doc_excerpts.excerpts("lab", fresh_run)
    fresh |= doc_excerpts.excerpts("help", doc_excerpts.run_help(fresh_run.folder))
    _assert_fresh(_stale_blocks(page, fresh))


@pytest.mark.slow  # ~20 s CPU: an initialisation and two adjustments of 1,070 image points
def test_close_range_excerpts_match_a_fresh_run(tmp_path):
    fresh = doc_excerpts.excerpts("close-range", doc_excerpts.run_close_range(tmp_path))
    _assert_fresh([diff for page in doc_excerpts.pages() for diff in _stale_blocks(page, fresh)])


def test_excerpt_comparison_is_as_printed():
    """Words and integers exactly, the last printed digit of a decimal within one unit, the
    timings and compile notices not at all."""
    same = doc_excerpts.same
    assert same("iter 4 cost 1.2168e+03 sigma0^2 0.995782\n",
                "iter 4 cost 1.2169e+03 sigma0^2 0.995783\n")
    assert not same("iter 4 sigma0^2 0.995782\n", "iter 4 sigma0^2 0.995784\n")
    assert not same("converged after 4 iterations\n", "converged after 5 iterations\n")
    assert not same("datum: control\n", "datum: free\n")
    assert not same("a\nb\n", "a\n")
    assert same("seconds: read 0.06, solve 0.21; compile 2.21 (8 programs, 8 from the cache)\n",
                "seconds: read 0.02, solve 1.74; compile 9.10 (8 programs, 0 from the cache)\n")
    assert not same("seconds: compile 2.21 (8 programs, 8 from the cache)\n",
                    "seconds: compile 2.21 (17 programs, 8 from the cache)\n")
    assert same("adjusting lab\n  solve: compiling...\niter 0\n", "adjusting lab\niter 0\n")
    assert same('{"sigma0": 0.9978887538834256}', '{"sigma0": 0.9978887538834226}')
    assert not same('{"sigma0": 0.9978887538834256}', '{"sigma0": 0.9978897538834226}')


def test_rewrite_replaces_only_stale_blocks(tmp_path):
    page = tmp_path / "page.md"
    page.write_text("x\n<!-- excerpt: a -->\n```text\nold 1\n```\n<!-- excerpt: b -->\n```text\n"
                    "same 0.5\n```\n", "utf-8")
    assert doc_excerpts.rewrite(page, {"a": "new 2\n", "b": "same 0.6\n"})
    assert page.read_text("utf-8") == ("x\n<!-- excerpt: a -->\n```text\nnew 2\n```\n"
                                       "<!-- excerpt: b -->\n```text\nsame 0.5\n```\n")
    assert not doc_excerpts.rewrite(page, {"a": "new 2\n", "b": "same 0.5\n"})
    with pytest.raises(KeyError, match="no excerpt named 'a'"):
        doc_excerpts.rewrite(page, {"b": ""})


def test_outputs_page_names_every_results_key_once(fresh_run):
    """Each top-level key of the lab's results.json has one row in the table of
    outputs.md's results.json section (rows for keys the lab lacks, such as `rigs`, may
    follow)."""
    section = _section((DOCS / "outputs.md").read_text("utf-8"), "results.json")
    rows = re.findall(r"^\| `([^`]+)`(?:, `([^`]+)`)* \|", section, re.M)
    keys = [key for row in rows for key in row if key]
    results = json.loads((fresh_run.folder / "out" / "lab" / "results.json").read_text())
    missing = [key for key in results if key not in keys]
    twice = sorted({key for key in keys if keys.count(key) > 1})
    assert not missing and not twice, f"missing: {missing}, more than one row: {twice}"


def test_home_page_lists_every_command_once():
    """index.md's table of commands: one row per subcommand of `jaxba --help`, and no
    command the program lacks."""
    page = (DOCS / "index.md").read_text("utf-8")
    rows = re.findall(r"^\| `jaxba ([a-z][\w-]*)", _section(page, "The commands"), re.M)
    commands = doc_excerpts.commands(_help())
    assert sorted(rows) == sorted(commands), f"table {rows}, program {commands}"
