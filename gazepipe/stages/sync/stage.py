"""sync stage: clapper sync of the mocap clock and the head-camera clock, and resampling onto mocap frames.

Klein 5.1: a clapper carrying one marker on each arm is snapped shut in view of the head camera, typically
once near the start and once near the end of a take. The mocap clock is the master clock (SPEC §2):

    t_mocap = offset + ratio · t_video

- Mocap clap (:func:`mocap_claps`): the contact instant, when the closing of the clapper arms ends.
- Video clap (:func:`match_clap`): where the per-frame motion energy follows the clapper's speed as the mocap
  saw it (opening, hold, closing), refined to the end of the closing burst; from a few seconds of frames around
  each expected clap only (the video is never decoded whole). A hand coming into view or the clapper opening
  is a burst of another shape.
- Clock map (:func:`choose_clock`): every clap pair is a measurement with a timing uncertainty (its mocap and
  video claps', from their detection); the map is fitted to all of them, weighted, with the nominal ratio as a
  prior as wide as what cameras do (a camera labelled 60 fps running at 59.94 has ratio 1.001). A pair is set
  aside, with a warning naming the video and the clap, only when it disagrees with the others and any camera
  rate beyond its uncertainty, never for a low detector score. How far the map may be off anywhere follows
  from the fit (``clock_bound_ms`` over the video; the report's ``clock_map`` check over the crop).
- :func:`resample_to_mocap` puts video-clock signals on the mocap frames, never extrapolating.

Everything here is pure: the video comes in as its probe's frame timestamps and a ``read_window(start, stop)``
callable returning ``(timestamps_s, frames)`` for the frames [start, stop) (a ``gazepipe.io.video.FrameReader``
for the take, typically with a small ``scale``: it decodes the windows, asked for mostly in increasing order,
through one open capture).

The steps live in their own modules (see the package); this module pairs them per take (:func:`sync_take`).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from gazepipe.errors import StageError
from gazepipe.stages.clean.spikes import find_spikes
from gazepipe.stages.sync.clap import Clap, clap_profile, clapper_distance, mocap_claps
from gazepipe.stages.sync.clock import BOUND_SIGMAS, ClockMap, choose_clock
from gazepipe.stages.sync.qc import ClapQC, SyncQC
from gazepipe.stages.sync.video import ReadWindow, VideoClap, match_clap

#: without a prior, a first clap found with less video confidence than this is weighed against the last clap
#: searched for at the video's tail (the surer one anchors the search for the others)
ANCHOR_CONFIDENCE = 0.5


@dataclass(frozen=True)
class SyncParams:
    """Parameters of the sync stage (see :func:`sync_take`).

    window_s : half-width (s) of each video window searched around a predicted clap.
    search_s : without a prior, the first clap is looked for in the first (or last) ``search_s`` of the video.
    max_drift : largest |ratio − 1| cameras show (a 59.94 Hz camera labelled 60 is 0.001, plus its crystal's
        error): the ratio's prior has standard deviation ``max_drift`` / 2, and claps that disagree beyond it
        and their timing are set aside (:func:`gazepipe.stages.sync.clock.choose_clock`).
    min_confidence : video claps below this confidence count as not found.
    video_scale : frames are scaled by this before motion energy (the clapper fills much of the view).

    Each field's metadata gives its allowed values (:func:`gazepipe.pipeline.registry.value_problem`) and its one
    line of help (``help``: what ``gazepipe params`` prints).
    """

    window_s: float = field(default=1.5, metadata={
        "gt": 0, "help": "half-width, in s, of the video window searched around each expected clap"})
    search_s: float = field(default=20.0, metadata={
        "gt": 0, "help": "how far into the video (s, from the start or the end) to look for the first clap"})
    max_drift: float = field(default=0.0012, metadata={
        "min": 0, "lt": 1, "help": "largest clock-rate difference cameras show (0.001 = 0.1 %); claps "
            "beyond it are set aside"})
    min_confidence: float = field(default=0.05, metadata={
        "min": 0, "max": 1, "help": "video claps below this confidence count as not found"})
    video_scale: float = field(default=0.5, metadata={
        "gt": 0, "max": 1, "help": "video frames are scaled by this before looking for claps (faster when "
            "smaller)"})


@dataclass
class SyncResult:
    """The clock map of a take and how it was found.

    Attributes
    ----------
    clock : the clock map.
    mocap_claps : every clap found in the mocap.
    video_claps : the video clap paired with each mocap clap (``None`` where none was found).
    frames_without_video : mocap frames outside the video's span once mapped.
    frames_decoded : video frames decoded to find the claps.
    qc : the QC record (plain JSON-able values): :class:`~gazepipe.stages.sync.qc.SyncQC` as a dict.
    """

    clock: ClockMap
    mocap_claps: list[Clap]
    video_claps: list[VideoClap | None]
    frames_without_video: int
    frames_decoded: int
    qc: dict = field(default_factory=dict)


def sync_take(clap_a_xyz: np.ndarray, clap_b_xyz: np.ndarray, valid_a: np.ndarray, valid_b: np.ndarray,
              rate_hz: float, probe_timestamps: np.ndarray, read_window: ReadWindow,
              params: SyncParams | None = None, *, offset_guess_s: float | None = None, ratio_guess: float = 1.0,
              roi: tuple[int, int, int, int] | None = None, mocap_path: str | None = None,
              video_path: str | None = None, take: str | None = None,
              mocap_kw: dict | None = None, video_kw: dict | None = None) -> SyncResult:
    """Find the claps on both clocks and map the video clock onto the mocap clock.

    Parameters
    ----------
    clap_a_xyz, clap_b_xyz, valid_a, valid_b, rate_hz : the clapper markers (see :func:`mocap_claps`); the
        take has ``len(valid_a)`` frames at ``rate_hz``. Their ghost spikes are left out first
        (:func:`gazepipe.stages.clean.spikes.find_spikes`): a one-frame jump of one arm is no clap.
    probe_timestamps, read_window : the video (see :func:`video_claps`).
    offset_guess_s, ratio_guess : prior t_mocap ≈ offset + ratio · t_video. Without one, the first mocap
        clap is looked for in the first ``search_s`` of the video (or, failing that, the last mocap clap in
        the last ``search_s``), and the other claps are predicted from that pair.
    params : the stage's parameters (default :class:`SyncParams`), of which it uses ``window_s``, the
        half-width of each video search window (windows predicted from a clap pair widen by ``max_drift`` times
        the distance to that pair), ``search_s``, ``max_drift``, the largest |ratio − 1| cameras show (the
        ratio's prior, and how far claps may disagree: :func:`choose_clock`), and ``min_confidence``, below which
        video claps count as not found.
    mocap_path, video_path, take : named in error messages.
    mocap_kw, video_kw : further parameters of :func:`mocap_claps` and :func:`match_clap`.

    Raises
    ------
    StageError : no clap in the mocap, or no clap found in the video. Claps that disagree are set aside with a
        warning (never an error).
    """
    p = params or SyncParams()
    window_s, search_s, max_drift, min_confidence = p.window_s, p.search_s, p.max_drift, p.min_confidence
    mocap_kw = dict(mocap_kw or {})
    video_kw = dict(video_kw or {}, roi=roi)
    ts = np.asarray(probe_timestamps, dtype=np.float64)
    T = int(np.asarray(valid_a).shape[0])
    counted = [0]

    def reader(start: int, stop: int) -> tuple[np.ndarray, np.ndarray]:
        t, fr = read_window(start, stop)
        counted[0] += len(fr)
        return t, fr

    pair = np.stack([np.asarray(clap_a_xyz, dtype=np.float64), np.asarray(clap_b_xyz, dtype=np.float64)], axis=1)
    measured = np.stack([np.asarray(valid_a, dtype=bool), np.asarray(valid_b, dtype=bool)], axis=1)
    kept = measured & ~find_spikes(pair, measured, rate_hz)
    mc = mocap_claps(clap_a_xyz, clap_b_xyz, kept[:, 0], kept[:, 1], rate_hz, **mocap_kw)
    if not mc:
        raise StageError(mocap_path, "no clap found in the clapper markers (no fast closing that stays shut)",
                         take=take)
    dist = clapper_distance(clap_a_xyz, clap_b_xyz, kept[:, 0], kept[:, 1])
    step = float(np.median(np.diff(ts))) if ts.size > 1 else 1.0 / 60.0
    profiles = [clap_profile(dist, rate_hz, c, step) for c in mc]

    def find(j: int, t0: float, t1: float) -> VideoClap | None:
        v = match_clap(ts, reader, max(t0, float(ts[0])), min(t1, float(ts[-1])), *profiles[j], **video_kw)
        return v if v is not None and v.confidence >= min_confidence else None

    tm = np.array([c.time_s for c in mc])
    vc: list[VideoClap | None] = [None] * len(mc)
    if offset_guess_s is not None:
        approx = (tm - offset_guess_s) / ratio_guess
        vc = [find(j, a - window_s, a + window_s) for j, a in enumerate(approx)]
    else:
        # never more than half the video, so that a clap near the end cannot be taken for the first one: a
        # clap in the take's first half is looked for in the video's head, one in its second half in the tail
        # (a take whose first clap was lost must not pair its last one with the video's first). The take's
        # first clap, and unless that is sure, its last.
        half = min(search_s, 0.5 * float(ts[-1] - ts[0]))

        def search(j: int) -> VideoClap | None:
            if tm[j] <= 0.5 * T / rate_hz:
                return find(j, float(ts[0]), float(ts[0]) + half)
            return find(j, float(ts[-1]) - half, float(ts[-1]))

        anchor, first = 0, search(0)
        if len(mc) > 1 and (first is None or first.confidence < ANCHOR_CONFIDENCE):
            last = search(len(mc) - 1)
            if last is not None and (first is None or last.confidence > first.confidence):
                anchor, first = len(mc) - 1, last
        if first is not None:
            vc[anchor] = first
            off = tm[anchor] - first.time_s
            for j in range(len(mc)):
                if j != anchor:
                    w = window_s + max_drift * abs(tm[j] - tm[anchor])
                    vc[j] = find(j, tm[j] - off - w, tm[j] - off + w)
    if all(v is None for v in vc):
        where = "around the expected times" if offset_guess_s is not None else \
            f"in the first or last {search_s:g} s"
        raise StageError(video_path, f"no clap found in the video {where} ({counted[0]} frames decoded)",
                         take=take)
    span_v = (float(ts[0]), float(ts[-1]))
    choice = choose_clock(mc, vc, video_span=span_v, max_drift=max_drift, video=video_path or "the video")
    clock = choice.clock
    frame_t = np.arange(T, dtype=np.float64) / float(rate_hz)
    span = clock.to_mocap(ts[[0, -1]])
    uncovered = int(np.count_nonzero((frame_t < span[0]) | (frame_t > span[1])))
    duration_v = float(ts[-1] - ts[0])
    qc = SyncQC(
        offset_s=clock.offset_at_first_clap_s,
        offset_at_video_zero_s=clock.offset_s,
        ratio=clock.ratio,
        drift_ppm=clock.drift_ppm,
        drift_ms_over_take=clock.drift_ms(duration_v),
        n_claps=clock.n_claps,
        residual_ms=clock.residual_ms,
        claps=tuple(ClapQC(mocap_s=m.time_s, mocap_confidence=m.confidence, mocap_timing_ms=m.timing_s * 1000.0,
                           video_s=None if v is None else v.time_s,
                           video_confidence=None if v is None else v.confidence,
                           video_match=None if v is None else v.match,
                           video_timing_ms=None if v is None else v.timing_s * 1000.0,
                           video_timed_by=None if v is None else v.timed_by,
                           mocap_gap_frames=m.gap_frames, used=u, set_aside=j in choice.set_aside)
                    for j, (m, v, u) in enumerate(zip(mc, vc, choice.used, strict=True))),
        frames_without_video=uncovered,
        frames_decoded=counted[0],
        video_frames=int(ts.size),
        video_span_s=span_v,
        clock_bound_ms=choice.bound_ms,
        clock_ref_s=clock.ref_s,
        clock_cov=clock.cov,
        clock_prior_ppm=clock.prior_sd * 1e6,
        clock_bound_sigmas=BOUND_SIGMAS,
        claps_used=tuple(j + 1 for j, u in enumerate(choice.used) if u),
        warnings=tuple([f"{video_path or 'the video'}: mocap clap {j + 1} at {m.time_s:.3f} s has no video "
                        f"counterpart" for j, (m, v) in enumerate(zip(mc, vc, strict=True)) if v is None]
                       + choice.warnings),
    ).to_record()
    return SyncResult(clock=clock, mocap_claps=mc, video_claps=vc, frames_without_video=uncovered,
                      frames_decoded=counted[0], qc=qc)
