"""The installed size of each distribution in an environment (docs/install.md).

    python3 -m venv /tmp/inst && /tmp/inst/bin/pip install -c constraints.txt .
    /tmp/inst/bin/python tools/install_size.py            # its own site-packages
    python tools/install_size.py /some/site-packages

Each distribution's size is the sum of the files its RECORD lists (the .pyc files pip compiled
included), in MB (10^6 bytes); the last line is the total. `du -sh` of the folder counts disk
blocks (MiB) and reads a few percent higher.
"""

from __future__ import annotations

import os
import sys
import sysconfig
from importlib import metadata


def sizes(site: str) -> list[tuple[int, str, str]]:
    """(bytes, name, version) of every distribution installed in `site`, largest first."""
    rows = []
    for dist in metadata.distributions(path=[site]):
        total = 0
        for f in dist.files or []:
            try:
                total += os.path.getsize(os.path.join(site, str(f)))
            except OSError:  # listed but absent (a file another distribution removed)
                pass
        rows.append((total, dist.metadata["Name"], dist.version))
    return sorted(rows, reverse=True)


def main(argv=None) -> int:
    argv = sys.argv[1:] if argv is None else argv
    site = argv[0] if argv else sysconfig.get_paths()["purelib"]
    rows = sizes(site)
    for total, name, version in rows:
        print(f"{total / 1e6:8.1f} MB  {name} {version}")
    print(f"{sum(r[0] for r in rows) / 1e6:8.1f} MB  in all ({len(rows)} distributions, {site})")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
