"""`python -m seuwgpu` = the `seuwgpu` command."""

import sys

from seuwgpu.apps.cli import console_main

sys.exit(console_main())
