"""`python -m launcher` is the `launch` command."""

import sys

from launcher.cli.launch import main

sys.exit(main())
