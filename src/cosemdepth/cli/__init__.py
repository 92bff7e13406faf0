"""Command-line interface: ``cosemdepth <command> ...`` (see :mod:`cosemdepth.cli.main`)."""
