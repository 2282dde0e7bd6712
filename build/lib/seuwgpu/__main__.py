"""`python -m seuwgpu` = the `seuwgpu` command."""

import sys

from seuwgpu.apps.cli import main

sys.exit(main())
