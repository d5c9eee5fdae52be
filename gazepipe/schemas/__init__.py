"""Arrow schemas of every table gazepipe writes; checked on write and on read."""

from __future__ import annotations

import pyarrow as pa

from gazepipe.schemas.markers import MARKERS_CLEAN, MARKERS_RAW

#: tables whose schema does not depend on the session (others are checked by name and version tags)
FIXED_SCHEMAS: dict[str, pa.Schema] = {"markers_raw": MARKERS_RAW, "markers": MARKERS_CLEAN}


def expected_schema(name: str, table: pa.Table) -> pa.Schema | None:
    """The schema a stored table called ``name`` must match (``None``: only its tags are checked)."""
    return FIXED_SCHEMAS.get(name)
