"""Root stabilisation (SPEC §3.2 step 3): every frame translated so the root marker sits at the lab origin,
optionally turned about the lab vertical to remove the heading. Positions are (T, M, 3) mm on lab axes.
"""

from __future__ import annotations

import numpy as np

from gazepipe.stages.geometry import cross3


def stabilise(xyz: np.ndarray, root: int, up: np.ndarray | None = None,
              left_pair: tuple[int, int] | None = None) -> np.ndarray:
    """Translate every frame so marker ``root`` is at the origin; frames where it is NaN become all NaN.

    With ``up`` and ``left_pair`` (the root segment's first and second marker), also rotate each frame about
    ``up`` so the horizontal part of (first − second) points along lab +X (frames where that is undefined
    become NaN).
    """
    out = xyz - xyz[:, root : root + 1, :]
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
    res = np.full_like(out, np.nan)
    if ok.any():
        rot = Rotation.from_rotvec(-ang[ok, None] * up[None, :])
        pts = out[ok]
        res[ok] = pts @ np.swapaxes(rot.as_matrix(), 1, 2)  # R · p for every point, as row vectors
    return res
