"""``python -m nespm_cli.cli``: the ``nespm`` command."""
import sys

from nespm_cli.cli import main

sys.exit(main())
