"""The ``jointlab`` command line (one module per subcommand in ``commands``)."""

from .main import main

__all__ = ["main"]
