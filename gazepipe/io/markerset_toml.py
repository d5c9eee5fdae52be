"""Read and validate a ``markerset.toml`` (SPEC §1): markers, segments from the root to the head, the target,
clapper, head centre, level-of-detail segments and camera.

Every problem is a :class:`~gazepipe.errors.ConfigError` naming the file, the dotted key and what is wrong, on
one line. :func:`validate_markerset` returns every problem found; :func:`load_markerset` raises the first.
"""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any

from gazepipe.errors import ConfigError
from gazepipe.io.toml_common import Collector, is_number, key_name, read_document, show, suggest, type_name
from gazepipe.model import MarkerSet, Segment
from gazepipe.timebase import unit_scale_to_mm

_MARKERSET_TOP = ("schema", "up_axis", "units", "root", "target", "clapper", "head_centre", "eye_offset_mm",
                  "segments", "lod", "camera")


def validate_markerset(path: str | Path) -> list[ConfigError]:
    """Every problem in a markerset.toml (empty when it is valid)."""
    return _parse_markerset(Path(path).absolute())[1]


def load_markerset(path: str | Path) -> MarkerSet:
    """Read and validate ``markerset.toml``; raises the first :class:`ConfigError` found."""
    ms, errors = _parse_markerset(Path(path).absolute())
    if errors:
        raise errors[0]
    assert ms is not None
    return ms


def _parse_markerset(path: Path) -> tuple[MarkerSet | None, list[ConfigError]]:
    col = Collector(path, doc="markerset")
    doc = read_document(path, col, _MARKERSET_TOP)
    if doc is None:
        return None, col.errors

    up_axis, units = _axis_and_units(doc, col)
    root = col.marker_name(doc["root"], "root") if "root" in doc else None
    if "root" not in doc:
        col.add("root", "missing (the marker at the base of the spine)")
    target = col.marker_name(doc["target"], "target") if "target" in doc else None
    head_centre = col.marker_name(doc["head_centre"], "head_centre") if "head_centre" in doc else None
    clapper = _clapper(doc, col)
    eye_offset = _vector(doc, "eye_offset_mm", 3, col)
    segments = _segments(doc, col)
    _off_subject(segments, root, head_centre, target, clapper, col)
    lod = _lod(doc, col, [s.name for s in segments])
    rotation = _camera(doc, col)

    if col.errors:
        return None, col.errors
    assert up_axis is not None and root is not None
    return MarkerSet(path=str(path), up_axis=up_axis.strip().lower(), units=units.strip().lower(), root=root,
                     target=target, clapper=clapper, segments=tuple(segments), head_centre=head_centre,
                     eye_offset_mm=eye_offset, lod_segments=lod, camera_rotation=rotation), []  # type: ignore[arg-type]


def _axis_and_units(doc: dict, col: Collector) -> tuple[str | None, str]:
    """``up_axis`` (None when missing or not y or z) and ``units`` (default mm)."""
    up_axis = col.string(doc, "up_axis", "up_axis", required=True)
    if up_axis is not None and up_axis.strip().lower() not in ("y", "z"):
        col.add("up_axis", f"must be \"y\" or \"z\", got {show(up_axis)}")
        up_axis = None
    units = col.string(doc, "units", "units") or "mm"
    try:
        unit_scale_to_mm(units)
    except KeyError:
        col.add("units", f"unknown units {show(units)} (expected mm, cm, m, dm or in)")
    return up_axis, units


def _clapper(doc: dict, col: Collector) -> tuple[str, ...]:
    """The two clapper markers (none when absent or wrong)."""
    if "clapper" not in doc:
        return ()
    value = doc["clapper"]
    if not isinstance(value, list) or len(value) != 2:
        col.add("clapper", f"must be an array of two marker names, got {show(value)}")
        return ()
    names = [col.marker_name(v, f"clapper[{i}]") for i, v in enumerate(value)]
    if None in names:
        return ()
    if names[0] == names[1]:
        col.add("clapper", f"the two clapper markers are the same ({names[0]!r})")
        return ()
    return tuple(names)  # type: ignore[arg-type]


def _off_subject(segments: list[Segment], root: str | None, head_centre: str | None, target: str | None,
                 clapper: tuple[str, ...], col: Collector) -> None:
    """The target and the clapper are not on the subject: they must not share a name with its markers."""
    seen: dict[str, str] = {}
    for s in segments:
        for m in s.markers:
            seen.setdefault(m, f"on segment {s.name!r}")
    if root is not None:
        seen.setdefault(root, "the root marker")
    if head_centre is not None:
        seen.setdefault(head_centre, "the head centre")
    for name, key in ((target, "target"), *((c, f"clapper[{i}]") for i, c in enumerate(clapper))):
        if name is not None and name in seen:
            col.add(key, f"marker {name!r} is also {seen[name]}")
    if target is not None and target in clapper:
        col.add("target", f"marker {target!r} is also a clapper marker")


def _lod(doc: dict, col: Collector, seg_names: list[str]) -> tuple[str, ...]:
    """The ``[lod]`` table's segments (none when absent)."""
    if "lod" not in doc or (table := col.table(doc["lod"], "lod")) is None:
        return ()
    col.unknown_keys(table, ("segments",), "lod.")
    value = table.get("segments", [])
    if not isinstance(value, list):
        col.add("lod.segments", f"must be an array of segment names, got {type_name(value)}")
        return ()
    lod_names: list[str] = []
    for i, v in enumerate(value):
        if not isinstance(v, str) or v not in seg_names:
            col.add(f"lod.segments[{i}]", f"{show(v)} is not a segment{suggest(str(v), seg_names)}")
        elif v in lod_names:
            col.add(f"lod.segments[{i}]", f"segment {v!r} listed twice")
        else:
            lod_names.append(v)
    return tuple(lod_names)


def _camera(doc: dict, col: Collector) -> tuple[float, ...] | None:
    """The ``[camera]`` table's rotation, a unit quaternion (w, x, y, z); None when absent."""
    if "camera" not in doc or (table := col.table(doc["camera"], "camera")) is None:
        return None
    col.unknown_keys(table, ("rotation",), "camera.")
    q = _vector(table, "rotation", 4, col, prefix="camera.")
    if q is None:
        return None
    norm = math.sqrt(sum(c * c for c in q))
    if abs(norm - 1.0) > 1e-3:
        col.add("camera.rotation", f"not a unit quaternion (w, x, y, z): norm {norm:.6g}")
        return None
    return tuple(c / norm for c in q)


def _vector(table: dict, name: str, n: int, col: Collector, prefix: str = "") -> tuple[float, ...] | None:
    if name not in table:
        return None
    value = table[name]
    if not isinstance(value, list) or len(value) != n or not all(is_number(v) for v in value):
        col.add(f"{prefix}{name}", f"must be an array of {n} finite numbers, got {show(value)}")
        return None
    return tuple(float(v) for v in value)


def _segments(doc: dict, col: Collector) -> list[Segment]:
    """The ``[segments.*]`` tables in file order; reports every structural problem."""
    if "segments" not in doc:
        col.add("segments", "missing (at least the root segment is required)")
        return []
    table = col.table(doc["segments"], "segments")
    if table is None:
        return []
    if not table:
        col.add("segments", "no segments defined")
        return []
    order = list(table)
    parents: dict[str, Any] = {}
    segments: list[Segment] = []
    owner: dict[str, str] = {}
    bad_parent: set[str] = set()
    for name in order:
        key = f"segments.{key_name(name)}"
        seg = col.table(table[name], key)
        if seg is None:
            continue
        col.unknown_keys(seg, ("markers", "parent"), f"{key}.")
        markers = _segment_markers(seg.get("markers"), key, name, owner, col)
        parent = seg.get("parent")
        if parent is not None and not isinstance(parent, str):
            col.add(f"{key}.parent", f"must be a segment name (string), got {type_name(parent)}")
            bad_parent.add(name)
            parent = None
        parents[name] = parent
        segments.append(Segment(name=str(name), markers=tuple(markers), parent=parent))
    _check_parents(order, parents, bad_parent, col)
    return segments


def _segment_markers(value: Any, key: str, name: str, owner: dict[str, str], col: Collector) -> list[str]:
    """Segment ``name``'s markers (its ``markers`` array, at ``key``), each on no other segment (``owner``:
    the segment each marker is on so far, updated)."""
    markers: list[str] = []
    if value is None:
        col.add(f"{key}.markers", "missing (three or more marker names)")
        return markers
    if not isinstance(value, list):
        col.add(f"{key}.markers", f"must be an array of marker names, got {type_name(value)}")
        return markers
    for i, v in enumerate(value):
        m = col.marker_name(v, f"{key}.markers[{i}]")
        if m is None:
            continue
        if m in markers:
            col.add(f"{key}.markers[{i}]", f"marker {m!r} listed twice")
        elif m in owner:
            col.add(f"{key}.markers[{i}]", f"marker {m!r} is already on segment {owner[m]!r}")
        else:
            markers.append(m)
            owner[m] = name
    if len(value) < 3:
        col.add(f"{key}.markers", f"a segment needs at least 3 markers, got {len(value)}")
    return markers


def _check_parents(order: list[str], parents: dict[str, Any], bad_parent: set[str], col: Collector) -> None:
    """One root; every parent a known segment listed before its child; no cycle (each reported once)."""
    roots = [n for n in parents if parents[n] is None and n not in bad_parent]
    for extra in roots[1:]:
        col.add(f"segments.{key_name(extra)}.parent",
                f"missing: only one segment may lack a parent (the root is {roots[0]!r})")
    reported_cycle: set[str] = set()
    for idx, name in enumerate(order):
        parent = parents.get(name)
        if parent is None or name not in parents:
            continue
        key = f"segments.{key_name(name)}.parent"
        if parent not in order:
            col.add(key, f"unknown parent {parent!r}{suggest(parent, order)}")
            continue
        # walk up the chain: a cycle returns to this segment
        chain, cur = [name], parent
        while cur is not None and cur not in chain and cur in parents:
            chain.append(cur)
            cur = parents[cur]
        if cur == name:
            if name not in reported_cycle:
                col.add(key, "parent cycle: " + " -> ".join([*chain, name]))
                reported_cycle.update(chain)
        elif cur is None and order.index(parent) > idx:
            col.add(key, f"parent {parent!r} comes after {name!r}: list segments from the root to the head")
