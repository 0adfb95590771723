"""Console and file excerpts in docs/ and README.md, produced by real runs of the documented
commands.

A fenced block right after a line `<!-- excerpt: NAME -->` holds the excerpt NAME of
`EXCERPTS`: a function of one `Run` of the commands of `RUNS`: "help" (`jaxba --help`
and the usage each command's --help prints, wrapped at 100 columns), "lab" (the lab's
input files, the lab adjusted as getting-started.md shows it and from Python as api.md does,
its cameras exported, its incomplete copy adjusted) or "close-range" (a close-range block from
nothing, whose weak points wait for the adjusted block: ~20 s of CPU in the tests). Run from the
repository's root,

    python tests/doc_excerpts.py --write

runs them once in a temporary folder and rewrites every marked block; tests/test_docs.py
runs the same commands and fails on any difference, naming the page, the line and a diff.

Compared as printed, except in three stated ways:
- the run's timings are masked: every number of a `seconds: ...` phrase but the count of
  programs (`8 programs`), which is deterministic;
- the console's `<phase>: compiling...` lines are left out: one shows when lowering a
  program took 0.05 s or more, which depends on the machine and its load;
- a number with a decimal point or an exponent may differ by one unit in its last printed
  digit, or by 1e-9 of itself: the same run rounds differently at about 1e-12 under other
  XLA flags (the tests' cheaper compilation) or on another machine, which can flip the last
  digit of a rounded number. Integers and words compare exactly.
"""

import contextlib
import dataclasses
import difflib
import io
import json
import os
import pathlib
import re
import shutil
import sys
import tempfile
from collections.abc import Callable

ROOT = pathlib.Path(__file__).resolve().parents[1]
DOCS = ROOT / "docs"
LAB = ROOT / "configs" / "lab"
REPORTS = ("lab.out", "lab.res", "lab.sigma", "results.json", "observations.csv")  # not copied
MARKED = re.compile(r"^<!-- excerpt: ([\w.-]+) -->[ \t]*\n```\w*[ \t]*\n(.*?)^```[ \t]*$",
                    re.M | re.S)
NUMBER = re.compile(r"[-+]?(?:\d+\.\d*|\.\d+|\d+)(?:[eE][-+]?\d+)?")
TIMINGS = re.compile(r"seconds: [^\n]*")
COMPILING = re.compile(r"^ +[\w -]+: compiling\.\.\.\n", re.M)
TIMED = re.compile(r"(?<![\d.])\d+(?:\.\d+)?(?![\d.]| programs)")  # not "8 programs"
RELATIVE_TOLERANCE = 1e-9
ELIDED = "  ..."


@dataclasses.dataclass(frozen=True)
class Run:
    """The documented commands run in `folder`, which holds their inputs and outputs;
    `console`: each command's standard output and error, interleaved."""

    folder: pathlib.Path
    console: dict[str, str]

    def file(self, relative: str) -> str:
        return (self.folder / relative).read_text("utf-8")


def _fresh() -> None:
    """Forget the programs compiled in this process, so that a command counts (and compiles
    or loads from the persistent cache) the programs it needs as in a process of its own."""
    import jax

    from jaxba._programs import forget_loaded
    from jaxba._solvers._compiled import solver_compiler_options

    jax.clear_caches()
    forget_loaded()
    solver_compiler_options.cache_clear()  # its probe is a program a fresh process loads


def _jaxba(*argv: str) -> str:
    """`jaxba ARGV` in this process; its console output. A failing command raises."""
    from jaxba._cli._main import main

    _fresh()
    text = io.StringIO()
    with contextlib.redirect_stdout(text), contextlib.redirect_stderr(text):
        code = main(list(argv))
    if code != 0:
        raise RuntimeError(f"jaxba {' '.join(argv)} exited with {code}:\n{text.getvalue()}")
    return text.getvalue()


def incomplete_lab(folder: pathlib.Path) -> pathlib.Path:
    """The lab copied into `folder` with `-` for every EOP and only its control points (1, 10,
    71) in the points table: 18 images and 77 tie points without approximations, cli.md's
    example. Returns its project file."""
    shutil.copytree(LAB, folder, ignore=shutil.ignore_patterns(*REPORTS))
    images = folder / "orientation.txt"
    images.write_text("".join(
        line if line.startswith("#") else " ".join(line.split()[:2] + ["-"] * 6) + "\n"
        for line in images.read_text().splitlines(keepends=True)))
    points = folder / "ground_points.txt"
    points.write_text("".join(line for line in points.read_text().splitlines(keepends=True)
                              if "- - -" not in line))
    return folder / "lab.toml"


def run_lab(folder: pathlib.Path) -> Run:
    """The lab's commands the excerpts show, in `folder` (relative paths, as a user types
    them)."""
    shutil.copytree(LAB, folder / "configs" / "lab", ignore=shutil.ignore_patterns(*REPORTS))
    incomplete_lab(folder / "incomplete")
    with contextlib.chdir(folder):
        console = {
            "adjust": _jaxba("adjust", "configs/lab/lab.toml", "--out", "out/lab"),
            "export": _jaxba("export", "out/lab", "--format", "opencv"),
            "incomplete": _jaxba("adjust", "incomplete/lab.toml", "--out", "out/incomplete"),
            "summary": _summary("configs/lab/lab.toml"),
        }
    return Run(folder, console)


def _summary(project_file: str) -> str:
    """`result.summary()` of the project adjusted from Python, as api.md does."""
    import jaxba

    _fresh()
    return jaxba.adjust_project(jaxba.build_project(jaxba.read_project(project_file))).summary()


def run_close_range(folder: pathlib.Path) -> Run:
    """cli.md's block from nothing: `jaxba adjust` of a close-range project without
    approximations, 8 images and 300 wall points (seed 0), in `folder`."""
    import jaxba

    jaxba.write_close_range_project(folder / "block", n_images=8, n_points=300,
                                    approximations=False)
    with contextlib.chdir(folder):
        console = {"adjust": _jaxba("adjust", "block/close_range.toml", "--out", "out")}
    return Run(folder, console)


HELP_COLUMNS = "100"  # the width argparse wraps the usage to, whatever the terminal


def _help(*command: str) -> str:
    """What `jaxba COMMAND --help` prints, wrapped at HELP_COLUMNS."""
    from jaxba._cli._main import main

    before = os.environ.get("COLUMNS")
    os.environ["COLUMNS"] = HELP_COLUMNS  # argparse's width
    text = io.StringIO()
    try:
        with contextlib.redirect_stdout(text):
            main([*command, "--help"])
    finally:
        if before is None:
            del os.environ["COLUMNS"]
        else:
            os.environ["COLUMNS"] = before
    return text.getvalue()


def commands(top_help: str) -> list[str]:
    """The subcommands listed under "positional arguments" of `jaxba --help`."""
    section = top_help.split("positional arguments:", 1)[1].split("\n\n", 1)[0]
    return re.findall(r"^ {4}([a-z][\w-]*)\s", section, re.M)


def run_help(folder: pathlib.Path) -> Run:
    """`jaxba --help`, console "", and the usage (the first paragraph) of each command's
    --help (`folder` is not used)."""
    top = _help()
    usage = {command: _help(command).split("\n\n", 1)[0] + "\n" for command in commands(top)}
    return Run(folder, {"": top} | usage)


def _usage(command: str) -> Callable[[Run], str]:
    return lambda run: run.console[command]


# --- selections --------------------------------------------------------------------------


def _lines(text: str, start: str, count: int | None = None) -> list[str]:
    """`count` lines (all to the next blank line: None) from the first that starts with
    `start`."""
    lines = text.splitlines()
    first = next((k for k, line in enumerate(lines) if line.startswith(start)), None)
    if first is None:
        raise ValueError(f"no line starts with {start!r}")
    if count is None:
        end = next((k for k in range(first, len(lines)) if not lines[k].strip()), len(lines))
        return lines[first:end]
    return lines[first:first + count]


def _until(text: str, start: str) -> list[str]:
    """The lines up to and with the first that starts with `start`."""
    lines = text.splitlines()
    last = next(k for k, line in enumerate(lines) if line.startswith(start))
    return lines[:last + 1]


def _join(*parts: list[str]) -> str:
    return "\n".join(line for part in parts for line in part) + "\n"


def _cameras_toml(run: Run) -> str:
    """The camera up to K0; the terms after it, all 0.0 in the file, named in a comment."""
    lines = run.file("configs/lab/cameras.toml").splitlines()
    k0 = next(k for k, line in enumerate(lines) if line.startswith("K0 "))
    terms = [line.split(" = ") for line in lines[k0 + 1:-1]]
    if any(value != "0.0" for _, value in terms):
        raise ValueError(f"cameras.toml: not all of {[name for name, _ in terms]} are 0.0")
    comment = f"# ... {' '.join(name for name, _ in terms)}, all 0.0"
    return _join(lines[:k0 + 1], [comment], lines[-1:])


def _tables(run: Run) -> str:
    """Each table's header and some of its rows, under its file name."""
    shown = {"orientation.txt": ["img01 "], "image_coordinates.txt": ["img01 1 "],
             "ground_points.txt": ["1 ", "2 ", "10 ", "71 "], "distances.txt": ["10 71 "]}
    parts = []
    for name, starts in shown.items():
        table = run.file(f"configs/lab/{name}")
        header = table.splitlines()[0].removeprefix("# ")
        parts.append([f"# {name}: {header}", *(_lines(table, start, 1)[0] for start in starts)])
    return _join(*[part + [""] for part in parts[:-1]], parts[-1])


def _incomplete_tables(run: Run) -> str:
    """The incomplete lab's images (the first two) and points tables."""
    images = run.file("incomplete/orientation.txt").splitlines()
    points = run.file("incomplete/ground_points.txt").splitlines()
    return _join([f"# orientation.txt: {images[0].removeprefix('# ')}"], images[1:3], ["..."],
                 [f"# ground_points.txt: {points[0].removeprefix('# ')}"], points[1:])


def _lab_out(run: Run) -> str:
    out = run.file("out/lab/lab.out")
    return _join(
        _lines(out, "Camera C1", 7), [ELIDED, ""],
        _lines(out, "IOP correlations of camera C1"), [""],
        _lines(out, "Image residuals", 4), [""],
        _lines(out, "Reliability"), [""],
        _lines(out, "Object points", 4), [ELIDED], _lines(out, "  10 ", 1))


def _one_line(value) -> str:
    return json.dumps(value, ensure_ascii=False)


def _first_of_each(mapping: dict, key: str, *extra: str) -> str:
    """`{"<key>": {"<first>": ..., "...": "..."}}`: one entry and its first value."""
    entry = mapping[key]
    first = next(iter(entry))
    shown = [f'"{first}": {_one_line(entry[first])}', '"...": "..."']
    shown += [f'"{name}": {_one_line(entry[name])}' for name in extra]
    return f'"{key}": {{' + ", ".join(shown) + "}"


def _results_json(run: Run) -> str:
    results = json.loads(run.file("out/lab/results.json"))
    head = ("project", "converged", "message", "steps", "solver", "datum", "sigma0",
            "sigma0_squared", "variance_test", "redundancy", "n_observations", "n_unknowns")
    lines = [f'  "{key}": {_one_line(results[key])},' for key in head]
    lines += [f'  "cameras": {{{_first_of_each(results["cameras"], "C1")}, "...": "..."}},',
              f'  "images": {{{_first_of_each(results["images"], "img01")}, "...": "..."}},',
              '  "points": {',
              f'    {_first_of_each(results["points"], "1")},',
              f'    {_first_of_each(results["points"], "2", "ellipsoid")},',
              '    "...": "..."',
              "  },"]
    tail = ("reliability", "outliers")
    lines += [f'  "{key}": {_one_line(results[key])},' for key in tail]
    lines[-1] = lines[-1].rstrip(",")
    return "{\n" + "\n".join(lines) + "\n}\n"


def _observations_csv(run: Run) -> str:
    table = run.file("out/lab/observations.csv")
    return _join(_lines(table, "type,", 2), _lines(table, "distances,", 1))


def _deferral(run: Run) -> str:
    """The line naming the deferred points (the first of them), the first adjustment's
    first line, and the lines of the deferred points' turn."""
    lines = run.console["adjust"].splitlines()
    deferred = next(line for line in lines if line.startswith("  deferred "))
    deferred = deferred[:deferred.index("; ", deferred.index("': "))] + "; ..."
    turn = next(k for k, line in enumerate(lines) if line.startswith("intersecting the "))
    again = next(k for k in range(turn, len(lines)) if lines[k].startswith("adjusting close"))
    return _join([deferred], _lines(run.console["adjust"], "adjusting close", 1), ["..."],
                 lines[turn:again + 1])


RUNS: dict[str, Callable[[pathlib.Path], Run]] = {
    "help": run_help, "lab": run_lab, "close-range": run_close_range}
EXCERPTS: dict[str, dict[str, Callable[[Run], str]]] = {"help": {
    "help": lambda run: run.console[""],
    **{f"usage-{command}": _usage(command) for command in (
        "adjust", "init", "import", "detect", "batch", "bal", "export", "compare")},
}, "lab": {
    "lab.toml": lambda run: run.file("configs/lab/lab.toml"),
    "lab-cameras.toml": _cameras_toml,
    "lab-tables": _tables,
    "lab-console": lambda run: run.console["adjust"],
    "lab.out": _lab_out,
    "lab.res": lambda run: _join(_lines(run.file("out/lab/lab.res"), "# image_id", 3)),
    "lab.sigma": lambda run: run.file("out/lab/lab.sigma"),
    "lab-results.json": _results_json,
    "lab-observations.csv": _observations_csv,
    "lab-export-console": lambda run: run.console["export"],
    "incomplete-lab-tables": _incomplete_tables,
    "lab-summary": lambda run: run.console["summary"],
    "incomplete-lab-console": lambda run: _join(
        _until(run.console["incomplete"], "adjusting lab:")),
}, "close-range": {
    "close-range-deferral-console": _deferral,
}}


# --- the pages ---------------------------------------------------------------------------


@dataclasses.dataclass(frozen=True)
class Block:
    """A marked block of `page`: its excerpt's name, its text and the line its text starts
    on (1-based)."""

    page: pathlib.Path
    name: str
    text: str
    line: int


def marked_blocks(page: pathlib.Path) -> list[Block]:
    text = page.read_text("utf-8")
    return [Block(page, match.group(1), match.group(2), text.count("\n", 0, match.start(2)) + 1)
            for match in MARKED.finditer(text)]


def pages() -> list[pathlib.Path]:
    """docs/ and README.md: those with a marked block."""
    return [page for page in [*sorted(DOCS.rglob("*.md")), ROOT / "README.md"]
            if MARKED.search(page.read_text("utf-8"))]


def excerpts(kind: str, run: Run) -> dict[str, str]:
    """The excerpts of the run of RUNS[kind]."""
    return {name: make(run) for name, make in EXCERPTS[kind].items()}


def _normalise(text: str) -> str:
    """Without the `compiling...` lines; every number of a `seconds: ...` phrase but the
    count of programs as `#`."""
    return TIMINGS.sub(lambda match: TIMED.sub("#", match.group(0)), COMPILING.sub("", text))


def _same_number(documented: str, fresh: str) -> bool:
    if not any(mark in documented + fresh for mark in ".eE"):
        return documented == fresh
    mantissa = re.split(r"[eE]", documented)[0]
    exponent = int(re.split(r"[eE]", documented)[1]) if re.search(r"[eE]", documented) else 0
    decimals = len(mantissa.split(".")[1]) if "." in mantissa else 0
    unit = 10.0 ** (exponent - decimals)
    a, b = float(documented), float(fresh)
    return abs(a - b) <= unit * (1 + 1e-9) or abs(a - b) <= RELATIVE_TOLERANCE * abs(b)


def same(documented: str, fresh: str) -> bool:
    """Whether a block matches its fresh excerpt, as the module's docstring says."""
    documented, fresh = _normalise(documented), _normalise(fresh)
    if NUMBER.split(documented) != NUMBER.split(fresh):
        return False
    numbers = NUMBER.findall(documented), NUMBER.findall(fresh)
    return len(numbers[0]) == len(numbers[1]) and all(map(_same_number, *numbers))


def _shown(page: pathlib.Path) -> pathlib.Path:
    """A page's path from the repository's root (another file's as it is)."""
    return page.relative_to(ROOT) if page.is_relative_to(ROOT) else page


def difference(block: Block, fresh: str) -> str:
    """What differs, as a diff of the page's block against the fresh excerpt."""
    where = f"{_shown(block.page)}:{block.line}"
    diff = difflib.unified_diff(block.text.splitlines(), fresh.splitlines(),
                                f"{where} (excerpt {block.name})", "a fresh run", lineterm="")
    return "\n".join(diff)


def rewrite(page: pathlib.Path, fresh: dict[str, str]) -> bool:
    """Replace the page's marked blocks that differ by their fresh excerpts; whether it
    changed. An unknown name raises."""
    text = page.read_text("utf-8")

    def replace(match: re.Match) -> str:
        name, old = match.group(1), match.group(2)
        if name not in fresh:
            raise KeyError(f"{_shown(page)}: no excerpt named {name!r}")
        new = old if same(old, fresh[name]) else fresh[name]
        start, end = match.start(2) - match.start(0), match.end(2) - match.start(0)
        return match.group(0)[:start] + new + match.group(0)[end:]

    new_text = MARKED.sub(replace, text)
    if new_text != text:
        page.write_text(new_text, "utf-8")
    return new_text != text


def main(argv: list[str]) -> int:
    if argv != ["--write"]:
        print(__doc__.split("\n\n")[1].strip(), file=sys.stderr)
        print("usage: python tests/doc_excerpts.py --write", file=sys.stderr)
        return 2
    fresh = {}
    for kind, run in RUNS.items():
        with tempfile.TemporaryDirectory(prefix="jaxba-doc-excerpts-") as folder:
            fresh |= excerpts(kind, run(pathlib.Path(folder)))
    for page in pages():
        if rewrite(page, fresh):
            print(f"rewrote {_shown(page)}")
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
