"""Command-line interface: ``cosemdepth <command> ...``.

Its public name is the module :mod:`cosemdepth.cli.main` (``main.main(argv)`` runs a command line); importing it loads
the command table only, each command's module is imported when the command runs."""

from . import main

__all__ = ["main"]
