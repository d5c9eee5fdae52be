"""What each stage parameter means, for ``gazepipe params``: the first sentence of its entry in the numpy-style
docstring of the code that declares it (``name : meaning``, or ``a, b : meaning`` for several)."""

from __future__ import annotations

import inspect
import re
from collections.abc import Callable
from typing import Any

_ENTRY = re.compile(r"^([A-Za-z_]\w*(?:\s*,\s*[A-Za-z_]\w*)*)\s+:\s*(.*)$")
_ROLE = re.compile(r":(?:func|meth):`~?(?:[\w.]*\.)?(\w+)`")
_OTHER_ROLE = re.compile(r":\w+:`~?(?:[\w.]*\.)?([^`]+)`")


def documented_by() -> dict[str, Callable[..., Any] | type]:
    """Each parameter group (a stage, or ``build``) → the class or function whose docstring documents its
    parameters. A group missing here has no meanings (the tests require every parameter to have one)."""
    from gazepipe.stages.build.stage import BuildParams
    from gazepipe.stages.clean.stage import CleanParams
    from gazepipe.stages.eyes.params import EyesParams
    from gazepipe.stages.face.stage import align_face
    from gazepipe.stages.frames.stage import FramesParams
    from gazepipe.stages.sync.stage import SyncParams

    return {"clean": CleanParams, "frames": FramesParams, "sync": SyncParams, "eyes": EyesParams,
            "face": align_face, "build": BuildParams}


def docstring_entries(doc: str) -> dict[str, str]:
    """Every ``name : text`` entry of a numpy-style docstring (continuation lines indented under it), by name,
    the text on one line; the first entry of a name wins."""
    out: dict[str, str] = {}
    names: list[str] = []
    text: list[str] = []

    def close() -> None:
        for n in names:
            out.setdefault(n, " ".join(text))

    for line in inspect.cleandoc(doc).splitlines():
        m = _ENTRY.match(line)
        if m:
            close()
            names = [n.strip() for n in m.group(1).split(",")]
            text = [m.group(2).strip()]
        elif line.startswith((" ", "\t")) and line.strip() and names:
            text.append(line.strip())
        else:
            close()
            names, text = [], []
    close()
    return out


def first_sentence(text: str) -> str:
    """The first sentence of ``text`` (a full stop followed by a capital, outside brackets), reST markup
    turned into plain text."""
    text = _ROLE.sub(r"\1()", text)
    text = _OTHER_ROLE.sub(r"\1", text).replace("``", "").replace("*", "")
    depth = 0
    for i, ch in enumerate(text):
        depth += (ch in "([{") - (ch in ")]}")
        if ch == "." and depth <= 0 and text[i + 1:i + 2] == " " and text[i + 2:i + 3].isupper():
            return text[:i + 1]
    return text


def param_meanings() -> dict[str, str]:
    """``"group.param"`` → one line saying what it means, for every parameter that is documented."""
    out: dict[str, str] = {}
    for group, obj in documented_by().items():
        for name, text in docstring_entries(inspect.getdoc(obj) or "").items():
            sentence = first_sentence(text).strip()
            if sentence:
                out[f"{group}.{name}"] = sentence
    return out


#: what ``gazepipe params`` says of each parameter: one short line for the person setting it (the meanings
#: above, from the code's docstrings, are the long form)
USER_HELP: dict[str, str] = {
    "clean.max_gap_s": "longest gap, in s, that gets filled; longer gaps stay gaps",
    "clean.max_fill_error_mm": "fill a gap only when its fill's estimated error is at most this, in mm",
    "clean.max_target_fill_error_deg": "the same for the gaze target marker, as an angle seen from the head, "
                                       "in degrees",
    "clean.remove_spikes": "turn spikes (ghost samples, impossible jumps) into gaps before filling",
    "clean.spike_residual_mm": "a sample this far (mm) from the median of its neighbours in time is a spike",
    "clean.spike_step_factor":
        "a sample farther from that median than this many times the marker's usual step is a spike",
    "clean.spike_cluster_mm": "a sample whose distances to its segment's other markers are off by this (mm) "
                              "is a spike",
    "clean.spike_max_accel_mm_s2": "acceleration above this (mm/s², 50 g) is impossible: a spike",
    "clean.spike_min_step_mm": "a jump between frames smaller than this (mm) is never a spike, whatever its acceleration",
    "clean.spike_max_piece_s": "stretches shorter than this (s) cut off between spikes become gaps too",
    "clean.fill_methods": "the gap-filling methods tried; the best one is chosen for each gap",
    "clean.lowpass_hz": "cutoff, in Hz, of a zero-phase low-pass on the cleaned markers (off by default)",
    "clean.lowpass_order": "order of that low-pass (2: a 4th-order filter forward and backward)",
    "clean.rest_speed_mm_s": "the subject rests while the mean marker speed is below this, in mm/s",
    "clean.rest_merge_s": "rests less than this apart (s) merge into one",
    "clean.rest_min_s": "rests shorter than this (s) do not count",
    "clean.rest_filter_hz": "low-pass, in Hz, of the positions the rest speed is measured on",
    "clean.rest_refine": "move the end of each long rest to where the movement really starts",
    "clean.remove_heading": "turn every frame so the subject faces the same way (lab +X to their left)",
    "clean.repair_swaps": "find markers that swapped labels and put their samples back under their own names",
    "clean.fill_unlabeled": "also fill unlabeled trajectories (*12, Unlabeled 3, ...); off: their gaps stay",
    "clean.fill_still_gaps": "fill a longer gap too where its marker is still on both sides and its body through it",
    "clean.swap_tolerance": "how far off (in spreads of a marker-to-marker distance) a sample is suspect of "
                            "a swap",
    "frames.min_neutral_frames": "fewest neutral-pose frames needed to calibrate a segment",
    "frames.head_segment": "the head segment, which carries the eyes (default: the one named head, else the last)",
    "frames.triangle": "how a three-marker segment's frame is built: rigid_fit or gram_schmidt",
    "frames.min_plane_ratio": "fit a segment to some of its markers only when they are not nearly in a line",
    "frames.max_fill_error_deg": "fill a segment's rotation across a marker gap when its estimated error is "
                                 "at most this, in degrees (0: off)",
    "frames.max_fit_uncertainty_deg": "a rotation fitted to filled markers more uncertain than this (degrees) is "
                                      "treated as a gap (0: never)",
    "frames.jump_factor": "a step this many typical departures off the angular velocity is a jump (0: no flips)",
    "frames.min_jump_deg": "the smallest departure from a segment's angular velocity that is a jump (degrees)",
    "frames.max_flip_s": "the longest a rotation may stay away between a jump and its return to be a flip (s)",
    "face.k": "highest time derivative of the blendshapes to compute",
    "sync.window_s": "half-width, in s, of the video window searched around each expected clap",
    "sync.search_s": "how far into the video (s, from the start or the end) to look for the first clap",
    "sync.max_drift": "largest clock-rate difference cameras show (0.001 = 0.1 %); claps beyond it are set aside",
    "sync.min_confidence": "video claps below this confidence count as not found",
    "sync.video_scale": "video frames are scaled by this before looking for claps (faster when smaller)",
    "eyes.min_confidence": "OpenFace samples below this confidence are not used",
    "eyes.max_eye_gap_s": "longest run of unusable eye samples, in s, bridged by interpolation",
    "eyes.head_segment": "the head segment the gaze is measured from (default: the one named head, else the last)",
    "eyes.smooth_s": "smoothing window, in s, of the gaze directions used to find fixations",
    "eyes.max_target_speed_deg_s": "frames where the target moves faster than this (degrees/s) are not used "
                                   "to find the camera rotation",
    "eyes.max_gaze_speed_deg_s": "frames where the gaze moves faster than this (degrees/s) are not used either",
    "eyes.settle_s": "frames this soon (s) after a fast target move are not used either",
    "eyes.max_eccentricity_deg": "frames whose target is further than this (degrees) from straight ahead are not used",
    "eyes.max_lag_s": "longest delay, in s, of the eyes behind the target that is searched",
    "eyes.keep_percentile": "after each fit, frames whose error is above this percentile are left out",
    "eyes.refit_iterations": "how many times the camera rotation is re-fitted without the worst frames",
    "eyes.min_fixation_frames": "fewest usable frames needed to estimate the camera rotation",
    "eyes.min_target_spread_deg": "warn when the targets looked at span less than this, in degrees",
    "build.train_frac": "share of the takes in the training split",
    "build.val_frac": "share of the takes in the validation split (the rest is the test split)",
    "build.split_salt": "change it to draw another (still reproducible) assignment of takes to splits",
    "build.mirror": "add a left-right mirrored copy of every row",
    "build.rnn_window": "frames per training sequence of the gaze_rnn datasets",
    "build.rnn_stride": "frames between the starts of two gaze_rnn sequences",
    "build.face_window": "frames per training sequence of the face_clean dataset",
    "build.face_stride": "frames between the starts of two face_clean sequences",
    "build.start_speed_deg_s": "gaze_map: a joint starts moving when its speed passes this, in degrees/s",
    "build.start_filter_hz": "gaze_map: low-pass, in Hz, of the rotations before measuring that speed",
    "build.start_min_s": "gaze_map: the speed must stay above the threshold this long, in s",
    "build.overshoot_window_s": "gaze_map: window, in s, each side of a peak that confirms an overshoot",
    "build.max_bridge_s": "gaze_map: missing rotations up to this long, in s, are bridged; longer ones leave "
                          "the event unknown",
    "build.head_segment": "gaze_map: name of the head segment (default: the one named head, else the last)",
}


def user_help() -> dict[str, str]:
    """``"group.param"`` → the short line ``gazepipe params`` prints; the docstring meaning where none is
    written here."""
    return {**param_meanings(), **USER_HELP}
