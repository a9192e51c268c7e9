"""Command-line interface; see :mod:`lfring.cli.main`."""
