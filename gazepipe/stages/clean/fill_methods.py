"""The gap-filling methods used by :mod:`gazepipe.stages.clean.gapfill`.

Each method predicts one marker's positions (mm, lab frame) over a half-open frame interval ``[a, b)`` from the
samples that are *known* for that marker (a boolean mask, so that validation can hide extra samples) and, for the
rigid and PCA methods, from the other markers measured in those frames. A method returns ``None`` when it cannot
predict every frame of the interval (no cluster, too few visible markers, no data on one side, ...).

Rigid and PCA predictions are corrected so they meet the known samples next to the interval: the mismatch at the
frame before ``a`` and at frame ``b`` is blended linearly across the interval (constant when only one side is
known). This removes the slowly varying bias of a reference shape or a linear model and is usually far more
accurate than the raw prediction.
"""

from __future__ import annotations

from typing import Literal, overload

import numpy as np

from gazepipe.stages.geometry import cross3, norm3

# scipy is imported where it is used: the engine imports this module (through the clean stage's parameters) to
# plan a run, and a run with nothing to do should not pay for scipy.interpolate and scipy.linalg

#: nearest markers whose interpolation over a gap's frames estimates an interpolation method's error there
_N_DONORS = 3
#: largest standard deviation (mm) of a mate's distance to the marker (the validation judges the rigid fit; 20 mm
#: lets the neighbouring bodies of a whole hidden ART body or a limb serve, measured better than 5 or 10 mm)
MATES_MAX_STD_MM = 20.0
#: PCA in a frame moving with the body (the predictors' mean trajectory subtracted), as Gløersen & Federolf
PCA_BODY_FRAME = True
#: PCA on coordinates normalised by their standard deviation before the distance weighting (off: measured
#: worse on the Walking file, 20.7 vs 8.0 mm on gaps over 0.25 s)
PCA_UNIT_STD = False
#: known samples used on each side of an interval by the interpolating methods (PCHIP's slope at a knot uses
#: its neighbours on both sides; three keep the knot next to the gap's edge as it would be with the whole take)
_N_ANCHORS = 3
#: rigid fill: two mates closer than this (mm) give no axis to turn about, and mates whose second singular value
#: is below this or ``_RIGID_MIN_PLANE`` times their first are too nearly collinear to fix a rotation (marker
#: noise of 0.5 mm turns a 5 mm baseline by about 6°)
_RIGID_MIN_SPREAD_MM = 5.0
_RIGID_MIN_PLANE = 0.05
#: PCA distance weighting: σ is this many times the median predictor distance (Gløersen & Federolf weight by
#: distance; with twice the median a predictor at the median distance weighs 0.88, at twice it 0.61, at four
#: times 0.14), and no predictor's weight falls below ``_PCA_MIN_WEIGHT`` (a far predictor still helps when
#: the near ones are hidden)
PCA_SIGMA_SCALE = 2.0
_PCA_MIN_WEIGHT = 1e-3
#: PCA training: with fewer frames than this the predictor measured least often is let go, and so on (20 frames
#: give up to 19 components, more than validation picks on the shortest takes); more predictors than
#: ``PCA_MAX_PREDICTORS`` (the nearest kept) add next to nothing after the distance weighting and cost time
PCA_MIN_TRAIN = 20
PCA_MAX_PREDICTORS = 12
#: frames sampled for the predictors' mean distances (a few hundred are plenty for a mean)
_PCA_DISTANCE_FRAMES = 200
#: a PCA moving frame needs its three markers this far apart (mm) and this far from collinear (mean sine of
#: the triangle's angle): otherwise its rotation would be mostly noise
_FRAME_MIN_EDGE_MM = 5.0
_FRAME_MIN_SINE = 0.1
#: the most frames a window statistic reads (:func:`distance_stats`) and a PCA model trains on
#: (:func:`fit_pca_models`): a window is given in seconds, so at a high capture rate it holds many frames, and
#: evenly spaced samples of it give the same statistics at a cost that does not grow with the rate. Every frame
#: is read up to 200 Hz (2 s each side of a 1 s gap: 1,000 frames; PCA's 10 s each side: 4,000); at 10 kHz,
#: every 41st of a short gap's 40,000 (a thousand samples fix a mean and a spread to a few percent of it)
WINDOW_SAMPLES = 1000
PCA_MAX_TRAIN = 4000


def sample_step(n: int, most: int) -> int:
    """The stride that reads at most ``most`` of ``n`` evenly spaced frames (1 when ``n <= most``)."""
    return max(1, -(-n // most))


def pchip_eval(x: np.ndarray, y: np.ndarray, t: np.ndarray) -> np.ndarray:
    """PCHIP interpolant through knots ``x`` (n,) increasing, values ``y`` (n, k), evaluated at ``t`` (q,) inside
    ``[x[0], x[-1]]``: (q, k), bit for bit ``scipy.interpolate.PchipInterpolator(x, y, axis=0)(t)``
    (:func:`gazepipe.stages.clean.kernels.pchip_eval`, compiled)."""
    from gazepipe.stages.clean import kernels

    return kernels.pchip_eval(*(np.ascontiguousarray(v, dtype=np.float64) for v in (x, y, t)))


def interp_fill(xyz_m: np.ndarray, known_m: np.ndarray, intervals: list[tuple[int, int]],
                kind: str) -> list[np.ndarray | None]:
    """Linear or PCHIP interpolation of one marker over each frame interval ``[a, b)`` of ``intervals``.

    Parameters
    ----------
    xyz_m : (T, 3) positions of the marker, mm.
    known_m : (T,) bool, samples that may be used.
    kind : ``"linear"`` or ``"pchip"``.

    An interval gets ``None`` unless known samples exist on both sides and none inside it (never extrapolates
    in time). PCHIP runs through the ``_N_ANCHORS`` known samples on each side of the interval (PCHIP is local:
    the same bits as an interpolant through every known sample). Compiled
    (:func:`gazepipe.stages.clean.kernels.interp_intervals`): the search for the anchors goes outward from each
    interval, so an interval costs its own length and the distance to its anchors, not the take's length.
    """
    from gazepipe.stages.clean import kernels

    if kind not in ("linear", "pchip"):
        raise ValueError(f"interpolation kind must be 'linear' or 'pchip', not {kind!r}")
    if not intervals:
        return []
    bounds = np.array(intervals, dtype=np.int64).reshape(-1, 2)
    # the marker's column and mask as they are (strided views): a copy would cost the neighbourhood's length
    out, good = kernels.interp_intervals(np.asarray(xyz_m, dtype=np.float64), np.asarray(known_m, dtype=np.bool_),
                                         np.ascontiguousarray(bounds[:, 0]), np.ascontiguousarray(bounds[:, 1]),
                                         kind == "pchip", _N_ANCHORS)
    offs = np.cumsum(bounds[:, 1] - bounds[:, 0]) - (bounds[:, 1] - bounds[:, 0])
    return [out[o:o + b - a] if ok else None
            for (a, b), o, ok in zip(intervals, offs.tolist(), good.tolist(), strict=True)]


def rigid_fill(xyz: np.ndarray, valid: np.ndarray, m: int, cluster: list[int], known_m: np.ndarray,
               a: int, b: int, partial: bool = False) -> np.ndarray | None:
    """Rigid-cluster fill of marker ``m`` over frames ``[a, b)``.

    In every frame the cluster's other markers that are measured there (at least three, not collinear; or, as
    a weaker fallback, two: then the twist about their axis is taken from the reference) are fitted to their
    positions in two reference frames: the nearest frames before and after the interval where
    ``m`` is known and those markers are measured. The two predictions are blended by time across the interval
    (one reference only at the ends of the take), then corrected to meet the known samples at both edges.
    With ``partial``, frames that cannot be predicted are NaN instead of making the result ``None``.
    """
    return rigid_fill_many(xyz, valid, m, cluster, known_m, [(a, b)], partial)[0]


def rigid_fill_many(xyz: np.ndarray, valid: np.ndarray, m: int, cluster: list[int], known_m: np.ndarray,
                    intervals: list[tuple[int, int]], partial: bool = False) -> list[np.ndarray | None]:
    """:func:`rigid_fill` over each of ``intervals`` (the same ``valid`` and ``known_m``): occlusion patterns
    and the frames where each set of mates is complete are found once for all of them."""
    from gazepipe.stages.clean import model_kernels

    n_t = xyz.shape[0]
    cl = np.asarray(cluster, dtype=np.int64)
    others = cl[cl != m]
    if others.size < 2:
        return [None] * len(intervals)
    spans = [(max(a - 1, 0), min(b + 1, n_t)) for a, b in intervals]
    pred_all = model_kernels.rigid_predict(
        np.asarray(xyz, dtype=np.float64), np.asarray(valid, dtype=np.bool_), np.asarray(known_m, dtype=np.bool_),
        m, others, np.array([a for a, _ in intervals], dtype=np.int64),
        np.array([b for _, b in intervals], dtype=np.int64), np.array([lo for lo, _ in spans], dtype=np.int64),
        np.array([hi for _, hi in spans], dtype=np.int64), _RIGID_MIN_SPREAD_MM, _RIGID_MIN_PLANE)
    jobs = [(a, b, known_m, partial) for a, b in intervals]
    return [r[0] for r in _unpack(*_edge_correct_packed(pred_all[None], xyz[:, m], spans, jobs), jobs)]


def _flat(xyz: np.ndarray) -> np.ndarray:
    """(T, M, 3) positions as (T, 3 M) (a view when contiguous)."""
    return xyz.reshape(xyz.shape[0], -1)


def _cols3(markers: np.ndarray) -> np.ndarray:
    """Columns of markers' x, y, z in :func:`_flat`'s layout."""
    return (3 * np.asarray(markers)[:, None] + np.arange(3)).ravel()


#: fractions of the weighted variance whose component counts are a model's candidate ``k``
VAR_FRACS = (0.9, 0.99, 0.999, 0.9999, 0.99999, 0.999999)


class PcaModel:
    """Gløersen & Federolf (2016) style PCA model of all markers' coordinates for one target marker.

    Fitted on the frames where the target and every predictor are measured (optionally only within a time
    window around the gap). With ``body_frame`` the predictors' mean trajectory is subtracted from every marker
    first (a frame moving with the body, as in the paper). Coordinates are centred on the training mean (and with
    ``unit_std`` divided by their standard deviation) and each marker's columns are weighted
    by ``exp(-d² / (2 σ²))`` with ``d`` its mean distance to the target (σ = ``sigma_scale`` × the median
    distance), so nearby markers dominate the components, as in the paper's distance weighting. The target's
    coordinates in a frame are reconstructed from the scores of the first ``k`` components fitted (least
    squares) to the predictors measured in that frame. Candidate ``k`` (``self.ks``) are the numbers of
    components explaining each of ``var_fracs`` of the weighted variance; the caller picks one (by validation).

    With ``local_frame`` (``"steady"``: the three predictors whose distance to the target varied least over the
    training frames; ``"near"``: the three nearest) every frame is first expressed in the moving frame of those
    three markers (their Gram–Schmidt triad, their centroid as origin) instead of the body
    frame, so the components describe how the body part bends rather than how it turns, which a linear model
    cannot follow through large rotations. ``self.frame`` stays None (lab or body frame) when the three are
    nearly collinear.

    Several models of one marker on the same predictors and training frames (the lab frame and moving frames)
    are fitted together by :func:`fit_pca_stack` and predict together by :func:`predict_stack`; this class is
    one of them.
    """

    m: int
    predictors: np.ndarray
    #: predictors (positions in ``predictors``) whose rigid motion defines the model's moving frame, or None
    frame: np.ndarray | None
    local_frame: str | None
    body_frame: bool
    #: (3 (P + 1),) training mean and column weights of the coordinates (predictors', then the target's)
    mean: np.ndarray
    w: np.ndarray
    #: candidate component counts, the one in use, and the components (3 (P + 1), max(ks))
    ks: list[int]
    k: int
    v_all: np.ndarray

    def __init__(self, xyz: np.ndarray, valid: np.ndarray, m: int, predictors: np.ndarray, train: np.ndarray,
                 *, sigma_scale: float = PCA_SIGMA_SCALE, body_frame: bool = PCA_BODY_FRAME,
                 unit_std: bool = PCA_UNIT_STD,
                 local_frame: str | None = None, var_fracs: tuple[float, ...] = VAR_FRACS) -> None:
        xt, dist = _training_arrays(xyz, m, predictors, train)
        pick = None if local_frame is None else _frame_markers(xt, dist, local_frame)
        fitted = fit_pca_stack(m, predictors, xt, dist, [(local_frame, pick)], sigma_scale=sigma_scale,
                               body_frame=body_frame, unit_std=unit_std, var_fracs=var_fracs)[0]
        self.__dict__.update(fitted.__dict__)

    def predict(self, xyz: np.ndarray, valid: np.ndarray | None, frames: np.ndarray,
                ks: list[int] | None = None, vis: np.ndarray | None = None, *, residuals: bool = False
                ) -> np.ndarray | tuple[np.ndarray, np.ndarray]:
        """Target positions (len(ks), n, 3) in ``frames`` from the first ``k`` components for each ``k`` in
        ``ks`` (default ``[self.k]``); NaN rows where too few predictors are measured. ``vis`` (n, M) replaces
        ``valid[frames]`` as the markers measured in each of those frames (frames may repeat).

        With ``residuals``, also the RMS residual (len(ks), n) of the least-squares fit to the measured
        predictors' weighted coordinates in each frame (NaN where not predicted): how far the frame's pose is
        from what the components can express."""
        ks = [self.k] if ks is None else ks
        if vis is None:
            assert valid is not None, "predict needs valid or vis"
            vis = valid[frames]
        return predict_stack([self], xyz, frames, vis, [ks], residuals=residuals)


def fit_pca_stack(m: int, predictors: np.ndarray, xt: np.ndarray, dist: np.ndarray,
                  frames: list[tuple[str | None, np.ndarray | None]], *, sigma_scale: float = PCA_SIGMA_SCALE,
                  body_frame: bool = PCA_BODY_FRAME, unit_std: bool = PCA_UNIT_STD,
                  var_fracs: tuple[float, ...] = VAR_FRACS) -> list[PcaModel]:
    """One :class:`PcaModel` of marker ``m`` per entry of ``frames`` (``(local_frame, frame markers or None)``),
    all on the training positions ``xt`` (n, P + 1, 3) (predictors then target, mm) and distances ``dist`` (n, P):
    the coordinates of every model, their means, Gram matrices and eigendecompositions as one stack."""
    from gazepipe.stages.clean import model_kernels

    n = xt.shape[0]
    d = dist.mean(axis=0)
    sigma = sigma_scale * max(_median(d), 1.0)
    w = np.repeat(np.concatenate([np.maximum(np.exp(-(d ** 2) / (2.0 * sigma ** 2)), _PCA_MIN_WEIGHT), [1.0]]), 3)
    picks = np.array([[-1, -1, -1] if pick is None else pick for _, pick in frames], dtype=np.int64)
    # Gløersen & Federolf's body frame for the models without a moving frame: the coordinates less the mean
    # trajectory of the predictors (a frame moving with the body)
    coords = model_kernels.training_coords(np.ascontiguousarray(xt, dtype=np.float64), picks, body_frame)
    weights = np.repeat(w[None], len(frames), axis=0)
    if unit_std:
        sd = coords.std(axis=1)
        weights /= np.where(sd > 1e-6, sd, 1.0)
    mean, z = model_kernels.centred_weighted(coords, weights)
    evals, evecs = np.linalg.eigh(np.matmul(np.swapaxes(z, 1, 2), z))
    evals, evecs = evals[:, ::-1], evecs[:, :, ::-1]              # largest first
    # eigenvalues at the rounding level of the data (a rigidly translating shape in the body frame) are zero:
    # otherwise their rounding noise would decide the component counts
    tol = 1e-12 * n * np.square(mean * weights).sum(axis=1)
    evals = np.where(evals > tol[:, None], evals, 0.0)
    total = evals.sum(axis=1, keepdims=True)
    with np.errstate(invalid="ignore", divide="ignore"):
        frac = np.where(total > 0, np.cumsum(evals, axis=1) / total, 1.0)
    k_max = max(3 * predictors.size - 1, 1)
    models = []
    for i, (kind, pick) in enumerate(frames):
        model = object.__new__(PcaModel)
        model.m, model.predictors, model.frame, model.local_frame = m, predictors, pick, kind
        model.body_frame = body_frame and pick is None
        model.mean, model.w = mean[i], weights[i]
        model.ks = sorted(set(np.minimum(np.searchsorted(frac[i], var_fracs) + 1, k_max).tolist()))
        model.k = model.ks[len(model.ks) // 2]
        model.v_all = np.ascontiguousarray(evecs[i][:, :max(model.ks)])
        models.append(model)
    return models


@overload
def predict_stack(models: list[PcaModel], xyz: np.ndarray, frames: np.ndarray, vis: np.ndarray,
                  kss: list[list[int]] | None = None, *, residuals: Literal[False] = False) -> np.ndarray: ...


@overload
def predict_stack(models: list[PcaModel], xyz: np.ndarray, frames: np.ndarray, vis: np.ndarray,
                  kss: list[list[int]] | None = None, *, residuals: bool
                  ) -> np.ndarray | tuple[np.ndarray, np.ndarray]: ...


def predict_stack(models: list[PcaModel], xyz: np.ndarray, frames: np.ndarray, vis: np.ndarray,
                  kss: list[list[int]] | None = None, *, residuals: bool = False
                  ) -> np.ndarray | tuple[np.ndarray, np.ndarray]:
    """Every (model, k) candidate's target positions in ``frames``, (C, n, 3): model after model, each with its
    ``ks`` (or ``kss``), in order; NaN where the model cannot predict that frame (too few of its predictors
    measured as ``vis`` (n, M) says, or its frame markers missing). The models share the target and predictors
    (:func:`fit_pca_stack`). With ``residuals`` also the RMS residual (C, n) of each frame's fit.

    A frame's scores are the least-squares fit of the components to the predictors measured there; frames with
    the same measured predictors share one QR factorisation of those predictors' rows
    (:func:`gazepipe.stages.clean.model_kernels.predict`). The first ``k`` columns of A = QR are
    Q[:, :k] R[:k, :k], and the leading k × k block of R⁻¹ is the inverse of R's leading block (R is upper
    triangular), so one QR serves every ``k``."""
    from gazepipe.stages.clean import model_kernels

    kss = [mod.ks for mod in models] if kss is None else kss
    n = frames.size
    preds = models[0].predictors
    pts = np.ascontiguousarray(_flat(xyz)[frames][:, _cols3(preds)].reshape(n, preds.size, 3), dtype=np.float64)
    seen = np.ascontiguousarray(vis[:, preds])
    outs, ress = [], []
    for mod, ks in zip(models, kss, strict=True):
        pick = np.empty(0, dtype=np.int64) if mod.frame is None else np.asarray(mod.frame, dtype=np.int64)
        out, res = model_kernels.predict(pts, seen, pick, bool(mod.body_frame), mod.mean, mod.w, mod.v_all,
                                       np.asarray(ks, dtype=np.int64), residuals)
        outs.append(out)
        ress.append(res)
    out_all = np.concatenate(outs)
    return (out_all, np.concatenate(ress)) if residuals else out_all


def _median(v: np.ndarray) -> float:
    """``np.median`` of a short finite 1-D array (the same value), without its overhead."""
    s = sorted(v.tolist())
    h = len(s) // 2
    return s[h] if len(s) % 2 else (s[h - 1] + s[h]) / 2.0


def _training_arrays(xyz: np.ndarray, m: int, predictors: np.ndarray, train: np.ndarray
                     ) -> tuple[np.ndarray, np.ndarray]:
    """Positions (n, P + 1, 3) of the predictors then marker ``m`` in frames ``train``, and each predictor's
    distance to ``m`` (n, P), mm."""
    cols = np.append(predictors, m)
    # rows first, then the columns of the (frames, markers × 3) view: far cheaper than xyz[train][:, cols]
    xt = _flat(xyz)[train][:, _cols3(cols)].reshape(train.size, cols.size, 3)
    return xt, norm3(xt[:, :-1] - xt[:, -1:])


def _frame_markers(xt: np.ndarray, dist: np.ndarray, kind: str) -> np.ndarray | None:
    """The three predictors (positions, in index order) of a :class:`PcaModel` moving frame: ``"steady"``, those
    whose distance to the target (``dist`` (n, P) over the training frames ``xt`` (n, P + 1, 3)) varied least;
    ``"near"``, the nearest. None when there are fewer than three or they are nearly collinear or coincident in
    a typical frame (the frame's rotation would be noise)."""
    if kind not in ("steady", "near"):
        raise ValueError(f"local_frame must be None, 'steady' or 'near', not {kind!r}")
    if dist.shape[1] < 3:
        return None
    rank = dist.std(axis=0) if kind == "steady" else dist.mean(axis=0)
    pick = np.sort(np.argsort(rank, kind="stable")[:3])
    a = xt[:, pick[1]] - xt[:, pick[0]]
    b = xt[:, pick[2]] - xt[:, pick[0]]
    la, lb = norm3(a), norm3(b)
    with np.errstate(invalid="ignore", divide="ignore"):
        sin = norm3(cross3(a, b)) / (la * lb)
    if not (la.mean() > _FRAME_MIN_EDGE_MM and lb.mean() > _FRAME_MIN_EDGE_MM
            and np.mean(sin) > _FRAME_MIN_SINE):
        return None
    return pick


def fit_pca_models(xyz: np.ndarray, valid: np.ndarray, m: int, known_m: np.ndarray, a: int, b: int,
                   local_frames: tuple[str | None, ...], *, window: tuple[int, int] | None = None,
                   min_train: int = PCA_MIN_TRAIN, max_predictors: int = PCA_MAX_PREDICTORS) -> list[PcaModel]:
    """PCA models (:class:`PcaModel`) of marker ``m``, one for each of ``local_frames``, on the same predictors
    and training frames; a moving frame that cannot be set up (collinear markers), or that is made of the same
    three markers as an earlier model's, gives no model.

    Predictors: the markers measured in every frame of ``[a - 1, b + 1)`` (the gap and the edge frames its
    correction uses), only the ``max_predictors`` nearest to ``m`` (mean distance over the window): the
    distance weighting makes far markers contribute next to nothing, and the model stays small and fast.
    Training frames: ``known_m`` and every predictor measured, inside ``window`` (half-open) when given, among
    every :func:`sample_step`-th frame of it when it holds more than ``PCA_MAX_TRAIN`` (a window in seconds at a
    high capture rate: the model's cost bounded, its components those of the same motion). When fewer than
    ``min_train`` frames remain, the predictor measured least often is dropped, and so on.
    """
    chosen = _pca_training(xyz, valid, m, known_m, a, b, window, min_train, max_predictors)
    if chosen is None:
        return []
    xt, dist = _training_arrays(xyz, m, *chosen)
    frames: list[tuple[str | None, np.ndarray | None]] = []
    seen = []
    for frame in local_frames:
        pick = None if frame is None else _frame_markers(xt, dist, frame)
        key = None if pick is None else tuple(pick.tolist())
        if (frame is not None and key is None) or key in seen:
            continue
        seen.append(key)
        frames.append((frame, pick))
    return fit_pca_stack(m, chosen[0], xt, dist, frames) if frames else []


def _pca_training(xyz: np.ndarray, valid: np.ndarray, m: int, known_m: np.ndarray, a: int, b: int,
                  window: tuple[int, int] | None, min_train: int, max_predictors: int
                  ) -> tuple[np.ndarray, np.ndarray] | None:
    """Predictors and training frames of :func:`fit_pca_models` (None when fewer than ``min_train`` frames
    remain)."""
    n_t, n_m = valid.shape
    lo, hi = (0, n_t) if window is None else window
    # measured in the gap's edge frames too: the edge correction compares the prediction there with the
    # measured marker, and a prediction there from fewer predictors would carry its own error into the gap
    through = np.all(valid[max(a - 1, 0):min(b + 1, n_t)], axis=0)
    through[m] = False
    preds = np.flatnonzero(through)
    rows = known_m[lo:hi]
    vw = valid[lo:hi]
    if preds.size > max_predictors:
        step = max(1, (hi - lo) // _PCA_DISTANCE_FRAMES)
        both = vw[::step][:, preds] & rows[::step, None]
        xs = _flat(xyz)[lo:hi:step]
        # coordinate by coordinate on (frames, markers) arrays: the same sums as norm3, on contiguous data
        sq = [np.square(xs[:, 3 * preds + c] - xs[:, 3 * m + c:3 * m + c + 1]) for c in range(3)]
        d = np.sqrt(sq[0] + sq[1] + sq[2])
        with np.errstate(invalid="ignore", divide="ignore"):
            mean_d = np.where(both, d, 0.0).sum(axis=0) / both.sum(axis=0)
        mean_d[~np.isfinite(mean_d)] = np.inf
        preds = np.sort(preds[np.argsort(mean_d, kind="stable")[:max_predictors]])
    # the training frames among evenly spaced frames of the window, at most PCA_MAX_TRAIN of them
    train_step = sample_step(hi - lo, PCA_MAX_TRAIN)
    rows, vw = rows[::train_step], vw[::train_step]
    while preds.size:
        ok = rows & vw[:, preds].all(axis=1)
        if np.count_nonzero(ok) >= min_train:
            return preds, np.flatnonzero(ok) * train_step + lo
        counts = (vw[:, preds] & rows[:, None]).sum(axis=0)
        preds = np.delete(preds, int(np.argmin(counts)))
    return None


def pca_fill_packed(models: PcaModel | list[PcaModel], xyz: np.ndarray,
                    jobs: list[tuple[int, int, np.ndarray, np.ndarray, bool]],
                    ks: list[int] | None = None) -> tuple[np.ndarray, np.ndarray]:
    """PCA reconstruction of the model's marker over several intervals, ``jobs`` = ``[(a, b, valid, known_m,
    partial), ...]``, each corrected to meet the known samples next to it (:func:`_edge_correct_packed`), for
    one model (its ``ks``, default its ``k``) or for several models of the same marker (each with all its
    ``ks``, in order): one prediction over all their frames, so intervals with the same occlusion pattern share
    its least-squares factorisation. Returns ``(filled, none)``: ``filled`` (predictions, Σ (b − a), 3) the
    intervals one after the other (NaN where not predicted; with ``partial`` false an interval with such a frame
    has none), ``none`` (predictions, len(jobs)) True where an interval has no prediction."""
    if isinstance(models, PcaModel):
        kss = [ks or [models.k]]
        models = [models]
    else:
        kss = [mod.ks for mod in models]
    n_t = xyz.shape[0]
    spans = [(max(a - 1, 0), min(b + 1, n_t)) for a, b, *_ in jobs]
    frames = np.concatenate([np.arange(lo, hi) for lo, hi in spans])
    vis = np.concatenate([valid[lo:hi] for (lo, hi), (_, _, valid, _, _) in zip(spans, jobs, strict=True)])
    preds = predict_stack(models, xyz, frames, vis, kss)
    return _edge_correct_packed(preds, xyz[:, models[0].m], spans, [(a, b, known_m, partial)
                                                                    for a, b, _, known_m, partial in jobs])


def _unpack(filled: np.ndarray, none: np.ndarray, jobs: list[tuple]) -> list[list[np.ndarray | None]]:
    """:func:`_edge_correct_packed`'s result as one list (over predictions) of arrays or None per job."""
    offs = np.cumsum([0] + [b - a for a, b, *_ in jobs]).tolist()
    return [[None if none[k, j] else filled[k, offs[j]:offs[j + 1]] for k in range(filled.shape[0])]
            for j in range(len(jobs))]


def _edge_correct_packed(preds: np.ndarray, xyz_m: np.ndarray, spans: list[tuple[int, int]],
                         jobs: list[tuple[int, int, np.ndarray, bool]]) -> tuple[np.ndarray, np.ndarray]:
    """Each of ``preds`` (K, F, 3) corrected to meet the known samples next to each interval, all at once:
    ``jobs`` = ``[(a, b, known_m, partial), ...]`` whose predictions over ``spans`` ``[(lo, hi), ...]`` (``lo =
    a - 1`` and ``hi = b + 1`` inside the take) lie one after the other along F.

    The mismatches at frames ``a - 1`` and ``b`` (where ``known_m`` and predicted) are blended linearly across
    ``[a, b)``; with one of them only, it is added throughout (the two-sided formula with weight 0 or 1 on a
    zero residual, which adds exact zeros). An interval with an unpredicted (NaN) frame is None unless
    ``partial`` (its NaN rows then stay NaN); with no predicted frame it is None. Returns ``(filled, none)`` as
    :func:`pca_fill_packed` does."""
    from gazepipe.stages.clean import kernels

    lo = np.array([x for x, _ in spans], dtype=np.int64)
    hi = np.array([x for _, x in spans], dtype=np.int64)
    a = np.array([j[0] for j in jobs], dtype=np.int64)
    b = np.array([j[1] for j in jobs], dtype=np.int64)
    # whether the marker is known in the frame before each interval and the one after it (inside its span)
    known_l = np.array([a_ - 1 >= lo_ and bool(j[2][a_ - 1]) for a_, lo_, j in zip(a.tolist(), lo.tolist(), jobs,
                                                                                      strict=True)], dtype=bool)
    known_r = np.array([b_ < hi_ and bool(j[2][b_]) for b_, hi_, j in zip(b.tolist(), hi.tolist(), jobs,
                                                                            strict=True)], dtype=bool)
    partial = np.array([j[3] for j in jobs], dtype=bool)
    # the marker's column as it is (a strided view): copying it would cost the neighbourhood's length
    return kernels.edge_correct(np.ascontiguousarray(preds, dtype=np.float64), np.asarray(xyz_m, dtype=np.float64),
                                lo, hi, a, b, partial, known_l, known_r)


def donor_interp_errors(xyz: np.ndarray, valid: np.ndarray, m: int, s: int, e: int,
                         methods: list[str], n_donors: int = _N_DONORS, *, window: int | None = None,
                         max_std_mm: float = MATES_MAX_STD_MM) -> dict[str, float]:
    """Mean error (mm) of each interpolation method over frames ``[s, e)`` of the ``n_donors`` markers nearest
    to ``m`` that are measured there and on both sides (NaN when there is none).

    With ``window``, only markers that move with ``m`` count: those whose distance to it has a standard deviation
    below ``max_std_mm`` over ``window`` frames each side (:func:`distance_sd`). A marker on another body part
    (the other foot, 300 mm away, swinging while this one stands) says nothing of this one's motion."""
    n_t = valid.shape[0]
    lo, hi = s - _N_ANCHORS, e + _N_ANCHORS
    if not methods or lo < 0 or hi > n_t:
        return {}
    cand = np.flatnonzero(valid[lo:hi].all(axis=0))
    cand = cand[cand != m]
    if window is not None and cand.size:
        cand = cand[distance_sd(xyz, valid, m, cand, s, e, window) < max_std_mm]
    if cand.size == 0:
        return {meth: float("nan") for meth in methods}
    # distance to the target on the measured frames next to the gap
    near = np.array([s - 1, e])
    d = norm3(xyz[near][:, cand] - xyz[near][:, [m]]).mean(axis=0)
    donors = cand[np.argsort(d, kind="stable")[:n_donors]]
    # the donors are measured on the _N_ANCHORS frames each side, the knots interp_fill would use: one
    # interpolant for all of them at once
    knots = np.r_[lo:s, e:hi]
    y = xyz[knots][:, donors].reshape(knots.size, -1)
    t = np.arange(s, e, dtype=np.float64)
    truth = xyz[s:e][:, donors]
    out: dict[str, float] = {}
    for meth in methods:
        if meth == "linear":
            w = ((t - (s - 1)) / (e - (s - 1)))[:, None]
            q = (1.0 - w) * xyz[s - 1, donors].reshape(1, -1) + w * xyz[e, donors].reshape(1, -1)
        else:
            q = pchip_eval(knots, y, t)
        err = norm3(q.reshape(e - s, donors.size, 3) - truth)
        out[meth] = float(err.mean(axis=0).mean())
    return out


def find_steady_mates(xyz: np.ndarray, valid: np.ndarray, m: int, s: int, e: int, window: int,
                  n_mates: int = 3, max_std_mm: float = MATES_MAX_STD_MM) -> list[int] | None:
    """A rigid cluster for marker ``m`` around gap ``[s, e)`` when it has none: the ``n_mates`` markers measured
    through the gap whose distance to ``m`` varied least (standard deviation below ``max_std_mm``) over the
    ``window`` frames on each side where both are measured. ``None`` when fewer than two qualify."""
    cand = np.flatnonzero(valid[s:e].all(axis=0))
    cand = cand[cand != m]
    if cand.size < 2:
        return None
    sd = distance_sd(xyz, valid, m, cand, s, e, window)
    order = np.argsort(sd, kind="stable")[:n_mates]
    mates = cand[order[sd[order] < max_std_mm]]
    return None if mates.size < 2 else [m, *sorted(int(j) for j in mates)]


def distance_sd(xyz: np.ndarray, valid: np.ndarray, m: int, cand: np.ndarray, s: int, e: int,
                window: int) -> np.ndarray:
    """Standard deviation (mm) of each of markers ``cand``'s distance to marker ``m`` over the frames from
    ``window`` before gap ``[s, e)`` to ``window`` after it where both are measured (inf with fewer than 10)."""
    return distance_stats(xyz, valid, m, cand, s, e, window)[1]


def distance_stats(xyz: np.ndarray, valid: np.ndarray, m: int, cand: np.ndarray, s: int, e: int, window: int,
                   known_m: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Mean and standard deviation (mm) of each of markers ``cand``'s distance to marker ``m`` over the frames
    within ``window`` of gap ``[s, e)`` where both are measured (and ``known_m``, when given, is True); the
    deviation is inf with fewer than 10 such frames. A window of more than ``WINDOW_SAMPLES`` frames is read at
    every :func:`sample_step`-th frame: the statistics of a few thousand evenly spaced samples, whatever the rate."""
    from gazepipe.stages.clean import kernels

    n_t = valid.shape[0]
    lo, hi = max(0, s - window), min(n_t, e + window)
    own = valid[:, m] if known_m is None else known_m
    n, mu, sd = kernels.distance_moments(np.asarray(xyz, dtype=np.float64), np.asarray(valid, dtype=np.bool_),
                                         np.asarray(own, dtype=np.bool_), m, np.asarray(cand, dtype=np.int64), lo,
                                         hi, sample_step(hi - lo, WINDOW_SAMPLES))
    sd[(n < 10) | ~np.isfinite(sd)] = np.inf
    return mu, sd


def pca_novelty(model: PcaModel, xyz: np.ndarray, valid: np.ndarray, valid_v: np.ndarray,
                wins: list[tuple[int, int]], s: int, e: int) -> float:
    """How much worse ``model`` explains its predictors in gap ``[s, e)`` than in the hidden stretches ``wins``:
    RMS fit residual over the gap's frames (measured as in ``valid``) over that of the stretches' frames
    (measured as in ``valid_v``). Above 1 when the gap's poses are unlike the training frames, which the
    stretches' validation error cannot show. NaN when either has no predicted frame.

    The residual is taken with the model's ``k`` components, but at most two thirds of the predictors'
    coordinates: with nearly all of them fitted, the few left hold only the smallest, noise-level components and
    the ratio says nothing (on a still-move-still take, 30 of 33 gave 2.6 to 4.2 depending on the BLAS build;
    10 gives 141)."""
    fh = np.concatenate([np.arange(a, b) for a, b in wins]) if wins else np.empty(0, dtype=np.int64)
    fg = np.arange(s, e)
    k = min(model.k, max(1, 2 * 3 * model.predictors.size // 3))
    _, r = model.predict(xyz, None, np.concatenate([fh, fg]), [k],
                         vis=np.concatenate([valid_v[fh], valid[fg]]), residuals=True)
    rh, rg = r[0, :fh.size], r[0, fh.size:]
    rh, rg = rh[np.isfinite(rh)], rg[np.isfinite(rg)]
    if not rh.size or not rg.size:
        return float("nan")
    den = float(np.sqrt(np.mean(np.square(rh))))
    return float(np.sqrt(np.mean(np.square(rg)))) / den if den > 0 else float("nan")


def edge_speed(xyz_m: np.ndarray, valid_m: np.ndarray, s: int, e: int) -> float:
    """How fast a marker moves about gap ``[s, e)``, mm per frame: the largest of its mean speed over the
    ``_N_ANCHORS`` measured frames before the gap, over those after it, and its net displacement across the gap
    per frame (inf when none of them can be measured)."""
    n_t = xyz_m.shape[0]
    n = _N_ANCHORS
    sp = [speed_over(xyz_m, [(a, b)]) for a, b in ((s - n - 1, s), (e, e + n + 1))
          if a >= 0 and b <= n_t and valid_m[a:b].all()]
    if s > 0 and e < n_t and valid_m[s - 1] and valid_m[e]:
        sp.append(float(norm3(xyz_m[e] - xyz_m[s - 1])) / (e - s + 1))
    return max(sp) if sp else float("inf")


def speed_over(xyz_m: np.ndarray, intervals: list[tuple[int, int]]) -> float:
    """A marker's mean speed (mm per frame) over the measured ``intervals`` ``[(a, b), ...]`` (0 when none has
    two frames)."""
    d = [norm3(np.diff(xyz_m[a:b], axis=0)) for a, b in intervals if b - a >= 2]
    return float(np.concatenate(d).mean()) if d else 0.0
