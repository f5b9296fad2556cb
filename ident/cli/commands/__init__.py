"""Subcommands of the jointlab CLI, one module each (register/run)."""
