"""Small capture files and a synthetic marker body, shared by the reader and gap-filler tests.

- ``VICON``, ``QTM``, ``QTM_OLD``: Vicon Nexus CSV and Qualisys TSV exports as text (the marker-file readers'
  fixtures, also cut up by the ragged-row tests);
- :func:`body` and :func:`hide`: three rigid 4-marker segments on a walking, turning trunk, and gaps punched in
  them (the gap filler's tests and its locality tests).
"""

from __future__ import annotations

import numpy as np
from scipy.spatial.transform import Rotation

# A Nexus 2.x export with a Devices block before the trajectories and a Model Outputs block after them.
VICON = """Devices
1000
,,Imported AMTI OR6 Series Force Plate #1 - Force,,
Frame,Sub Frame,Fx,Fy,Fz
,,N,N,N
1,0,0.1,0.2,0.3

Trajectories
100
,,Ann:LASI,,,Ann:RASI,,,Ann:HEADC,,
Frame,Sub Frame,X,Y,Z,X,Y,Z,X,Y,Z
,,mm,mm,mm,mm,mm,mm,mm,mm,mm
12,0,101.5,-20.25,950,,,,0,0,1600
13,0,102.5,-20.5,951,230.125,25,948.5,0.5,0,1601
14,0,103.5,-20.75,952,231.125,25.5,949,1,0,1602

Model Outputs
100
,,Ann:LHipAngles,,
Frame,Sub Frame,X,Y,Z
,,deg,deg,deg
12,0,1,2,3
"""

# QTM 2019 3D export: header keys, a Frame/Time column row, empty cells and 0.000 for missing markers.
QTM = """NO_OF_FRAMES\t3
NO_OF_CAMERAS\t8
NO_OF_MARKERS\t2
FREQUENCY\t120
NO_OF_ANALOG\t0
ANALOG_FREQUENCY\t0
DESCRIPTION\t--
TIME_STAMP\t2019-11-28, 13:43:42.715\t1476252.89504471
DATA_INCLUDED\t3D
MARKER_NAMES\tHFL\tHFR
TRAJECTORY_TYPES\tMeasured\tMeasured
Frame\tTime\tHFL X\tHFL Y\tHFL Z\tHFR X\tHFR Y\tHFR Z
1\t0.00000\t10.000\t20.000\t1700.000\t0.000\t0.000\t0.000
2\t0.00833\t10.500\t20.500\t1700.500\t60.000\t20.000\t1699.000
3\t0.01667\t\t\t\t61.000\t21.000\t1698.000
"""

# Older QTM export: no Frame/Time row, data rows carry only the coordinates.
QTM_OLD = """NO_OF_FRAMES\t2
NO_OF_CAMERAS\t6
NO_OF_MARKERS\t1
FREQUENCY\t100
NO_OF_ANALOG\t0
ANALOG_FREQUENCY\t0
DESCRIPTION\t--
TIME_STAMP\t2006-03-07, 11:12:03
DATA_INCLUDED\t3D
MARKER_NAMES\tTOP
1.5\t2.5\t3.5
1.25\t2.25\t3.25
"""


# ---------------------------------------------------------------------------------- a synthetic marker body

RATE = 60.0
NOISE = 0.5


def body(n_t: int = 600, seed: int = 0, noise: float = NOISE) -> tuple[np.ndarray, np.ndarray, list[list[int]]]:
    """Three rigid 4-marker segments on a walking, turning trunk: (truth, measured, clusters).

    Segment 0 is the trunk; segments 1 and 2 hang from it and swing about their own joints, so markers are
    intercorrelated (PCA has something to learn) but only segment mates are rigid together.
    """
    rng = np.random.default_rng(seed)
    t = np.arange(n_t) / RATE
    root = np.stack([400 * np.sin(2 * np.pi * 0.15 * t), 100 * np.sin(2 * np.pi * 0.3 * t),
                     1000 + 20 * np.sin(2 * np.pi * 0.5 * t)], axis=1)
    trunk = Rotation.from_euler("zxy", np.stack([0.6 * np.sin(2 * np.pi * 0.2 * t), 0.1 * np.sin(2 * np.pi * 0.4 * t),
                                                 0.1 * np.cos(2 * np.pi * 0.3 * t)], axis=1))
    shapes = [rng.normal(0, 70, (4, 3)) for _ in range(3)]
    joints = [np.zeros(3), np.array([150.0, 0, -200]), np.array([-150.0, 0, -200])]
    parts = [np.stack([trunk.apply(p) for p in shapes[0]], axis=1)]
    for k in (1, 2):
        swing = Rotation.from_euler("x", 0.5 * np.sin(2 * np.pi * 0.8 * t + k)[:, None])
        rot = trunk * swing
        parts.append(trunk.apply(joints[k])[:, None, :]
                     + np.stack([rot.apply(p + np.array([0, 0, -150.0])) for p in shapes[k]], axis=1))
    truth = np.concatenate(parts, axis=1) + root[:, None, :]
    measured = truth + rng.normal(0, noise, truth.shape)
    return truth, measured, [[0, 1, 2, 3], [4, 5, 6, 7], [8, 9, 10, 11]]


def hide(measured: np.ndarray, gaps: list[tuple[int, int, int]]) -> tuple[np.ndarray, np.ndarray]:
    valid = np.ones(measured.shape[:2], bool)
    for m, s, e in gaps:
        valid[s:e, m] = False
    return np.where(valid[..., None], measured, np.nan), valid
