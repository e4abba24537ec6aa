"""`python -m multipendulum` is the `multipendulum` command."""
import sys

from .cli import main

sys.exit(main())
