"""Print pip constraints that pin every runtime dependency of pyproject.toml to the oldest release series it
allows (``numpy>=1.26,<3`` → ``numpy==1.26.*``), for CI's oldest-versions leg."""

from __future__ import annotations

import re
import sys
import tomllib
from pathlib import Path

project = tomllib.loads((Path(__file__).parents[1] / "pyproject.toml").read_text())["project"]
for requirement in project["dependencies"]:
    found = re.fullmatch(r"\s*([A-Za-z0-9_.\-\[\]]+)\s*>=\s*([0-9][0-9.]*)\s*(,.*)?", requirement)
    if found is None:
        sys.exit(f"{requirement!r}: no lower bound to pin (write it as name>=X,<Y)")
    name, lowest = re.sub(r"\[.*\]", "", found.group(1)), found.group(2)
    print(f"{name}=={lowest}.*" if lowest.count(".") < 2 else f"{name}=={lowest}")
