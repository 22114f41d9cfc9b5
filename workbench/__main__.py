"""``python -m workbench`` is the ``workbench`` command (for machines where the script is not on PATH)."""
import sys

from workbench.cli import main

if __name__ == "__main__":
    sys.exit(main())
