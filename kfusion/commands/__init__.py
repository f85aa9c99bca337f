"""Subcommands of the ``kfusion`` command line; one module each (see :mod:`kfusion.cli`)."""
