"""Take-disjoint train / val / test splits (SPEC §3.6).

A take's ``split`` in session.toml pins it; otherwise the split follows from a hash of the take's qualified id
``<session>/<take>`` alone, so a take keeps its split when other takes are added or removed, and every dataset
puts it in the same split. The session is part of the key because sessions of different subjects usually reuse
the same take ids (``follow_standing_01``): hashing the bare id would send that take of every subject to one
split, and with a handful of distinct ids leave val or test empty.
"""

from __future__ import annotations

import hashlib

from gazepipe.errors import ConfigError
from gazepipe.model import SPLITS


def hash_unit(key: str, salt: str = "") -> float:
    """A deterministic number in [0, 1) from ``key`` (first 8 bytes of sha256(salt + key), big-endian)."""
    digest = hashlib.sha256(f"{salt}{key}".encode()).digest()
    return int.from_bytes(digest[:8], "big") / 2.0**64


def check_fractions(train: float, val: float) -> None:
    """Raise :class:`ConfigError` unless 0 ≤ train, 0 ≤ val and train + val ≤ 1."""
    if not (0.0 <= train and 0.0 <= val and train + val <= 1.0):
        raise ConfigError(None, f"split fractions train={train}, val={val} must be >= 0 with train + val <= 1",
                          key="build.train_frac")


def assign_split(key: str, pinned: str | None, train: float = 0.8, val: float = 0.1, salt: str = "") -> str:
    """The split of one take: ``pinned`` when given, else by :func:`hash_unit` of ``key`` (the take's
    ``<session>/<take>``): train below ``train``, val below ``train + val``, test above."""
    if pinned is not None:
        if pinned not in SPLITS:
            raise ConfigError(None, f"split {pinned!r} is not one of {', '.join(SPLITS)}", take=key)
        return pinned
    u = hash_unit(key, salt)
    if u < train:
        return "train"
    if u < train + val:
        return "val"
    return "test"


def rebalance(takes: list[tuple[str, str, bool]], train: float = 0.8, val: float = 0.1,
              salt: str = "") -> list[tuple[str, str, str, str]]:
    """The moves that keep a dataset's splits from emptying (SPEC §3.6), as ``(take, from, to, why)``.

    ``takes`` are the takes that gave rows: ``(key, split, pinned)`` with ``key`` the ``<session>/<take>`` of
    :func:`assign_split`. The train split is never empty while an unpinned take exists; with three or more
    takes an empty val split takes one (a trainer then has something to validate on), with five or more an empty
    test split too. A take moves only to fill a split that would otherwise be empty, and
    only out of a split that keeps at least one take; of those that may move, the one whose hash lies nearest
    the empty split's share of [0, 1) moves (ties by key), so the choice is as deterministic as the hash.
    """
    split = {k: s for k, s, _ in takes}
    pinned = {k for k, _, p in takes if p}
    bounds = {"train": (0.0, train), "val": (train, train + val), "test": (train + val, 1.0)}
    moves: list[tuple[str, str, str, str]] = []

    def fill(target: str, why: str) -> None:
        counts = {s: sum(v == s for v in split.values()) for s in SPLITS}
        if counts[target]:
            return
        movable = [k for k in split if k not in pinned and counts[split[k]] >= 2 - (target == "train")]
        if not movable:
            return
        lo, hi = bounds[target]

        def distance(k: str) -> tuple[float, str]:
            u = hash_unit(k, salt)
            return (0.0 if lo <= u < hi else min(abs(u - lo), abs(u - hi)), k)

        k = min(movable, key=distance)
        moves.append((k, split[k], target, why))
        split[k] = target

    fill("train", "the train split would be empty (statistics need a training take)")
    if len(takes) >= 3:
        fill("val", f"the val split would be empty with {len(takes)} takes")
    if len(takes) >= 5:
        fill("test", f"the test split would be empty with {len(takes)} takes")
    return moves
