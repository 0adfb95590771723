"""`python -m jaxba ...`: the `jaxba` command line."""

from ._cli._main import entry

entry()
