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
from gazepipe.stages.clean.filters import true_runs
from gazepipe.stages.geometry import (
    frame_from_points,
    heading_frames,
    kabsch,
    mean_wxyz,
    six_from_matrix,
    to_wxyz,
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

    Each field's metadata gives its allowed values (:func:`gazepipe.pipeline.registry.value_problem`).
    """

    min_neutral_frames: int = field(default=3, metadata={"min": 1})
    head_segment: str | None = None
    triangle: str = field(default="rigid_fit", metadata={"choices": ("rigid_fit", "gram_schmidt")})
    min_plane_ratio: float = field(default=0.2, metadata={"min": 0, "max": 1})
    max_fill_error_deg: float = field(default=2.0, metadata={"min": 0})
    max_fit_uncertainty_deg: float = field(default=3.0, metadata={"min": 0})


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
        rot = kabsch(root_ref[pat], pts[r][:, pat])              # lab from the reference's character axes
        cmat[r] = heading_frames(rot @ (root_ref[1] - root_ref[2]), up)
        fitted[r] = True
    return origin, cmat, fitted


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
        else:
            out[ok] = kabsch(ref, pts[ok])
        centre[ok] = pts[ok].mean(axis=1)
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
        rot = kabsch(sub, pts[r][:, pat])
        out[r] = rot
        centre[r] = pts[r][:, pat].mean(axis=1) + rot @ (ref.mean(axis=0) - sub.mean(axis=0))
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
    from scipy.spatial.transform import Rotation  # here: planning a run imports this module

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
        n_glob = Rotation.from_matrix(n_cmat[nok].transpose(0, 2, 1) @ n_raw)
        calib = n_glob.mean().inv().as_matrix()   # right-multiplied: neutral mean → identity
        cols = [markers.index(m) for m in s.markers]
        err = None if sample_err is None else sample_err[:, cols]
        raw, centres[s.name], unc = _marker_frames(pts, ref, params.triangle, params.min_plane_ratio, err)
        if s.name == markerset.root_segment.name and params.triangle == "rigid_fit":
            _root_segment_fit(raw, pts, npts, nok, n_origin, n_cmat, markers, chosen_markers,
                              markerset, params, unc, sample_err)
        if judge:
            unsure = (unc > params.max_fit_uncertainty_deg) & np.isfinite(raw).all(axis=(1, 2))
            raw[unsure] = np.nan
            qc["fill_uncertain_frames"][s.name] = int(unsure[lead:].sum())
        ok = has_char & np.isfinite(raw).all(axis=(1, 2))
        if ok.any():
            gmat[ok, j] = cmat_t[ok] @ raw[ok] @ calib

    rot_filled = np.zeros((n, ns), dtype=bool)
    if params.max_fill_error_deg > 0:
        rot_filled, qc["rotation_gaps"] = fill_rotation_gaps(gmat, parents, has_char, params.max_fill_error_deg,
                                                             window=int(round(10.0 * markers.rate_hz)))
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
        g = Rotation.from_matrix(gmat[ok, j])
        quat[ok, j] = to_wxyz(g)
        p = parents[j]
        if p < 0:
            quat_local[ok, j] = quat[ok, j]
            continue
        okp = ok & np.isfinite(gmat[:, p]).all(axis=(1, 2))
        if okp.any():
            loc = Rotation.from_matrix(gmat[okp, p].transpose(0, 2, 1) @ gmat[okp, j])
            quat_local[okp, j] = to_wxyz(loc)
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
        char_rot[has_char] = to_wxyz(Rotation.from_matrix(cmat[has_char]))
    k = slice(lead, None)                                     # the take's own frames
    qc["invalid_frames"] = int(np.sum(~valid[k]))
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


#: known frames on each side a rotation gap is interpolated from (and that a hidden stretch keeps)
_ROT_ANCHORS = 1


def _slerp_across(local, start: int, stop: int):
    """Rotations (stop − start) filling [start, stop) by slerp between the known rotations just before and just
    after (``local``: a scipy Rotation stack over every frame). A cubic spline through two frames on each side
    was measured too: its edge velocities carry the rotations' noise into the gap (0.4° of noise: 1.2° mean
    error over 12 frames at 120 Hz and 4.7° over 30, against slerp's 0.3° and 0.3°)."""
    from scipy.spatial.transform import Slerp

    return Slerp([start - 1, stop], local[[start - 1, stop]])(np.arange(start, stop, dtype=float))


#: training frames the neighbour model needs at least, and its ridge weight (a share of the features' energy)
_MODEL_MIN_FRAMES = 30
_MODEL_RIDGE = 1e-3


def _model_across(local, span, usable: np.ndarray, start: int, stop: int, window: int):
    """Rotations (stop − start) filling [start, stop) of a segment from the rotation its neighbours span across
    it (``span``: its parent's rotation to its child's, which moves with it; a scipy Rotation stack): a ridge
    regression of the segment's parent-relative rotation on the span's (as rotation vectors about their means)
    over the ``usable`` frames within ``window`` of the gap, corrected to meet the known rotations just before
    and just after (the correction interpolated across). None with too few training frames.

    Not used at a take's start or end: corrected from one side only, it was measured up to 7° off where the
    hold-out beside the gap said 1.4° (a gaze shift's first frames, whose motion the frames after do not show)."""
    from scipy.spatial.transform import Rotation

    lo, hi = max(0, start - window), min(len(usable), stop + window)
    train = np.flatnonzero(usable[lo:hi]) + lo
    train = train[(train < start - 1) | (train > stop)]
    if len(train) < _MODEL_MIN_FRAMES:
        return None
    ref, ref_s = local[train].mean(), span[train].mean()
    x = np.column_stack([(ref_s.inv() * span[train]).as_rotvec(), np.ones(len(train))])
    y = (ref.inv() * local[train]).as_rotvec()
    gram = x.T @ x
    w = np.linalg.solve(gram + _MODEL_RIDGE * np.trace(gram) / 4.0 * np.eye(4), x.T @ y)
    frames = np.arange(start - 1, stop + 1)
    xs = np.column_stack([(ref_s.inv() * span[frames]).as_rotvec(), np.ones(len(frames))])
    pred = ref * Rotation.from_rotvec(xs @ w)
    miss0 = (pred[0].inv() * local[start - 1]).as_rotvec()
    miss1 = (pred[-1].inv() * local[stop]).as_rotvec()
    f = ((np.arange(start, stop) - (start - 1)) / (stop - start + 1))[:, None]
    return pred[1:-1] * Rotation.from_rotvec((1.0 - f) * miss0 + f * miss1)


def _given(known: np.ndarray | None) -> np.ndarray:
    """The frames where a span or neighbour is known: always passed along with the span or neighbour."""
    assert known is not None
    return known


def _candidates(local, known: np.ndarray, span, span_ok: np.ndarray | None, start: int, stop: int,
                window: int) -> dict:
    """Each way of filling [start, stop) that applies: slerp, and the neighbour model where the span is known
    from the frame before to the frame after (``known``, ``span_ok``: frames where the segment's rotation and the
    span are known)."""
    out = {"slerp": _slerp_across(local, start, stop)}
    if span is not None and _given(span_ok)[start - 1:stop + 1].all():
        model = _model_across(local, span, known & span_ok, start, stop, window)
        if model is not None:
            out["model"] = model
    return out


def _off_slerp_deg(nb, lo: int, hi: int) -> float:
    """How far (deg, the largest over [lo, hi)) a rotation stack ``nb`` strays from the slerp between its
    rotations at lo − 1 and hi: the motion inside a stretch that interpolation across it cannot see."""
    return float(np.degrees((_slerp_across(nb, lo, hi) * nb[lo:hi].inv()).magnitude()).max())


def _motion_deg(local, nb, nb_ok: np.ndarray | None, lo: int, hi: int) -> float:
    """How much a stretch [lo, hi) moves, deg: the larger of the segment's own turn across it (its rotations at
    lo − 1 and hi, known on both sides of a gap) and how far its neighbour ``nb`` strays from its own
    interpolation inside it (where known; :func:`_off_slerp_deg`)."""
    own = float(np.degrees((local[lo - 1].inv() * local[hi]).magnitude()))
    if nb is None or not _given(nb_ok)[lo - 1:hi + 1].all():
        return own
    return max(own, _off_slerp_deg(nb, lo, hi))


#: hold-out stretches that move like the gap: at most this many, beside the two next to the gap
_MATCHED_STRETCHES = 2
#: a stretch moves like a gap when it moves at least this share of the gap's amount (the amounts carry noise)
_LIKE_SHARE = 0.8
#: a stretch moves at least this much, deg (the rotations' own noise): a still stretch is not taken as frozen
_MOTION_FLOOR_DEG = 1.0


def _holdouts(local, nb, nb_ok: np.ndarray | None, loc_ok: np.ndarray, s: int, e: int, window: int, a: int
              ) -> tuple[list[int], list[float], float, int]:
    """Where to hide stretches of the gap's length to estimate a fill's error, with how much each moves.

    The two stretches next to the gap, and up to :data:`_MATCHED_STRETCHES` within ``window`` frames that move
    at least as much as the gap (:func:`_motion_deg`; the nearest such amounts first). Returns the stretches'
    first frames (those beside the gap first), their motion and the gap's (deg), and how many are beside it."""
    n, length = len(loc_ok), e - s
    usable = [int(lo) for lo in np.arange(max(a + 1, s - window), min(n - length - a - 1, e + window) + 1,
                                          max(1, length // 4))       # every quarter of the gap's length
              if (lo + length + a <= s - a or lo - a >= e + a) and loc_ok[lo - a:lo + length + a].all()]
    beside = [lo for lo in (s - a - length, e + a)
              if lo - a >= 0 and lo + length + a <= n and loc_ok[lo - a:lo + length + a].all()]
    gap = _motion_deg(local, nb, nb_ok, s, e)
    moves = {lo: _motion_deg(local, nb, nb_ok, lo, lo + length) for lo in {*usable, *beside}}
    like = sorted((abs(moves[lo] - gap), lo) for lo in usable if moves[lo] >= _LIKE_SHARE * gap and lo not in beside)
    picked = beside + [lo for _, lo in like[:_MATCHED_STRETCHES]]
    return picked, [moves[lo] for lo in picked], gap, len(beside)


def _estimate(errors: list[float], amounts: list[float], gap: float, n_beside: int) -> float:
    """A fill's estimated error from its mean misses on the hold-out stretches (deg; the first ``n_beside`` are
    the stretches next to the gap; a stretch moves like the gap when it moves at least :data:`_LIKE_SHARE` of
    its amount): the worst miss beside the gap when one of those moves like it; else, when stretches further
    off do, the worse of the misses beside it and the mean miss on those (the evidence on the gap's kind of
    motion); when none does, each miss scaled by how much more the gap moves than its stretch (a still stretch beside a
    gap in which the head turns says little of it), the motion floored at :data:`_MOTION_FLOOR_DEG`."""
    floor = _MOTION_FLOOR_DEG
    beside = errors[:n_beside]
    if any(m >= _LIKE_SHARE * gap for m in amounts[:n_beside]):
        return max(beside)                     # the stretches next to the gap move like it: they are the evidence
    like = [err for err, m in zip(errors, amounts, strict=True) if m >= _LIKE_SHARE * gap]
    if like:
        return max(max(beside, default=0.0), float(np.mean(like)))
    return max(err * max(1.0, max(gap, floor) / max(m, floor)) for err, m in zip(errors, amounts, strict=True))


def fill_rotation_gaps(gmat: np.ndarray, parents: np.ndarray, has_char: np.ndarray,
                       max_error_deg: float, window: int = 300) -> tuple[np.ndarray, list[dict]]:
    """Fill, in place, each segment's rotations (``gmat`` (N, S, 3, 3), character frame, NaN where its markers
    stay unfilled) across gaps where the character frame and the parent's rotation exist: the parent-relative
    rotation is interpolated by :func:`_slerp_across`, or predicted from its neighbours by :func:`_model_across`
    (where its first child is known through the gap), and composed with the parent's (segments in chain order,
    so a parent filled first carries its children). Each candidate is tried across stretches of the gap's length
    hidden just before and after it, and across stretches that move at least as much as the gap
    (:func:`_holdouts`, :func:`_motion_deg`: the segment's own turn across the stretch, and how far its
    neighbour, the parent's rotation in the character frame or for the root its first child's, strays from its
    own interpolation inside it); a candidate's estimate is its worst mean miss, each scaled by how much more
    the gap moves than that stretch (:func:`_estimate`: the stretches beside a gap in which the head turns are
    still, and slerp looks perfect there). The candidate with the smallest estimate fills the gap when that is at most
    ``max_error_deg``; with no stretch to hide the gap stays open. ``window``: frames each side of a gap the
    neighbour model learns from and the matched stretches are looked for in.

    Returns the (N, S) mask of filled rotations and one record per gap (segment, start, stop, method, estimated
    error in degrees, filled).
    """
    from scipy.spatial.transform import Rotation

    n, ns = gmat.shape[:2]
    filled = np.zeros((n, ns), dtype=bool)
    records: list[dict] = []
    a = _ROT_ANCHORS
    ok_rot = np.isfinite(gmat).all(axis=(2, 3))
    for j in range(ns):
        p = int(parents[j])
        known = ok_rot[:, j]
        base = has_char & (ok_rot[:, p] if p >= 0 else True)
        missing = base & ~known
        if not missing.any():
            continue
        loc_ok = known & base
        mats = np.where(loc_ok[:, None, None], gmat[:, j], np.eye(3))
        if p >= 0:
            mats = np.where(loc_ok[:, None, None], np.swapaxes(gmat[:, p], 1, 2) @ mats, np.eye(3))
        local = Rotation.from_matrix(mats)                   # identity where unknown: never used there
        children = np.flatnonzero(np.asarray(parents) == j)
        span = span_ok = None
        if len(children):
            c = int(children[0])
            span_ok = base & ok_rot[:, c]
            sm = np.where(span_ok[:, None, None], gmat[:, c], np.eye(3))
            if p >= 0:
                sm = np.where(span_ok[:, None, None], np.swapaxes(gmat[:, p], 1, 2) @ sm, np.eye(3))
            span = Rotation.from_matrix(sm)
        # the neighbour whose motion says how the gap moves: the parent in the character frame, else a child
        nb_seg = p if p >= 0 else (int(children[0]) if len(children) else -1)
        nb = nb_ok = None
        if nb_seg >= 0:
            nb_ok = has_char & ok_rot[:, nb_seg]
            nb = Rotation.from_matrix(np.where(nb_ok[:, None, None], gmat[:, nb_seg], np.eye(3)))

        for s, e in true_runs(missing):
            length = e - s
            if s < a or e + a > n or not loc_ok[s - a:s].all() or not loc_ok[e:e + a].all():
                records.append({"segment": j, "start": s, "stop": e, "method": None, "error_deg": None,
                                "filled": False})
                continue
            stretches, amounts, gap_moves, n_beside = _holdouts(local, nb, nb_ok, loc_ok, s, e, window, a)
            errs: dict[str, dict[int, float]] = {}            # method -> stretch index -> mean miss (deg)
            for i, lo in enumerate(stretches):
                hi = lo + length
                for name, guess in _candidates(local, loc_ok, span, span_ok, lo, hi, window).items():
                    errs.setdefault(name, {})[i] = float(np.degrees((guess * local[lo:hi].inv()).magnitude()).mean())
            # a method is scored when it was tried beside the gap; the stretches further off where it could not be
            # tried (the neighbour model needs its child there) count for the others only
            scored = {k: _estimate([v[i] for i in sorted(v)], [amounts[i] for i in sorted(v)], gap_moves,
                                   sum(i < n_beside for i in v))
                      for k, v in errs.items() if all(i in v for i in range(n_beside))}
            # the surest of the methods that apply across the gap itself (the neighbour model needs its child
            # known through the gap, which the stretches it was tried on may have had)
            at_gap = _candidates(local, loc_ok, span, span_ok, s, e, window)
            scored = {k: v for k, v in scored.items() if k in at_gap}
            best = min(scored, key=lambda k: (scored[k], k != "slerp")) if scored else None
            fill = at_gap.get(best) if best else None
            error = scored.get(best) if best else None
            ok = fill is not None and error is not None and error <= max_error_deg
            records.append({"segment": j, "start": s, "stop": e, "method": best, "error_deg": error,
                            "filled": ok})
            if fill is None or not ok:
                continue
            fill = fill.as_matrix()
            gmat[s:e, j] = fill if p < 0 else gmat[s:e, p] @ fill
            ok_rot[s:e, j] = True
            filled[s:e, j] = True
    return filled, records


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
