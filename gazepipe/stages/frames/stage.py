"""The ``frames`` stage (SPEC §2, §3.3, Pejsa 5.2.2.2): segment orientations in the character frame.

Per frame: the character frame (origin the root marker; +X left = horizontal part of the root segment's first
minus second marker, +Y the lab vertical, +Z forward = left × up), each segment's orientation from its markers
(a least-squares rigid fit to the neutral cluster, or Gram–Schmidt on a triangle) calibrated so that the
neutral pose is the identity, parent-relative rotations, the 6-number form, the eyes'
centre and the unit direction from it to the target. Pure functions; no file I/O.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field, replace

import numpy as np

from gazepipe.errors import StageError
from gazepipe.model import Markers, MarkerSet
from gazepipe.stages.frames.continuity import JumpRule, flips
from gazepipe.stages.frames.rotfill import SegmentMarkers, fill_rotation_gaps
from gazepipe.stages.geometry import (
    frame_from_points,
    heading_frames,
    mean_wxyz,
    six_from_matrix,
    up_vector,
)


@dataclass(frozen=True)
class FramesParams:
    """Parameters of :func:`compute_frames`.

    Attributes
    ----------
    min_neutral_frames : fewest neutral frames (with every marker of a segment and a character frame) needed to
        calibrate a segment; fewer is a stage failure.
    head_segment : name of the head segment (for ``eye_offset_mm``); ``None`` = the segment named ``head``,
        else the last segment of the chain.
    triangle : marker frame of a three-marker segment: ``rigid_fit`` (default; the least-squares rigid fit to
        the neutral cluster, as for larger clusters) or ``gram_schmidt`` (centroid, one edge, the plane normal).
        After neutral calibration both estimate the same rotation; the rigid fit weighs all three markers
        alike and is ~10 % less noisy (0.9° vs 1.05° median error on the sample session's 62 mm neck
        triangles with 0.5 mm noise).
    max_fill_error_deg : a segment whose markers stay unfilled gets its parent-relative rotation filled across
        the gap (:func:`fill_rotation_gaps`: slerp between the rotations on either side, or a model of its
        neighbours' rotations) when the hold-out estimate of that fill's error, on stretches of the gap's length
        beside it and on stretches that move like it, is at most this many degrees; 0 turns it off.
    max_fit_uncertainty_deg : a rotation fitted to gap-filled markers whose estimated fill errors may turn it by
        more than this (RMS, :func:`fit_uncertainty_deg`) is unsure and treated as a gap of its markers (with
        ``fill_error_mm`` given to :func:`compute_frames`; it may then be filled across by the rotation fill);
        0 turns it off. The propagation takes the fills' errors as independent, and fills of a cluster made
        together move it together, so it overstates them there: ``bench/bench_datasets_truth.py`` (both
        layouts, every hazard) has rotations estimated 2–3° off on three filled neck markers at 1.1° from the
        truth (median), none beyond 3°, and those estimated 4° on a chest of three markers filled by three
        methods at up to 5.3°.
    min_plane_ratio : a segment of more than three markers with some missing in a frame is fitted to the
        markers present when there are at least three and their neutral reference is not nearly collinear:
        the second singular value of the centred reference subset must be at least this share of the first
        (the rotation about a line through the markers is undetermined when it is 0; at 0.2 it is still
        known to within a few times the noise of a full cluster).
    jump_factor : how far a step from one frame to the next must depart from the local angular velocity (the
        running median of the steps over 0.25 s each side), in typical departures there, to be a jump; a segment's
        rotation (from its markers) or the character frame's heading that jumps away and back within
        ``max_flip_s`` is a flip, and those frames are a gap of the segment's markers (the rotation fill may then
        fill them) or frames without a character frame (:func:`gazepipe.stages.frames.continuity.flips`). A jump
        comes back when the rotation after it is where the measured speed would take the rotation before it. A
        missed 35 mm ghost on one of four chest markers turned the chest 14° for two frames; a left/right name
        exchange on the head with its other markers gone flipped it 180° for 0.6 s. 0 turns flips off.
    min_jump_deg : the smallest departure from the local angular velocity, in degrees, that is a jump (see
        ``jump_factor``).
    max_flip_s : the longest a rotation may stay away, in seconds, between a jump and its way back, for the
        stretch to be a flip (see ``jump_factor``).
    Each field's metadata gives its allowed values (:func:`gazepipe.pipeline.registry.value_problem`) and its one
    line of help (``help``: what ``gazepipe params`` prints).
    """

    min_neutral_frames: int = field(default=3, metadata={
        "min": 1, "help": "fewest neutral-pose frames needed to calibrate a segment"})
    head_segment: str | None = field(default=None, metadata={
        "help": "the head segment, which carries the eyes (default: the one named head, else the last)"})
    triangle: str = field(default="rigid_fit", metadata={
        "choices": ("rigid_fit", "gram_schmidt"), "help": "how a three-marker segment's frame is built: "
            "rigid_fit or gram_schmidt"})
    min_plane_ratio: float = field(default=0.2, metadata={
        "min": 0, "max": 1, "help": "fit a segment to some of its markers only when they are not nearly in "
            "a line"})
    max_fill_error_deg: float = field(default=2.0, metadata={
        "min": 0, "help": "fill a segment's rotation across a marker gap when its estimated error is at "
            "most this, in degrees (0: off)"})
    max_fit_uncertainty_deg: float = field(default=3.0, metadata={
        "min": 0, "help": "a rotation fitted to filled markers more uncertain than this (degrees) is "
            "treated as a gap (0: never)"})
    jump_factor: float = field(default=4.0, metadata={
        "min": 0, "help": "a step this many typical departures off the angular velocity is a jump (0: no "
            "flips)"})
    min_jump_deg: float = field(default=3.0, metadata={
        "min": 0, "help": "the smallest departure from a segment's angular velocity that is a jump "
            "(degrees)"})
    max_flip_s: float = field(default=2.0, metadata={
        "min": 0, "help": "the longest a rotation may stay away between a jump and its return to be a flip "
            "(s)"})


@dataclass
class Joints:
    """Per-frame segment orientations of one take (output of :func:`compute_frames`).

    Attributes
    ----------
    segments : segment names, root of the chain first (markerset order).
    parents : (S,) index of each segment's parent in ``segments`` (−1 for a root).
    quat : (N, S, 4) w, x, y, z global rotation of each segment in the character frame (identity in neutral).
    quat_local : (N, S, 4) w, x, y, z parent-relative rotation (parent⁻¹ · global; global for a root).
    six : (N, S, 6) 6-number form of ``quat``: forward R·ẑ, then up R·ŷ.
    head_centre : (N, 3) mm, eyes' centre in the character frame.
    target_dir : (N, 3) unit vector from the head centre to the target marker, character frame (NaN where
        the target is unfilled or the markerset has none).
    char_origin : (N, 3) mm, the character frame's origin (the root marker) in lab coordinates.
    char_rot : (N, 4) w, x, y, z lab-from-character rotation.
    valid : (N,) bool, True where the character frame and every segment are defined.
    rot_filled : (N, S) bool, segment rotations filled across a gap of its markers (not measured).
    rot_measured : (N, S) bool, segment rotations from measured marker samples only: every marker of the
        segment measured (not gap-filled) and the rotation not filled.
    rest_before : the still pose just before the first frame when the rest before it was given
        (:func:`rest_pose`: ``quat`` per segment, ``char_rot``, each a mean over its last frames; a segment's
        from its measured rotations (``rot_measured``) only, None where the rest has none), else None.
    rate_hz, first_frame : as in the input :class:`~gazepipe.model.Markers` (source frame of row 0).
    qc : JSON-ready record (neutral frames used per segment, invalid frames, warnings).
    All arrays are float64 and NaN where undefined.
    """

    segments: list[str]
    parents: np.ndarray
    quat: np.ndarray
    quat_local: np.ndarray
    six: np.ndarray
    head_centre: np.ndarray
    target_dir: np.ndarray
    char_origin: np.ndarray
    char_rot: np.ndarray
    valid: np.ndarray
    rate_hz: float
    first_frame: int = 1
    qc: dict = field(default_factory=dict)
    rot_filled: np.ndarray | None = None
    rest_before: dict | None = None
    rot_measured: np.ndarray | None = None

    @property
    def n_frames(self) -> int:
        return int(self.quat.shape[0])

    @property
    def source_frame(self) -> np.ndarray:
        return self.first_frame + np.arange(self.n_frames, dtype=np.int64)


def _col(markers: Markers, name: str, path: str | None, take: str | None, what: str) -> np.ndarray:
    try:
        return markers.xyz[:, markers.index(name)]
    except KeyError:
        raise StageError(path, f"{what} marker {name!r} is not in the capture", take=take) from None


def character_frame(markers: Markers, markerset: MarkerSet, *, path: str | None = None,
                    take: str | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Origin (T, 3) mm and lab-from-character matrices (T, 3, 3) per frame (NaN where undefined, SPEC §2)."""
    rs = markerset.root_segment
    if len(rs.markers) < 2:
        raise StageError(path, f"root segment {rs.name!r} needs at least two markers for the heading", take=take)
    origin = _col(markers, markerset.root, path, take, "root")
    left = _col(markers, rs.markers[0], path, take, "root segment") - _col(markers, rs.markers[1], path, take,
                                                                             "root segment")
    return origin, heading_frames(left, up_vector(markerset.up_axis))


def root_reference(sources: Sequence[tuple[str, Markers]], markerset: MarkerSet,
                   min_frames: int) -> np.ndarray | None:
    """The neutral geometry of the root marker and the root segment's markers (K, 3), character coordinates: their
    mean over the first neutral source's frames where all of them are measured (at least ``min_frames``);
    ``None`` when no source has that many."""
    names = [markerset.root, *markerset.root_segment.markers]
    for _, neutral in sources:
        if any(n not in neutral.labels for n in names):
            continue
        origin, cmat = character_frame(neutral, markerset)
        pts = np.stack([neutral.xyz[:, neutral.index(n)] for n in names], axis=1)
        ok = np.isfinite(pts).all(axis=(1, 2)) & np.isfinite(cmat).all(axis=(1, 2))
        if ok.sum() >= min_frames:
            return _to_char(pts[ok], origin[ok], cmat[ok]).mean(axis=0)
    return None


def calibrated_segments(pose: Markers, markerset: MarkerSet, params: FramesParams) -> set[str] | None:
    """The segments that ``pose``, as a take's first neutral source, calibrates in :func:`compute_frames`
    (every marker of the segment and a character frame in at least ``min_neutral_frames`` frames); ``None``
    when the pose does not give the root reference itself (then which it calibrates depends on the take's
    other sources)."""
    root_ref = root_reference([("pose", pose)], markerset, params.min_neutral_frames)
    if root_ref is None:
        return None
    try:
        origin, cmat, _ = fitted_character_frame(pose, markerset, root_ref, params.min_plane_ratio)
    except StageError:
        return None
    has_char = np.isfinite(cmat).all(axis=(1, 2)) & np.isfinite(origin).all(axis=1)
    out = set()
    for s in markerset.segments:
        if all(m in pose.labels for m in s.markers):
            pts = np.stack([pose.xyz[:, pose.index(m)] for m in s.markers], axis=1)
            if (has_char & np.isfinite(pts).all(axis=(1, 2))).sum() >= params.min_neutral_frames:
                out.add(s.name)
    return out


def fitted_character_frame(markers: Markers, markerset: MarkerSet, root_ref: np.ndarray | None,
                           min_plane_ratio: float, *, path: str | None = None,
                           take: str | None = None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """:func:`character_frame`, and where one of the root segment's first two markers is missing but the root
    marker is there, the heading from the root segment's orientation: a least-squares rigid fit of its markers
    present and the root marker (three or more, not nearly collinear) to their neutral geometry ``root_ref``
    (:func:`root_reference`), whose left direction is that of the first marker minus the second (SPEC §2).

    Returns origin (T, 3) mm, lab-from-character matrices (T, 3, 3) and which frames' heading was fitted (T,).
    """
    origin, cmat = character_frame(markers, markerset, path=path, take=take)
    fitted = np.zeros(markers.n_frames, dtype=bool)
    need = ~np.isfinite(cmat).all(axis=(1, 2)) & np.isfinite(origin).all(axis=1)
    if root_ref is None or not need.any():
        return origin, cmat, fitted
    names = [markerset.root, *markerset.root_segment.markers]
    pts = np.stack([_col(markers, n, path, take, "root segment") for n in names], axis=1)
    seen = np.isfinite(pts).all(axis=2)
    rows = np.flatnonzero(need & (seen.sum(axis=1) >= 3))
    if not len(rows):
        return origin, cmat, fitted
    patterns, inverse = np.unique(seen[rows], axis=0, return_inverse=True)
    up = up_vector(markerset.up_axis)
    for p, pat in enumerate(patterns):
        if not _well_conditioned(root_ref[pat], min_plane_ratio):
            continue
        r = rows[inverse.reshape(-1) == p]
        rot = rigid_fit(root_ref[pat], pts[r][:, pat])           # lab from the reference's character axes
        cmat[r] = heading_frames(rot @ (root_ref[1] - root_ref[2]), up)
        fitted[r] = True
    return origin, cmat, fitted


def rigid_fit(ref: np.ndarray, pts: np.ndarray) -> np.ndarray:
    """Least-squares rotations (N, 3, 3) with pts[n] − centroid ≈ R[n] · (ref − centroid(ref)): ``ref`` (K, 3) the
    reference cluster (any origin), ``pts`` (N, K, 3) the observed clusters, every marker finite (mm).

    Horn's closed form, compiled (:func:`gazepipe.stages.frames.kernels.horn_rotations`: the eigenvalue by
    Newton's steps on the characteristic quartic, the quaternion from the adjugate; Jacobi's rotations where the
    eigenvalue is not well apart): the rotation of :func:`gazepipe.stages.geometry.kabsch` to rounding (within
    1e-14 on the sample's and the Klein corpus's clusters), about 0.3 µs a frame with its centring, 9 times faster
    than a LAPACK 3×3 SVD per frame. On a nearly collinear cluster (0.1 mm across 200 mm) both lose digits and this more
    (2e-9 against the SVD's 3e-13, noiseless): far below what the markers' noise does to such a fit. The clean
    stage's filler keeps :func:`~gazepipe.stages.geometry.kabsch`."""
    return _fit_and_centre(ref, pts)[0]


def _fit_and_centre(ref: np.ndarray, pts: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """:func:`rigid_fit`'s rotations (N, 3, 3) and the observed clusters' centroids (N, 3) mm."""
    from gazepipe.stages.frames.kernels import horn_rotations

    a = np.ascontiguousarray(ref - ref.mean(axis=0), dtype=np.float64)[None]
    return horn_rotations(a, np.ascontiguousarray(pts, dtype=np.float64))


def _to_char(p: np.ndarray, origin: np.ndarray, c: np.ndarray) -> np.ndarray:
    """Lab points p (T, ..., 3) into character coordinates: Cᵀ (p − origin)."""
    d = p - origin.reshape(origin.shape[0], *([1] * (p.ndim - 2)), 3)
    # row vectors times C (batched matmul: several times faster than the equivalent einsum)
    if p.ndim == 2:
        return (d[:, None, :] @ c)[:, 0, :]
    return d @ c


def _well_conditioned(ref: np.ndarray, min_plane_ratio: float) -> bool:
    """True when the reference points ref (K, 3) are at least three and not nearly collinear."""
    if len(ref) < 3:
        return False
    sv = np.linalg.svd(ref - ref.mean(axis=0), compute_uv=False)
    return bool(sv[0] > 0 and sv[1] >= min_plane_ratio * sv[0])


def fit_uncertainty_deg(ref: np.ndarray, err: np.ndarray) -> np.ndarray:
    """How far (deg) errors in a cluster's marker positions turn its least-squares rigid fit: the first-order
    propagation of independent, isotropic position errors of (3-D RMS) size ``err`` (T, K) mm through the fit
    to the reference cluster ``ref`` (K, 3) mm.

    A small rotation δθ of the fit answers the centred positions' errors δp_i as A·δθ = Σ r_i × δp_i, with r_i
    the centred reference points and A = Σ (|r_i|² I − r_i r_iᵀ) the cluster's inertia (translations are
    absorbed by the centroid). So each marker's error turns the fit by A⁻¹ [r_i]× δp_i, most about an axis the
    cluster is thin across (markers nearly in a line), about atan(error / radius) otherwise. Returns the RMS
    angle √(Σ_i err_i² ‖A⁻¹ [r_i]×‖²_F / 3); 0 where every error is 0, NaN where one is NaN or the cluster is
    degenerate.
    """
    r = np.asarray(ref, dtype=np.float64)
    r = r - r.mean(axis=0)
    inertia = (r * r).sum() * np.eye(3) - r.T @ r
    if np.linalg.cond(inertia) > 1e12:
        return np.full(np.shape(err)[0], np.nan)
    inv = np.linalg.inv(inertia)
    cross = np.zeros((len(r), 3, 3))
    cross[:, 0, 1], cross[:, 0, 2], cross[:, 1, 2] = -r[:, 2], r[:, 1], -r[:, 0]
    cross -= cross.transpose(0, 2, 1)
    gain = ((inv[None] @ cross) ** 2).sum(axis=(1, 2)) / 3.0            # rad² per mm² of each marker's error
    e = np.asarray(err, dtype=np.float64)
    return np.degrees(np.sqrt((e * e) @ gain))


def _marker_frames(pts: np.ndarray, ref: np.ndarray | None, triangle: str = "rigid_fit",
                   min_plane_ratio: float = 0.2, err: np.ndarray | None = None
                   ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Raw lab-from-marker frames (T, 3, 3) of one segment's markers pts (T, K, 3), the cluster's centroid
    (T, 3) in lab coordinates, NaN where the segment is undefined, and how far the markers' fill errors ``err``
    (T, K) mm (0 where measured) may turn each frame (T,) deg (:func:`fit_uncertainty_deg` over the markers
    each frame uses; 0 without ``err`` or ``ref``).

    Kabsch fit to ``ref`` (K, 3); Gram–Schmidt on the triangle for three markers when ``triangle`` says so.
    Frames with every marker use them all. For more than three markers, frames with some missing are fitted
    to the markers present (grouped by visibility pattern, one batched fit per pattern) when the pattern's
    reference subset passes :func:`_well_conditioned`; their centroid is that of the whole reference cluster
    carried by the fit (present centroid + R · (full − present reference centroid)).
    """
    t, k = pts.shape[:2]
    out = np.full((t, 3, 3), np.nan)
    centre = np.full((t, 3), np.nan)
    unc = np.zeros(t)
    seen = np.isfinite(pts).all(axis=2)
    ok = seen.all(axis=1)
    if ok.any():
        if ref is None or (k == 3 and triangle == "gram_schmidt"):
            out[ok] = frame_from_points(pts[ok, 0], pts[ok, 1], pts[ok, 2])
            centre[ok] = pts[ok].mean(axis=1)
        else:
            out[ok], centre[ok] = _fit_and_centre(ref, pts[ok])
        if err is not None and ref is not None:
            unc[ok] = fit_uncertainty_deg(ref, err[ok])
    if ref is None or k <= 3:
        return out, centre, unc
    part = ~ok & (seen.sum(axis=1) >= 3)
    if not part.any():
        return out, centre, unc
    patterns, inverse = np.unique(seen[part], axis=0, return_inverse=True)
    rows = np.flatnonzero(part)
    inverse = inverse.reshape(-1)
    for p, pat in enumerate(patterns):
        sub = ref[pat]
        if not _well_conditioned(sub, min_plane_ratio):
            continue
        r = rows[inverse == p]
        rot, present = _fit_and_centre(sub, pts[r][:, pat])
        out[r] = rot
        centre[r] = present + rot @ (ref.mean(axis=0) - sub.mean(axis=0))
        if err is not None:
            unc[r] = fit_uncertainty_deg(sub, err[r][:, pat])
    return out, centre, unc


def compute_frames(markers: Markers, markerset: MarkerSet,  # noqa: C901
                   neutral: Markers | Sequence[tuple[str, Markers]] | None, params: FramesParams | None = None,
                   *, path: str | None = None, take: str | None = None, before: Markers | None = None,
                   measured: np.ndarray | None = None, before_measured: np.ndarray | None = None,
                   fill_error_mm: np.ndarray | None = None, before_fill_error_mm: np.ndarray | None = None) -> Joints:
    """Segment orientations, head centre and target direction per frame (SPEC §3.3).

    Parameters
    ----------
    markers : cleaned (stabilised, cropped) markers of the take, mm, lab axes.
    markerset : the session's markerset.
    neutral : markers in the neutral pose, same labels (the ``neutral`` take's cleaned markers, or the take's
        first rest period: :attr:`gazepipe.stages.clean.stage.CleanResult.neutral`), or several such sources as
        ``(name, markers)`` in order of preference. Each segment's calibration is the mean (``Rotation.mean``)
        of its marker frame in the character frame over the frames of the first source where the segment is
        solvable (every marker measured or filled, and a character frame) in at least ``min_neutral_frames``,
        so the neutral pose maps to the identity; QC ``neutral_sources`` says which source each segment used.
        A segment no source can calibrate has no orientation in this take (a QC warning), and the take goes on.
    params : :class:`FramesParams`.

    The character frame's heading comes from the root segment's first two markers, or where one of them is
    missing from a rigid fit of the root segment (:func:`fitted_character_frame`; QC ``heading_fitted_frames``).

    ``before``: the frames just before the take's first one (the rest the crop starts after), same labels and
    axes; they give a segment's rotation gap that starts before the take its known side there
    (:func:`fill_rotation_gaps`), and are not in the output. QC frame numbers count from the take's first frame.

    ``measured`` / ``before_measured``: (frames, M) bool, the samples of ``markers`` / ``before`` that were
    measured (fill code ``measured`` or ``swap_repaired``), not filled; default: every valid sample. A segment's
    rotation is measured (:attr:`Joints.rot_measured`) where all its markers are and it was not filled.

    ``fill_error_mm`` / ``before_fill_error_mm``: (frames, M) the estimated error (mm) of each filled sample of
    ``markers`` / ``before`` (the markers table's ``fill_error_mm``; NaN where measured, unfilled or filled
    without an estimate). A segment whose rotation the errors of its filled markers may turn by more than
    ``max_fit_uncertainty_deg`` (:func:`fit_uncertainty_deg`, over the markers the frame's fit uses; a fill
    without an estimate counts 0, so that is a least uncertainty) is unsure there, like a segment whose markers stay
    unfilled: it gets no rotation from its markers, and :func:`fill_rotation_gaps` may fill it across the
    stretch when its hold-out estimate allows (QC ``fill_uncertain_frames`` per segment). Three chest markers
    110 mm across filled 2.3–4.5 mm off may turn it by 4° (RMS); it was 5.3° off. Default: not judged.

    Raises :class:`~gazepipe.errors.StageError` when a marker is missing from the capture, a segment has fewer
    than three markers, or there is no neutral pose at all.
    """
    # here: planning a run imports this module, and numba is slow to load
    from gazepipe.stages.frames.kernels import Rot

    params = params or FramesParams()
    if params.triangle not in ("rigid_fit", "gram_schmidt"):
        raise ValueError(f"FramesParams.triangle must be 'rigid_fit' or 'gram_schmidt', not {params.triangle!r}")
    lead = 0
    meas = markers.valid if measured is None else np.asarray(measured, dtype=bool) & markers.valid
    ferr = None if fill_error_mm is None else np.asarray(fill_error_mm, dtype=np.float64)
    if before is not None and before.n_frames and list(before.labels) == list(markers.labels):
        lead = before.n_frames
        meas = np.concatenate([before.valid if before_measured is None
                               else np.asarray(before_measured, dtype=bool) & before.valid, meas])
        if ferr is not None:
            ferr = np.concatenate([np.full(before.valid.shape, np.nan) if before_fill_error_mm is None
                                   else np.asarray(before_fill_error_mm, dtype=np.float64), ferr])
        markers = replace(markers, xyz=np.concatenate([before.xyz, markers.xyz]),
                          valid=np.concatenate([before.valid, markers.valid]),
                          first_frame=int(markers.first_frame) - lead)
    sources = ([] if neutral is None else [("neutral", neutral)] if isinstance(neutral, Markers)
               else [(name, m) for name, m in neutral if m is not None and m.n_frames])
    if not sources:
        raise StageError(path, "frames: no neutral pose to calibrate the segments "
                         "(no neutral take and no rest period)", take=take)
    segs = markerset.segments
    names = [s.name for s in segs]
    parents = np.array([names.index(s.parent) if s.parent in names else -1 for s in segs], dtype=np.int64)
    n, ns = markers.n_frames, len(segs)
    qc: dict = {"warnings": [], "neutral_frames": {}, "neutral_sources": {}}

    root_ref = root_reference(sources, markerset, params.min_neutral_frames)
    origin, cmat, fitted = fitted_character_frame(markers, markerset, root_ref, params.min_plane_ratio, path=path,
                                                  take=take)
    qc["heading_fitted_frames"] = int(fitted.sum())
    rule = _jump_rule(params, markers.rate_hz)
    qc["flip_frames"] = {}
    heading_flip = flips(cmat, rule) if rule is not None else np.zeros(n, dtype=bool)
    cmat[heading_flip] = np.nan
    has_char = np.isfinite(cmat).all(axis=(1, 2)) & np.isfinite(origin).all(axis=1)
    frames_of = []          # per source: (markers, origin, character matrices, has a character frame)
    for _, nm in sources:
        n_origin, n_cmat, _ = fitted_character_frame(nm, markerset, root_ref, params.min_plane_ratio, path=path,
                                                     take=take)
        frames_of.append((nm, n_origin, n_cmat,
                          np.isfinite(n_cmat).all(axis=(1, 2)) & np.isfinite(n_origin).all(axis=1)))
    # rotations are composed as matrices (batched matmul) and turned into quaternions once per segment
    cmat_t = np.where(has_char[:, None, None], cmat, np.eye(3)).transpose(0, 2, 1)

    gmat = np.full((n, ns, 3, 3), np.nan)
    centres: dict[str, np.ndarray] = {}   # lab centroid of each segment's full cluster
    # each sample's position error (mm): 0 where measured, the fill's estimate where filled (0 without one)
    sample_err = (np.where(meas, 0.0, np.nan_to_num(ferr, nan=0.0))
                  if ferr is not None and params.max_fit_uncertainty_deg > 0 else None)
    judge = sample_err is not None
    qc["fill_uncertain_frames"] = {}
    fit_unc = np.zeros((n, ns))                 # how far the fills of a segment's markers may turn its rotation
    seg_markers: list[SegmentMarkers | None] = [None] * ns
    for j, s in enumerate(segs):
        if len(s.markers) < 3:
            raise StageError(path, f"frames: segment {s.name!r} has {len(s.markers)} markers, needs three",
                             take=take)
        pts = np.stack([_col(markers, m, path, take, f"segment {s.name!r}") for m in s.markers], axis=1)
        chosen = None
        for (label, _), (nm, n_origin, n_cmat, n_has_char) in zip(sources, frames_of, strict=True):
            npts = np.stack([_col(nm, m, path, take, f"segment {s.name!r}") for m in s.markers], axis=1)
            nok = n_has_char & np.isfinite(npts).all(axis=(1, 2))
            if nok.sum() >= params.min_neutral_frames:
                chosen = (label, npts, nok, n_origin, n_cmat, nm)
                break
        qc["neutral_frames"][s.name] = int(chosen[2].sum()) if chosen else 0
        qc["neutral_sources"][s.name] = chosen[0] if chosen else None
        if chosen is None:
            qc["warnings"].append(f"segment {s.name!r}: no neutral source has {params.min_neutral_frames} frames "
                                  f"with every marker ({', '.join(lab for lab, _ in sources)}); it has no "
                                  "orientation in this take")
            centres[s.name] = np.full((n, 3), np.nan)
            continue
        _, npts, nok, n_origin, n_cmat, chosen_markers = chosen
        # reference cluster for rigid fits: the neutral cluster's mean shape in character coordinates
        ref = _to_char(npts[nok], n_origin[nok], n_cmat[nok]).mean(axis=0)
        n_raw, _, _ = _marker_frames(npts[nok], ref, params.triangle)
        n_glob = Rot.from_matrix(n_cmat[nok].transpose(0, 2, 1) @ n_raw)
        calib = n_glob.mean().inv().as_matrix()   # right-multiplied: neutral mean → identity
        cols = [markers.index(m) for m in s.markers]
        err = None if sample_err is None else sample_err[:, cols]
        raw, centres[s.name], unc = _marker_frames(pts, ref, params.triangle, params.min_plane_ratio, err)
        if s.name == markerset.root_segment.name and params.triangle == "rigid_fit":
            _root_segment_fit(raw, pts, npts, nok, n_origin, n_cmat, markers, chosen_markers,
                              markerset, params, unc, sample_err)
        seg_meas = meas[:, cols]
        if judge:
            unsure = _refit_measured(raw, centres[s.name], unc, pts, seg_meas, ref, params)
            raw[unsure] = np.nan
            qc["fill_uncertain_frames"][s.name] = int(unsure[lead:].sum())
        flip = flips(raw, rule) if rule is not None else np.zeros(n, dtype=bool)
        raw[flip] = np.nan
        qc["flip_frames"][s.name] = int(flip[lead:].sum())
        ok = has_char & np.isfinite(raw).all(axis=(1, 2))
        if ok.any():
            gmat[ok, j] = cmat_t[ok] @ raw[ok] @ calib
        fit_unc[:, j] = unc
        # the markers measured where the rotation is not known from them: a fill across is turned to meet them
        seen = seg_meas & ~flip[:, None] & has_char[:, None]
        seg_markers[j] = SegmentMarkers(body=ref - ref.mean(axis=0),      # (Cᵀ·p as rows: p·C, a batched matmul)
                                        pos=np.where(seen[..., None], pts, np.nan) @ cmat_t.transpose(0, 2, 1))

    rot_filled = refuted = np.zeros((n, ns), dtype=bool)
    if params.max_fill_error_deg > 0:
        rot_filled, qc["rotation_gaps"], refuted = fill_rotation_gaps(
            gmat, parents, has_char, params.max_fill_error_deg, window=int(round(10.0 * markers.rate_hz)),
            markers=seg_markers, fit_unc=fit_unc if judge else None)
    qc["fit_refuted_frames"] = {s.name: int(refuted[lead:, j].sum()) for j, s in enumerate(segs)}
    if not any(qc["neutral_sources"].values()):
        raise StageError(path, f"frames: no segment has {params.min_neutral_frames} neutral frame(s) with every "
                         f"marker ({', '.join(lab for lab, _ in sources)})", take=take)
    valid = has_char & np.isfinite(gmat).all(axis=(1, 2, 3))
    rot_measured = np.isfinite(gmat).all(axis=(2, 3)) & ~rot_filled & np.stack(
        [meas[:, [markers.index(m) for m in s.markers]].all(axis=1) for s in segs], axis=1)
    quat = np.full((n, ns, 4), np.nan)
    quat_local = np.full((n, ns, 4), np.nan)
    for j in range(ns):
        ok = np.isfinite(gmat[:, j]).all(axis=(1, 2))
        if not ok.any():
            continue
        quat[ok, j] = Rot.from_matrix(gmat[ok, j]).wxyz()
        p = parents[j]
        if p < 0:
            quat_local[ok, j] = quat[ok, j]
            continue
        okp = ok & np.isfinite(gmat[:, p]).all(axis=(1, 2))
        if okp.any():
            quat_local[okp, j] = Rot.from_matrix(gmat[okp, p].transpose(0, 2, 1) @ gmat[okp, j]).wxyz()
    six = six_from_matrix(gmat)

    head_centre = _head_centre(markers, markerset, params, origin, cmat, gmat, names, centres, qc, path,
                               take)
    target_dir = np.full((n, 3), np.nan)
    if markerset.target and markerset.target in markers.labels:
        tgt = _to_char(markers.xyz[:, markers.index(markerset.target)], origin, cmat)
        d = tgt - head_centre
        with np.errstate(invalid="ignore", divide="ignore"):
            target_dir = d / np.linalg.norm(d, axis=1, keepdims=True)
    elif markerset.target:
        qc["warnings"].append(f"target marker {markerset.target!r} is not in the capture")

    char_rot = np.full((n, 4), np.nan)
    if has_char.any():
        char_rot[has_char] = Rot.from_matrix(cmat[has_char]).wxyz()
    k = slice(lead, None)                                     # the take's own frames
    qc["invalid_frames"] = int(np.sum(~valid[k]))
    qc["heading_flip_frames"] = int(heading_flip[k].sum())
    qc["heading_fitted_frames"] = int(fitted[k].sum())
    for g in qc.get("rotation_gaps", []):
        g["start"], g["stop"] = g["start"] - lead, g["stop"] - lead
    qc["rotation_gaps"] = [g for g in qc.get("rotation_gaps", []) if g["stop"] > 0]
    rest = (rest_pose(quat[:lead], char_rot[:lead], int(round(REST_POSE_S * markers.rate_hz)),
                      rot_measured[:lead]) if lead else None)
    return Joints(segments=names, parents=parents, quat=quat[k], quat_local=quat_local[k], six=six[k],
                  head_centre=head_centre[k], target_dir=target_dir[k],
                  char_origin=np.where(has_char[:, None], origin, np.nan)[k], char_rot=char_rot[k], valid=valid[k],
                  rate_hz=float(markers.rate_hz), first_frame=int(markers.first_frame) + lead, qc=qc,
                  rot_filled=rot_filled[k], rest_before=rest, rot_measured=rot_measured[k])


#: seconds each side of a step over which :func:`_jump_rule`'s running medians run
JUMP_WINDOW_S = 0.25
#: a flip up to this long (s) needs no more than its two jumps and its coming back (a ghost, a one-frame flip)
SHORT_FLIP_S = 0.1


def _jump_rule(params: FramesParams, rate_hz: float) -> JumpRule | None:
    """The continuity rule of ``params`` at ``rate_hz`` (None when ``jump_factor`` is 0)."""
    if params.jump_factor <= 0:
        return None
    return JumpRule(factor=params.jump_factor, min_deg=params.min_jump_deg,
                    window=max(3, int(round(JUMP_WINDOW_S * rate_hz))),
                    max_frames=max(1, int(round(params.max_flip_s * rate_hz))),
                    short_frames=max(1, int(round(SHORT_FLIP_S * rate_hz))))


#: seconds at the end of the rest before the take over which :func:`rest_pose` averages the pose
REST_POSE_S = 0.5


def rest_pose(quat: np.ndarray, char_rot: np.ndarray, n_last: int,
              measured: np.ndarray | None = None) -> dict | None:
    """The still pose just before the take: each segment's rotation (S, 4) wxyz and the character frame's (4,),
    each the mean (``Rotation.mean``) over the last ``n_last`` rest frames where it is measured, else over every
    rest frame where it is (None where never). The subject is still there by definition, so the mean is the
    pose at the take's first frame with the noise of a single frame averaged out; None without any rest frame.

    ``measured`` (N, S) bool marks segment rotations from measured marker samples (``Joints.rot_measured``;
    default: every known one). Rotations from gap-filled markers or filled across a gap of them never enter a
    segment's mean: a fill is estimated from what lies around it, and one that reaches into a rest from its
    edge or from other segments was measured 7–10 mm (4–10°) off where its estimate said 1–2 mm. A fill inside
    the rest with measured frames on both sides adds nothing those frames do not show; where no frame of the
    rest is measured, nothing shows the filled pose is the still one: that segment's pose is None.
    """
    if not len(quat):
        return None

    def mean(q: np.ndarray) -> list[float] | None:
        m = mean_wxyz(q[-n_last:])
        m = mean_wxyz(q) if m is None else m
        return None if m is None else [float(x) for x in m]

    if measured is not None:
        quat = np.where(np.asarray(measured, dtype=bool)[..., None], quat, np.nan)
    return {"quat": [mean(quat[:, j]) for j in range(quat.shape[1])], "char_rot": mean(char_rot),
            "frames": int(min(n_last, len(quat)))}


def _refit_measured(raw: np.ndarray, centre: np.ndarray, unc: np.ndarray, pts: np.ndarray, measured: np.ndarray,
                    ref: np.ndarray, params: FramesParams) -> np.ndarray:
    """Where the fills of a segment's markers may turn its fit by more than ``max_fit_uncertainty_deg``, the fit
    to its measured markers alone when they can give one (at least three, not nearly collinear: a cluster of more
    than three with some filled), in place in ``raw`` (T, 3, 3), ``centre`` (T, 3) and ``unc`` (T,; 0 there).
    Returns the frames still unsure (T,)."""
    unsure = (unc > params.max_fit_uncertainty_deg) & np.isfinite(raw).all(axis=(1, 2))
    rows = np.flatnonzero(unsure)
    if not len(rows) or pts.shape[1] <= 3:
        return unsure
    alt, alt_centre, _ = _marker_frames(np.where(measured[rows][..., None], pts[rows], np.nan), ref,
                                        params.triangle, params.min_plane_ratio)
    good = np.isfinite(alt).all(axis=(1, 2))
    raw[rows[good]], centre[rows[good]], unc[rows[good]] = alt[good], alt_centre[good], 0.0
    unsure[rows[good]] = False
    return unsure


def _root_segment_fit(raw: np.ndarray, pts: np.ndarray, npts: np.ndarray, nok: np.ndarray, n_origin: np.ndarray,
                      n_cmat: np.ndarray, markers: Markers, neutral: Markers, markerset: MarkerSet,
                      params: FramesParams, unc: np.ndarray | None = None,
                      sample_err: np.ndarray | None = None) -> None:
    """Where the root segment's own markers cannot give its frame (one of three missing), fill ``raw`` in place
    from a rigid fit of the markers present and the root marker to their neutral geometry (SPEC §3.3), and
    ``unc`` with that fit's uncertainty from the samples' errors ``sample_err`` (T, M) mm, when given."""
    miss = ~np.isfinite(raw).all(axis=(1, 2))
    root = markerset.root
    if not miss.any() or root not in markers.labels or root not in neutral.labels:
        return
    ext_n = np.concatenate([npts, neutral.xyz[:, neutral.index(root)][:, None]], axis=1)
    ok = nok & np.isfinite(ext_n).all(axis=(1, 2))
    if ok.sum() < params.min_neutral_frames:
        return
    ref = _to_char(ext_n[ok], n_origin[ok], n_cmat[ok]).mean(axis=0)
    ext = np.concatenate([pts[miss], markers.xyz[miss, markers.index(root)][:, None]], axis=1)
    err = None
    if sample_err is not None:
        err = sample_err[miss][:, [markers.index(m) for m in (*markerset.root_segment.markers, root)]]
    raw[miss], _, ext_unc = _marker_frames(ext, ref, "rigid_fit", params.min_plane_ratio, err)
    if unc is not None and err is not None:
        unc[miss] = ext_unc


def _head_centre(markers: Markers, markerset: MarkerSet, params: FramesParams, origin: np.ndarray,
                 cmat: np.ndarray, gmat: np.ndarray, names: list[str], centres: dict[str, np.ndarray],
                 qc: dict, path: str | None, take: str | None) -> np.ndarray:
    """Eyes' centre (T, 3) mm in the character frame: the head-centre marker, else the head markers'
    centroid (carried by the rigid fit where a marker is missing, ``centres``) plus ``eye_offset_mm`` in the
    head segment's axes.

    The head-centre marker moves with the head, so where it is missing (unfilled) and the head segment is
    solved, it is carried by the head's fit: the head centroid plus its median offset in the head's axes over
    the frames that have both (``qc["head_centre_carried_frames"]``).
    """
    head = params.head_segment or ("head" if "head" in names else names[-1])
    j = names.index(head)
    centre = _to_char(centres[head], origin, cmat)
    if markerset.head_centre:
        marker = _to_char(_col(markers, markerset.head_centre, path, take, "head centre"), origin, cmat)
        rot = gmat[:, j]
        both = np.isfinite(marker).all(axis=1) & np.isfinite(centre).all(axis=1) & np.isfinite(rot).all(axis=(1, 2))
        lost = ~np.isfinite(marker).all(axis=1) & np.isfinite(centre).all(axis=1) & np.isfinite(rot).all(axis=(1, 2))
        qc["head_centre_carried_frames"] = 0
        if both.any() and lost.any():
            off = np.median(np.einsum("tji,tj->ti", rot[both], marker[both] - centre[both]), axis=0)
            marker[lost] = centre[lost] + np.einsum("tij,j->ti", rot[lost], off)
            qc["head_centre_carried_frames"] = int(lost.sum())
        return marker
    if markerset.eye_offset_mm is None:   # a fact of the session's markerset: the neutral_poses unit says it once
        return centre
    off = np.asarray(markerset.eye_offset_mm, dtype=np.float64)
    return centre + np.einsum("tij,j->ti", gmat[:, j], off)
