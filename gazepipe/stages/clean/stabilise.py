"""Root stabilisation (SPEC §3.2 step 3): every frame translated so the root marker sits at the lab origin,
optionally turned about the lab vertical to remove the heading. Positions are (T, M, 3) mm on lab axes.
"""

from __future__ import annotations

import numpy as np

from gazepipe.stages.geometry import cross3

#: frames rotated at a time by the heading removal: its temporaries (rotation matrices, rotated points) stay
#: within a block, not the take
_BLOCK_FRAMES = 8192


def stabilise(xyz: np.ndarray, root: int, up: np.ndarray | None = None,
              left_pair: tuple[int, int] | None = None, *, in_place: bool = False) -> np.ndarray:
    """Translate every frame so marker ``root`` is at the origin; frames where it is NaN become all NaN.

    With ``up`` and ``left_pair`` (the root segment's first and second marker), also rotate each frame about
    ``up`` so the horizontal part of (first − second) points along lab +X (frames where that is undefined
    become NaN). With ``in_place`` (``xyz`` a float64 array the caller owns) the result is written into ``xyz``
    and returned; otherwise ``xyz`` is left as it was.
    """
    out = xyz if in_place else xyz.copy()
    out -= out[:, root : root + 1, :].copy()
    if up is None or left_pair is None:
        return out
    from scipy.spatial.transform import Rotation

    left = out[:, left_pair[0]] - out[:, left_pair[1]]
    left = left - (left @ up)[:, None] * up
    ex = np.zeros(3)
    ex[int(np.argmax(np.abs(up) < 0.5))] = 1.0  # lab X (or Y when X is vertical)
    ey = cross3(up, ex)
    ang = np.arctan2(left @ ey, left @ ex)           # heading of "left" about up, from ex
    ok = np.isfinite(ang) & (np.linalg.norm(left, axis=1) > 1e-9)
    out[~ok] = np.nan
    for lo in range(0, len(out), _BLOCK_FRAMES):
        rows = lo + np.flatnonzero(ok[lo:lo + _BLOCK_FRAMES])
        if rows.size:
            rot = Rotation.from_rotvec(-ang[rows, None] * up[None, :])
            out[rows] = out[rows] @ np.swapaxes(rot.as_matrix(), 1, 2)  # R · p for every point, as row vectors
    return out
