"""The project file's text (docs/project-files.md), the one header every writer of a
project writes (`jaxba init`, the importers, `jaxba detect`, the synthetic blocks):
`project_toml`, and a TOML value's text, `toml_text`. No jax."""

import json
from collections.abc import Mapping, Sequence


def toml_text(value) -> str:
    """A TOML value: string, bool, integer, finite float (in full, `repr`) or list of them."""
    if isinstance(value, str):
        return json.dumps(value, ensure_ascii=False).replace("\x7f", "\\u007f")
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, int | float):
        return repr(value)
    if isinstance(value, list):
        return "[" + ", ".join(map(toml_text, value)) + "]"
    raise TypeError(f"no TOML for {value!r}")


def project_toml(
    name: str, image_units: str, files: Mapping[str, str], adjustment: Mapping[str, object],
    *, comment: Sequence[str] = (), notes: Mapping[str, str] | None = None,
) -> str:
    """The project file: the `comment` lines (each written "# line"), [project] (`name`,
    `image_units`), [files] (table key -> file name, relative to the project file) and,
    unless `adjustment` is empty, [adjustment] (key -> value, in order; `notes`: key -> a
    comment after that key's value)."""
    notes = notes or {}
    lines = [f"# {line}" for line in comment]
    lines += ["[project]", f"name = {toml_text(name)}",
              f"image_units = {toml_text(image_units)}", "", "[files]"]
    lines += [f"{key} = {toml_text(file)}" for key, file in files.items()]
    if adjustment:
        lines += ["", "[adjustment]"]
        lines += [f"{key} = {toml_text(value)}" + (f"  # {notes[key]}" if key in notes else "")
                  for key, value in adjustment.items()]
    return "\n".join(lines) + "\n"
