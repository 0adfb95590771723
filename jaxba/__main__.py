"""`python -m jaxba ...`: the `jaxba` command line."""

from ._cli import entry

entry()
