"""The `seuwgpu` command line."""

import sys


def main(argv=None):
    print("seuwgpu: under construction", file=sys.stderr)
    return 0
