"""Write a whole synthetic capture session (SPEC §1) with its ground truth beside it."""

from __future__ import annotations

import functools
import json
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
from scipy.spatial.transform import Rotation

from gazepipe.synth.markers import (
    apply_label_swaps,
    build_kinematics,
    gap_runs,
    make_gaps,
    make_label_swaps,
    make_long_gaps,
    make_occlusion_bursts,
    make_root_rest_gap,
    make_spikes,
)
from gazepipe.synth.motion import follow_motion, neutral_motion, shift_motion
from gazepipe.synth.record import ModalityWriter, TakeRecord
from gazepipe.synth.skeleton import (
    CLAPPER_MARKERS,
    HEAD_CENTRE_MARKER,
    ROOT_MARKER,
    SEGMENT_MARKERS,
    SEGMENTS,
    TARGET_MARKER,
    Placement,
    camera_to_head,
    eye_offset_mm,
)
from gazepipe.synth.truth import crop_bounds, quat_wxyz, rest_periods, subject_columns, take_truth, write_npz

MOCAP_RATE_HZ = 30000.0 / 1001.0
GENERATOR_VERSION = 3

#: the gaze_shift targets of the sample session (a part of Pejsa's 36° x 12° grid)
DEFAULT_SHIFTS: tuple[tuple[float, float], ...] = (
    (36.0, 12.0), (-36.0, 0.0), (72.0, 0.0), (-72.0, 12.0), (0.0, 12.0), (36.0, -12.0), (-72.0, -12.0),
    (72.0, 12.0), (-36.0, -12.0),
)


@dataclass(frozen=True)
class SynthConfig:
    """What to generate.

    ``follow_poses``: one gaze_follow take per entry (pose names; unknown poses move like ``standing``);
    ``follow_duration_s``: approximate length of each; ``shift_targets``: (yaw, pitch) degrees per gaze_shift
    take; ``neutral_s``: length of the neutral take (0: none); ``noise_mm``: marker noise sigma;
    ``head_camera``: write a head-camera video and an OpenFace CSV per gaze_follow take;
    ``face_takes``: one ``face`` take (Live Link Face tracked/clean pair) per (capture rate Hz, seconds);
    ``spikes_per_marker_min``: ghost-reflection spikes (15–50 mm, 1–2 frames) per marker per minute of capture,
    on any marker (0: none; the truth marks them in ``spike_mask``); ``long_gaps``: 1–3 s occlusions of trunk
    and neck markers per mocap take (the first inside the first rest, the next two across the crop's edges);
    ``gaps_per_marker_min``: further interior gaps of 1–120 frames per subject marker per minute;
    ``rate_hz``: the mocap capture rate; ``segments``: the segments that carry markers (all ten, or a subset
    with the pelvis and the head such as ``FOUR_SEGMENTS``; the truth keeps the ten segments of the moving
    chain); ``up_axis``: the lab's vertical axis in the written files (``"z"`` or ``"y"``; truth lab arrays
    follow it); ``body_steps``: share of gaze_shift takes in which the whole body steps 40–150 mm over
    0.8–1.4 s as the gaze change ends (the truth's rests follow the body in the room); ``root_rest_gaps``: one
    0.5–1.5 s gap per mocap take on a root-segment marker inside a rest; ``clap_rebounds``: share of claps whose
    stick bounces open 3–6 mm for one to two mocap frames right after contact (on the mocap and the video);
    ``blink_every_s``, ``eye_dip_every_s``: the range of seconds between blinks and between OpenFace confidence
    dips (each blink longer than the eyes stage bridges ends a run of usable gaze_follow frames);
    ``more_follow`` (pose, seconds) and ``more_face_takes`` (rate Hz, seconds): takes generated after all the
    others, so the others stay as they were; ``label_swaps``: stretches of 0.3–3 s per mocap take in which two
    markers carry each other's names (:func:`~gazepipe.synth.markers.make_label_swaps`: two markers of a segment,
    close markers of neighbouring segments, left and right; half of them at a gap's edge; the truth marks the
    samples written under the wrong name in ``swap_mask`` and lists the stretches in ``swaps``);
    ``occlusion_bursts``: per mocap take, moments when 30–80 % of the subject's markers, on one side of the body,
    vanish at once for 0.2–1.5 s (:func:`~gazepipe.synth.markers.make_occlusion_bursts`); ``clap_hazards``:
    share of gaze_follow takes with one of the clapper's hazards on one of its claps, the kinds taking turns
    over the session (:data:`CLAP_HAZARDS`, :func:`clap_hazard`; the truth's ``design.clap_hazard`` says which);
    ``own_motion_deg``: in gaze_follow takes each segment also turns on its own, smooth (below 1.5 Hz) and
    unlike its neighbours, by this RMS angle per axis (degrees; trunk twists and leans, nods), rests kept still
    (:func:`~gazepipe.synth.motion.follow_motion`).
    """

    follow_poses: tuple[str, ...] = ("standing", "standing", "sitting")
    follow_duration_s: float = 45.0
    shift_targets: tuple[tuple[float, float], ...] = DEFAULT_SHIFTS
    neutral_s: float = 4.0
    noise_mm: float = 0.5
    gaps: bool = True
    session_id: str = "session01"
    subject: str = "p01"
    placement: Placement = field(default_factory=Placement)
    head_camera: bool = True
    face_takes: tuple[tuple[float, float], ...] = ((60.0, 16.0), (30.0, 20.0))
    spikes_per_marker_min: float = 0.0
    long_gaps: int = 0
    gaps_per_marker_min: float = 0.0
    rate_hz: float = MOCAP_RATE_HZ
    segments: tuple[str, ...] = SEGMENTS
    up_axis: str = "z"
    body_steps: float = 0.0
    root_rest_gaps: bool = False
    clap_rebounds: float = 0.0
    blink_every_s: tuple[float, float] = (2.0, 6.0)
    eye_dip_every_s: tuple[float, float] = (1.5, 5.0)
    more_follow: tuple[tuple[str, float], ...] = ()
    more_face_takes: tuple[tuple[float, float], ...] = ()
    label_swaps: int = 0
    occlusion_bursts: int = 0
    clap_hazards: float = 0.0
    own_motion_deg: float = 0.0


#: the clapper's hazards (SPEC §3.4): a slow, soft clap; the clapper partly hidden from the camera (an occluder
#: over most of its arms, coming in a second before the clap); one or two video frames dropped shortly before a
#: clap while the container keeps stamping frames at the nominal rate; a clapper marker missing across the contact
CLAP_HAZARDS = ("weak", "hidden", "dropped_frames", "clapper_gap")


def clap_hazard(rng: np.random.Generator, kind: str, rate_hz: float) -> dict[str, Any]:
    """One clap hazard of ``kind`` on clap 0 or 1 of a gaze_follow take, with its drawn parameters (seconds on
    the mocap clock, relative to the clap's contact where they are times)."""
    out: dict[str, Any] = {"kind": kind, "clap": int(rng.integers(2))}
    if kind == "weak":
        out.update(closing_s=float(rng.uniform(0.3, 0.5)), depth=float(rng.uniform(0.3, 0.5)),
                   softness=float(rng.uniform(0.6, 0.9)))
    elif kind == "hidden":
        out.update(visible=float(rng.uniform(0.1, 0.3)), enter_s=-float(rng.uniform(0.9, 1.2)),
                   leave_s=float(rng.uniform(0.5, 0.8)))
    elif kind == "dropped_frames":
        out.update(frames=int(rng.integers(1, 3)), before_s=float(rng.uniform(0.2, 0.8)))
    elif kind == "clapper_gap":
        out.update(marker=int(rng.integers(2)), start_frames=int(rng.integers(1, 3)),
                   frames=int(rng.integers(2, 6)))
    else:
        raise ValueError(f"unknown clap hazard {kind!r} (one of {', '.join(CLAP_HAZARDS)})")
    return out


def clapper_gap(labels: list[str], n: int, rate_hz: float, clap_times_s: np.ndarray, hazard: dict[str, Any]
                ) -> np.ndarray:
    """(n, M) gap mask: one clapper marker missing for ``frames`` frames from ``start_frames`` frames before the
    hazard's clap's contact (so across it)."""
    mask = np.zeros((n, len(labels)), dtype=bool)
    col = labels.index(CLAPPER_MARKERS[hazard["marker"]])
    contact = int(np.floor(float(clap_times_s[hazard["clap"]]) * rate_hz))
    start = max(0, contact - hazard["start_frames"] + 1)
    mask[start:min(n, start + hazard["frames"]), col] = True
    return mask


def sample_config() -> SynthConfig:
    """The bundled sample session (``sample_data/session01``): small, but fair to every dataset. The default
    capture (neutral, three 45 s gaze_follow takes, nine gaze_shift takes, two face takes) plus two 24 s
    gaze_follow and three short face takes generated after them (five of each, so train, val and test each get
    one), with eye tracking as a well-lit head camera gives it during a visual-following task (blinks every
    7–15 s, fewer than at rest; confidence dips every 15–30 s: Klein 5.2's LED-lit camera), so 4-second training
    windows fit between them."""
    return SynthConfig(more_follow=(("standing", 24.0), ("sitting", 24.0)),
                       more_face_takes=((60.0, 10.0), (30.0, 12.0), (60.0, 8.0)),
                       blink_every_s=(7.0, 15.0), eye_dip_every_s=(15.0, 30.0))


#: Klein, Table 1: seconds of gaze-following capture per pose (60,800 frames in all)
KLEIN_POSE_SECONDS: dict[str, float] = {"standing": 633.33, "sitting": 633.33, "laying": 280.0, "walking": 480.0}


def klein_config(scale: float = 1.0, take_s: float = 60.0, seed_session: str = "klein") -> SynthConfig:
    """A gaze_follow corpus the size of Klein's (Table 1) times ``scale``: per pose, enough ``take_s`` takes to
    cover its share. Poses without a motion profile of their own (laying, walking) move like standing."""
    poses: list[str] = []
    for pose, secs in KLEIN_POSE_SECONDS.items():
        poses.extend([pose] * max(1, int(round(secs * scale / take_s))))
    return SynthConfig(follow_poses=tuple(poses), follow_duration_s=take_s, shift_targets=(), neutral_s=4.0,
                       session_id=seed_session, face_takes=())


def write_c3d(path: Path, labels: list[str], xyz: np.ndarray, rate_hz: float) -> None:
    """C3D with float storage, POINT:UNITS mm, first frame 1; NaN samples are written as gaps
    (residual −1, coordinates 0). Takes of more than 65,535 frames (the header's 16-bit word) also say their
    frame range in TRIAL:ACTUAL_START_FIELD / ACTUAL_END_FIELD (low and high 16-bit words), as Vicon does."""
    import ezc3d

    c = ezc3d.c3d()
    c["parameters"]["POINT"]["RATE"]["value"] = [rate_hz]
    c["parameters"]["POINT"]["LABELS"]["value"] = tuple(labels)
    c["parameters"]["POINT"]["UNITS"]["value"] = ["mm"]
    pts = np.ones((4, len(labels), xyz.shape[0]))
    pts[:3] = np.transpose(xyz, (2, 1, 0))
    c["data"]["points"] = pts
    n_frames = xyz.shape[0]
    if n_frames > 65535:
        c.add_parameter("TRIAL", "ACTUAL_START_FIELD", [1, 0])
        c.add_parameter("TRIAL", "ACTUAL_END_FIELD", [n_frames % 65536, n_frames // 65536])
    c.write(str(path))


#: lab axes of a y-up capture from the generator's z-up ones: a right-handed turn of −90° about x
Y_UP = np.array([[1.0, 0.0, 0.0], [0.0, 0.0, 1.0], [0.0, -1.0, 0.0]])
#: truth arrays of lab points and of lab-from-something rotations (w, x, y, z)
_LAB_POINTS = ("markers_true", "joints_lab", "char_origin_lab", "fixation_lab")
_LAB_ROTATIONS = ("seg_quat_lab", "char_quat_lab")


def _lab_axes(up_axis: str) -> np.ndarray:
    """Rotation from the generator's z-up lab axes to the written files' (identity for z-up)."""
    return Y_UP if up_axis == "y" else np.eye(3)


def _relabel_lab(arrays: dict[str, np.ndarray], axes: np.ndarray) -> None:
    """Truth arrays in the written files' lab axes (in place)."""
    turn = Rotation.from_matrix(axes)
    for name in _LAB_POINTS:
        arrays[name] = (arrays[name].astype(np.float64) @ axes.T).astype(arrays[name].dtype)
    for name in _LAB_ROTATIONS:
        q = arrays[name].astype(np.float64)
        r = turn * Rotation.from_quat(q.reshape(-1, 4)[:, [1, 2, 3, 0]])
        arrays[name] = quat_wxyz(r).reshape(q.shape).astype(arrays[name].dtype)


def markerset_toml(segments: tuple[str, ...] = SEGMENTS, up_axis: str = "z") -> str:
    """markerset.toml text (SPEC §1) for markers on ``segments``, each the parent of the next. The camera
    rotation is left out: the pipeline estimates it."""
    off = eye_offset_mm()
    lines = [
        "schema = 1",
        f'up_axis = "{up_axis}"',
        'units = "mm"',
        f'root = "{ROOT_MARKER}"',
        f'target = "{TARGET_MARKER}"',
        f'clapper = ["{CLAPPER_MARKERS[0]}", "{CLAPPER_MARKERS[1]}"]',
        f'head_centre = "{HEAD_CENTRE_MARKER}"',
        f"eye_offset_mm = [{off[0]:.1f}, {off[1]:.1f}, {off[2]:.1f}]",
        "",
    ]
    for k, name in enumerate(segments):
        lines.append(f"[segments.{name}]")
        lines.append("markers = [" + ", ".join(f'"{m}"' for m in SEGMENT_MARKERS[name]) + "]")
        if k:
            lines.append(f'parent = "{segments[k - 1]}"')
        lines.append("")
    lod = [s for s in ("pelvis", "chest", "head") if s in segments]
    lines += ["[lod]", "segments = [" + ", ".join(f'"{s}"' for s in lod) + "]", ""]
    return "\n".join(lines)


def _toml_value(v: Any) -> str:
    if isinstance(v, str):
        return json.dumps(v)
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, dict):
        return "{ " + ", ".join(f"{k} = {_toml_value(x)}" for k, x in v.items()) + " }"
    if isinstance(v, float):
        return repr(v)
    return str(v)


def session_toml(cfg: SynthConfig, takes: list[TakeRecord]) -> str:
    lines = ["schema = 1", "", "[session]", f'id = "{cfg.session_id}"', f'subject = "{cfg.subject}"',
             'markerset = "markerset.toml"', ""]
    for t in takes:
        lines.append("[[takes]]")
        lines.extend(f"{k} = {_toml_value(v)}" for k, v in t.entries.items())
        lines.append("")
    return "\n".join(lines)


def _take_plan(cfg: SynthConfig) -> list[tuple[str, str, str, tuple[float, float] | None]]:
    plan: list[tuple[str, str, str, tuple[float, float] | None]] = []
    if cfg.neutral_s > 0:
        plan.append(("neutral", "neutral", "standing", None))
    counts: dict[str, int] = {}
    for pose in cfg.follow_poses:
        counts[pose] = counts.get(pose, 0) + 1
        plan.append((f"follow_{pose}_{counts[pose]:02d}", "gaze_follow", pose, None))
    for yaw, pitch in cfg.shift_targets:
        ys = "m" if yaw < 0 else ""
        ps = "m" if pitch < 0 else ""
        plan.append((f"shift_y{ys}{abs(yaw):03.0f}_p{ps}{abs(pitch):02.0f}", "gaze_shift", "standing",
                     (float(yaw), float(pitch))))
    for k, (rate, secs) in enumerate(cfg.face_takes):
        plan.append((f"face_{k + 1:02d}", "face", "", (float(rate), float(secs))))
    # takes added after the others keep the others' random streams (a stream per take index) as they were
    for pose, secs in cfg.more_follow:
        counts[pose] = counts.get(pose, 0) + 1
        plan.append((f"follow_{pose}_{counts[pose]:02d}", "gaze_follow", pose, (float(secs), 0.0)))
    for k, (rate, secs) in enumerate(cfg.more_face_takes, start=len(cfg.face_takes)):
        plan.append((f"face_{k + 1:02d}", "face", "", (float(rate), float(secs))))
    return plan


def builtin_writers(cfg: SynthConfig) -> list[ModalityWriter]:
    """The modality writers the configuration asks for (head camera video + OpenFace, Live Link Face)."""
    from gazepipe.synth.headcam import head_camera_writer
    from gazepipe.synth.livelinkface import face_writer

    out: list[ModalityWriter] = []
    if cfg.head_camera:
        out.append(functools.partial(head_camera_writer, blink_every_s=cfg.blink_every_s,
                                     dip_every_s=cfg.eye_dip_every_s))
    if cfg.face_takes:
        out.append(face_writer)
    return out


def generate_session(out_dir: str | Path, seed: int = 0, config: SynthConfig | None = None,
                     writers: tuple[ModalityWriter, ...] | list[ModalityWriter] = ()) -> Path:
    """Generate a session folder: session.toml, markerset.toml, mocap/*.c3d, video/*.mp4 and eyes/*.csv
    (gaze_follow takes, when ``head_camera``), face/*.csv (``face_takes``) and truth/ (npz per take,
    truth.json, README.md). ``writers`` run after the built-in ones. Same seed and config give byte-identical
    files. Returns the folder."""
    cfg = config or SynthConfig()
    all_writers = [*builtin_writers(cfg), *writers]
    out = Path(out_dir)
    (out / "mocap").mkdir(parents=True, exist_ok=True)
    (out / "truth").mkdir(exist_ok=True)
    rate = float(cfg.rate_hz)
    cam = camera_to_head()
    records: list[TakeRecord] = []
    meta_takes: dict[str, Any] = {}
    n_clap_hazards = 0                   # the kinds of clap hazard take turns over the session's takes
    for index, (take_id, kind, pose, target) in enumerate(_take_plan(cfg)):
        # a stream per purpose; one added later is spawned last, so the earlier streams stay as they were
        r_motion, r_noise, r_gaps, r_writer, r_spikes, r_long, r_hazard, r_swaps, r_bursts, r_claps, r_own = (
            np.random.default_rng(s) for s in np.random.SeedSequence([seed, index]).spawn(11))
        if kind == "face":
            assert target is not None
            rec = TakeRecord(take_id, kind, pose, index, target[0], None, None, {}, {"kind": kind, "rate_hz": target[0],
                             "duration_s": target[1]}, r_writer, cam, {"id": take_id, "kind": kind})
            for w in all_writers:
                rec.entries.update(w(out, rec))
            write_npz(out / "truth" / f"{take_id}.npz", rec.truth_arrays)
            meta_takes[take_id] = rec.truth_scalars
            records.append(rec)
            continue
        if kind == "gaze_follow":
            rebound = None
            if cfg.clap_rebounds > 0:
                bounce = r_hazard.random(2) < cfg.clap_rebounds
                rebound = np.stack([np.where(bounce, r_hazard.uniform(3.0, 6.0, 2), 0.0),
                                    r_hazard.uniform(1.0, 2.0, 2) / rate], axis=1)
            secs = cfg.follow_duration_s if target is None else target[0]
            hazard = None
            if cfg.clap_hazards > 0 and r_claps.random() < cfg.clap_hazards:
                hazard = clap_hazard(r_claps, CLAP_HAZARDS[n_clap_hazards % len(CLAP_HAZARDS)], rate)
                n_clap_hazards += 1
            weak = None if hazard is None or hazard["kind"] != "weak" else (
                hazard["clap"], hazard["closing_s"], hazard["depth"], hazard["softness"])
            motion = follow_motion(r_motion, rate, cfg.placement, pose, secs, rebound, weak,
                                   (r_own, cfg.own_motion_deg) if cfg.own_motion_deg > 0 else None)
            if hazard is not None:
                motion.design["clap_hazard"] = hazard
        elif kind == "gaze_shift":
            assert target is not None
            step = None
            if cfg.body_steps > 0 and r_hazard.random() < cfg.body_steps:
                ang = r_hazard.uniform(0.0, 2.0 * np.pi)
                mm = r_hazard.uniform(40.0, 150.0)
                step = (float(r_hazard.uniform(-0.8, -0.2)), float(r_hazard.uniform(0.8, 1.4)),
                        mm * np.array([np.cos(ang), np.sin(ang), 0.0]))
            motion = shift_motion(r_motion, rate, cfg.placement, pose, *target, step=step)
        else:
            motion = neutral_motion(r_motion, rate, cfg.placement, cfg.neutral_s)
        kin = build_kinematics(motion, cfg.placement, cfg.segments)
        n, m = kin.markers_true.shape[:2]
        mask = (make_gaps(r_gaps, kin.labels, n, kind, motion.clapper_busy) if cfg.gaps
                else np.zeros((n, m), dtype=bool))
        noisy = kin.markers_true + r_noise.normal(0.0, cfg.noise_mm, size=kin.markers_true.shape)
        if cfg.gaps and (cfg.long_gaps or cfg.gaps_per_marker_min):
            rests = rest_periods(kin.markers_true[:, subject_columns(kin.labels)], rate)
            mask |= make_long_gaps(r_long, kin.labels, n, rate, cfg.long_gaps, cfg.gaps_per_marker_min, rests,
                                   crop_bounds(rests, kind))
        if cfg.gaps and cfg.root_rest_gaps:
            rests = rest_periods(kin.markers_true[:, subject_columns(kin.labels)], rate)
            mask |= make_root_rest_gap(r_hazard, kin.labels, n, rate, rests)
        if cfg.gaps and cfg.occlusion_bursts:
            mask |= make_occlusion_bursts(r_bursts, kin.labels, kin.markers_true, rate, cfg.occlusion_bursts)
        hazard = motion.design.get("clap_hazard")
        if hazard is not None and hazard["kind"] == "clapper_gap":
            mask |= clapper_gap(kin.labels, n, rate, motion.clap_times_s, hazard)
        offsets, spiked = make_spikes(r_spikes, kin.labels, mask, rate, cfg.spikes_per_marker_min,
                                      motion.clapper_busy)
        noisy += offsets
        swaps = make_label_swaps(r_swaps, kin.labels, mask, rate, cfg.label_swaps) if cfg.label_swaps else []
        swapped = apply_label_swaps(noisy, mask, swaps)
        for a, b, s, e in swaps:                 # a ghost on a swapped marker shows under the other name
            spiked[s:e, [a, b]] = spiked[s:e, [b, a]]
        noisy[mask] = np.nan
        mocap_rel = f"mocap/{take_id}.c3d"
        if cfg.up_axis != "z":
            noisy = noisy @ _lab_axes(cfg.up_axis).T
        write_c3d(out / mocap_rel, kin.labels, noisy, rate)
        arrays, scalars = take_truth(kind, motion, kin, mask, gap_runs(mask), rate, target)
        if cfg.up_axis != "z":
            _relabel_lab(arrays, _lab_axes(cfg.up_axis))
        arrays["spike_mask"] = spiked
        scalars["spike_samples"] = int(spiked.sum())
        if cfg.label_swaps:
            arrays["swap_mask"] = swapped
            arrays["swaps"] = np.array(swaps, dtype=np.int64).reshape(-1, 4)
            scalars["swap_samples"] = int(swapped.sum())
        scalars.update({"kind": kind, "pose": pose, "mocap": mocap_rel, "rate_hz": rate})
        entries: dict[str, Any] = {"id": take_id, "kind": kind, "pose": pose, "mocap": mocap_rel}
        if kind == "gaze_shift" and target is not None:
            entries["target"] = {"yaw_deg": target[0], "pitch_deg": target[1]}
        rec = TakeRecord(take_id, kind, pose, index, rate, motion, kin, arrays, scalars, r_writer, cam, entries)
        for w in all_writers:
            rec.entries.update(w(out, rec))
        write_npz(out / "truth" / f"{take_id}.npz", rec.truth_arrays)
        meta_takes[take_id] = rec.truth_scalars
        records.append(rec)

    (out / "markerset.toml").write_text(markerset_toml(cfg.segments, cfg.up_axis))
    (out / "session.toml").write_text(session_toml(cfg, records))
    meta = {
        "generator_version": GENERATOR_VERSION,
        "seed": int(seed),
        "rate_hz": rate,
        "noise_mm": cfg.noise_mm,
        "subject_floor_lab_mm": (list(cfg.placement.floor_mm) if cfg.up_axis == "z" else
                                 (np.asarray(cfg.placement.floor_mm) @ _lab_axes(cfg.up_axis).T).tolist()),
        "heading_deg": cfg.placement.heading_deg,
        "char_to_lab_quat": quat_wxyz(Rotation.from_matrix(_lab_axes(cfg.up_axis)) * cfg.placement.h_lab)[0].tolist()
        if cfg.up_axis != "z" else quat_wxyz(cfg.placement.h_lab)[0].tolist(),
        "camera_to_head_quat": quat_wxyz(cam)[0].tolist(),
        "eye_offset_mm": eye_offset_mm().tolist(),
        "segments": list(SEGMENTS),
        **({} if cfg.segments == SEGMENTS else {"marker_segments": list(cfg.segments)}),
        **({} if cfg.up_axis == "z" else {"up_axis": cfg.up_axis}),
        "takes": meta_takes,
    }
    (out / "truth" / "truth.json").write_text(json.dumps(meta, indent=1, sort_keys=True) + "\n")
    from gazepipe.synth.readme import TRUTH_README
    (out / "truth" / "README.md").write_text(TRUTH_README)
    return out
