"""``python -m ident.cli``: the jointlab command line."""
import sys

from ident.cli.main import main

sys.exit(main())
