"""The synthetic subject: segments, joints, marker offsets, lab placement and head camera.

Every offset here is in the *character* axes of the neutral pose (X the character's left, Y up, Z forward),
millimetres, relative to the subject's floor point (between the feet, or below the seat when sitting).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.spatial.transform import Rotation

#: segment names, root first; each segment's parent is the previous one (Klein's 10 central segments)
SEGMENTS: tuple[str, ...] = (
    "pelvis", "spine1", "spine2", "spine3", "spine4", "chest", "neck1", "neck2", "neck3", "head",
)

#: joint position of each segment in the neutral standing pose, character axes, mm above the floor point
JOINTS_MM: np.ndarray = np.array([
    [0.0, 1000.0, 0.0],     # pelvis
    [0.0, 1080.0, -10.0],   # spine1
    [0.0, 1160.0, -15.0],   # spine2
    [0.0, 1240.0, -15.0],   # spine3
    [0.0, 1320.0, -10.0],   # spine4
    [0.0, 1400.0, 0.0],     # chest
    [0.0, 1480.0, 5.0],     # neck1
    [0.0, 1520.0, 12.0],    # neck2
    [0.0, 1560.0, 20.0],    # neck3
    [0.0, 1610.0, 25.0],    # head
])

ROOT_MARKER = "SACR"
TARGET_MARKER = "POLE"
CLAPPER_MARKERS = ("CLAP1", "CLAP2")
HEAD_CENTRE_MARKER = "HEADC"

#: half the distance between the eyes, mm (each eye sits at HEADC ± this along the head's X axis)
HALF_IPD_MM = 32.0


def _tri(a: float, b: float, h: float, z: float, dz: float = -5.0) -> list[tuple[float, float, float]]:
    """A triangle on the back: two markers ``a`` mm left/right (``b`` is their height) and one ``h`` above."""
    return [(a, b, z), (-a, b, z), (0.0, b + h, z + dz)]


#: markers of each segment, relative to that segment's joint (character axes, neutral pose, mm)
SEGMENT_MARKERS: dict[str, dict[str, tuple[float, float, float]]] = {
    "pelvis": {"PEL_L": (130.0, 50.0, 40.0), "PEL_R": (-130.0, 50.0, 40.0), "PEL_B": (0.0, 70.0, -105.0)},
    "spine1": dict(zip(("SP1A", "SP1B", "SP1C"), _tri(40.0, 0.0, 60.0, -125.0), strict=True)),
    "spine2": dict(zip(("SP2A", "SP2B", "SP2C"), _tri(45.0, -5.0, 55.0, -130.0), strict=True)),
    "spine3": dict(zip(("SP3A", "SP3B", "SP3C"), _tri(42.0, 0.0, 62.0, -135.0), strict=True)),
    "spine4": dict(zip(("SP4A", "SP4B", "SP4C"), _tri(48.0, -5.0, 58.0, -135.0), strict=True)),
    "chest": {"CHA": (55.0, 0.0, -135.0), "CHB": (-55.0, 0.0, -135.0), "CHC": (0.0, 65.0, -140.0),
              "CHD": (20.0, -45.0, -132.0)},
    "neck1": dict(zip(("NK1A", "NK1B", "NK1C"), _tri(33.0, 0.0, 52.0, -85.0), strict=True)),
    "neck2": dict(zip(("NK2A", "NK2B", "NK2C"), _tri(31.0, 0.0, 55.0, -80.0), strict=True)),
    "neck3": dict(zip(("NK3A", "NK3B", "NK3C"), _tri(32.0, 0.0, 54.0, -75.0), strict=True)),
    "head": {"HFL": (75.0, 130.0, 60.0), "HFR": (-75.0, 130.0, 60.0), "HBL": (75.0, 130.0, -80.0),
             "HBR": (-75.0, 130.0, -80.0), "HTOP": (0.0, 195.0, -10.0)},
}

#: rigid extra markers: (segment, offset from its joint)
EXTRA_MARKERS: dict[str, tuple[str, tuple[float, float, float]]] = {
    ROOT_MARKER: ("pelvis", (0.0, 20.0, -115.0)),
    HEAD_CENTRE_MARKER: ("head", (0.0, 50.0, 95.0)),   # between the eyes
}


#: markers a capture may carry that no markerset segment lists (``SynthConfig.unlisted_markers``), as offsets
#: from the chest joint (character axes, neutral pose, mm): the acromions (shoulders, 340 mm apart), which ride
#: on the chest plus the shoulder blade's own shrugging and reaching, and the lateral epicondyles (elbows), at
#: the end of an upper arm that swings about the shoulder joint: rigid with no segment
UNLISTED_MARKERS: dict[str, tuple[float, float, float]] = {
    "LSHO": (170.0, 60.0, -25.0), "RSHO": (-170.0, 60.0, -25.0),
    "LELB": (205.0, -275.0, -40.0), "RELB": (-205.0, -275.0, -40.0),
}
#: the sets of unlisted markers the generator's command line offers, by name
UNLISTED_SETS: dict[str, tuple[str, ...]] = {"shoulders": ("LSHO", "RSHO"), "arms": ("LSHO", "RSHO", "LELB", "RELB")}
#: each elbow's shoulder marker (the arm hangs from that shoulder's joint)
ELBOW_SHOULDER: dict[str, str] = {"LELB": "LSHO", "RELB": "RSHO"}
#: the shoulder joint (the upper arm's centre of rotation) relative to its acromion marker, chest axes, mm
SHOULDER_JOINT_BELOW_MM: tuple[float, float, float] = (0.0, -45.0, 0.0)


def head_centre_offset() -> np.ndarray:
    """HEADC relative to the head joint, (3,) mm, head axes."""
    return np.array(EXTRA_MARKERS[HEAD_CENTRE_MARKER][1])


def eye_offset_mm() -> np.ndarray:
    """The eyes' centre relative to the head markers' centroid, head axes (X left, Y up, Z forward), mm."""
    hat = np.array(list(SEGMENT_MARKERS["head"].values()))
    return head_centre_offset() - hat.mean(axis=0)


#: a coarser marker layout: markers on four of the chain's segments only (the others move, unseen)
FOUR_SEGMENTS: tuple[str, ...] = ("pelvis", "chest", "neck2", "head")


def subject_marker_layout(segments: tuple[str, ...] = SEGMENTS) -> tuple[list[str], np.ndarray, np.ndarray]:
    """Labels, owning segment index (M,) and offset from that segment's joint (M, 3) of every subject marker
    on ``segments`` (a subset of :data:`SEGMENTS` with the pelvis and the head).

    Order: the root marker, each segment's markers from the root to the head, then the head centre.
    """
    labels: list[str] = [ROOT_MARKER]
    seg = [0]
    off = [EXTRA_MARKERS[ROOT_MARKER][1]]
    for k, name in enumerate(SEGMENTS):
        if name not in segments:
            continue
        for lab, o in SEGMENT_MARKERS[name].items():
            labels.append(lab)
            seg.append(k)
            off.append(o)
    labels.append(HEAD_CENTRE_MARKER)
    seg.append(SEGMENTS.index("head"))
    off.append(EXTRA_MARKERS[HEAD_CENTRE_MARKER][1])
    return labels, np.array(seg, dtype=np.int64), np.array(off, dtype=np.float64)


@dataclass(frozen=True)
class Placement:
    """Where the subject stands in the lab (lab frame: Z up, mm).

    ``heading_deg``: the character's forward is the lab +Y axis turned by this angle about lab +Z.
    """

    floor_mm: tuple[float, float, float] = (1500.0, -700.0, 0.0)
    heading_deg: float = 35.0

    @property
    def h_lab(self) -> Rotation:
        """Rotation from character axes to lab axes at the neutral stance (v_lab = H · v_char)."""
        a = np.deg2rad(self.heading_deg)
        fwd = np.array([-np.sin(a), np.cos(a), 0.0])
        up = np.array([0.0, 0.0, 1.0])
        left = np.cross(up, fwd)
        return Rotation.from_matrix(np.column_stack([left, up, fwd]))


def camera_to_head(tilt_up_deg: float = 20.0, yaw_deg: float = 5.0) -> Rotation:
    """True rotation from the head camera's axes (x right, y down, z forward) to the head axes.

    The camera sits below and in front of the face, looking back at it (its z axis ≈ head −Z), tilted up by
    ``tilt_up_deg`` and turned by ``yaw_deg`` about the head's Y axis.
    """
    base = Rotation.from_matrix(np.diag([1.0, -1.0, -1.0]))
    return (Rotation.from_euler("y", yaw_deg, degrees=True) * Rotation.from_euler("x", tilt_up_deg, degrees=True)
            * base)


#: rotation limits and how the body shares a gaze change while following a target, per pose (degrees; shares
#: of the body's part, root to head: decreasing down the chain; sitting keeps the pelvis still)
POSE_PROFILES: dict[str, dict[str, object]] = {
    "standing": {"floor_drop_mm": 0.0, "body_yaw_max": 130.0, "body_pitch_max": 40.0,
                 "yaw_share": (0.03, 0.04, 0.05, 0.06, 0.07, 0.08, 0.08, 0.09, 0.10, 0.40)},
    "sitting": {"floor_drop_mm": 450.0, "body_yaw_max": 85.0, "body_pitch_max": 35.0,
                "yaw_share": (0.0, 0.02, 0.02, 0.03, 0.03, 0.05, 0.09, 0.10, 0.10, 0.56)},
}
