"""Write a whole synthetic capture session (SPEC §1) with its ground truth beside it."""

from __future__ import annotations

import functools
import json
import os
import shutil
from dataclasses import dataclass, field, replace
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
    make_root_final_rest_gap,
    make_root_rest_gap,
    make_spikes,
    with_unlisted_markers,
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
from gazepipe.synth.video import SAMPLE_LOOK, ClapperLook

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
    ``nexus_csv``: share of mocap takes exported as Vicon Nexus CSV files instead of C3D (:func:`write_nexus_csv`:
    a Trajectories block, labels ``<subject>:<marker>``, 6 significant digits, CRLF line ends; the take's
    ``mocap`` in the truth says which file); ``face_tracking_loss``: stretches of 0.2–1.5 s per face take in which
    the tracked file's rows are written as Live Link Face writes them while ARKit has lost the face (the timecode,
    a ``BlendShapeCount`` of 0 and nothing else; the truth marks them in ``face_tracked_lost``);
    ``root_final_rest_gap_s``: (shortest, longest) seconds: every gaze_shift take's final rest is lengthened by
    its drawn length plus 1.6 s and the root marker itself is lost for that long inside it, measured still on
    both sides (:func:`~gazepipe.synth.markers.make_root_final_rest_gap`; None: no such gap, the take as it was);
    ``clapper_look``: how the head camera sees the clapper (smaller, dimmer, noisier, blurred, a hand swinging
    beside it: :class:`~gazepipe.synth.video.ClapperLook`, :data:`~gazepipe.synth.video.LOOKS`; the truth's
    ``video.clapper_look`` says which when it is not the sample's);
    ``unlisted_markers``: markers the capture carries that the markerset lists in no segment (names of
    :data:`~gazepipe.synth.skeleton.UNLISTED_MARKERS`: shoulders and elbows, moving against the chest
    (:func:`~gazepipe.synth.markers.with_unlisted_markers`); written after the listed subject markers, with
    gaps, spikes and bursts like any marker, and label swaps between them: mirror pairs and their neighbours);
    ``unlisted_motion``: how far they move against the chest, as a multiple of the default (20 mm shrugs, 15 mm
    reaches, the upper arm's 20° swing);
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
    nexus_csv: float = 0.0
    face_tracking_loss: int = 0
    root_final_rest_gap_s: tuple[float, float] | None = None
    clapper_look: ClapperLook = SAMPLE_LOOK
    unlisted_markers: tuple[str, ...] = ()
    unlisted_motion: float = 1.0
    own_motion_deg: float = 0.0


#: the final rest around a root-marker gap of ``SynthConfig.root_final_rest_gap_s`` (s): added to the gap's length
FINAL_REST_MARGIN_S = 1.6


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


def write_nexus_csv(path: Path, labels: list[str], xyz: np.ndarray, rate_hz: float, subject: str) -> None:
    """A Vicon Nexus 2 CSV export of the markers: the ``Trajectories`` block (title, the rate as Nexus prints it
    with 6 significant digits, names ``<subject>:<marker>``, ``Frame,Sub Frame,X,Y,Z…``, a units row in mm), first
    frame 1, coordinates with 6 significant digits, NaN samples as empty cells, CRLF line ends."""
    t, m = xyz.shape[:2]
    names = ",".join(f"{subject}:{lab},," for lab in labels)
    head = ["Trajectories", f"{rate_hz:.6g}", f",,{names}", "Frame,Sub Frame," + ",".join(["X,Y,Z"] * m),
            ",," + ",".join(["mm,mm,mm"] * m)]
    cells = np.char.mod("%.6g", xyz.reshape(t, 3 * m))
    cells[np.isnan(xyz.reshape(t, 3 * m))] = ""
    rows = [f"{i + 1},0," + ",".join(r) for i, r in enumerate(cells.tolist())]
    path.write_bytes(("\r\n".join(head + rows) + "\r\n").encode("ascii"))


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
                                     dip_every_s=cfg.eye_dip_every_s, look=cfg.clapper_look))
    if cfg.face_takes:
        out.append(face_writer)
    return out


class OutputFolderError(ValueError):
    """The session folder cannot be written there (``path``: the folder; ``problem``: why, a short phrase)."""

    def __init__(self, path: str, problem: str) -> None:
        super().__init__(f"{path}: {problem}")
        self.path, self.problem = path, problem


def generate_session(out_dir: str | Path, seed: int = 0, config: SynthConfig | None = None,
                     writers: tuple[ModalityWriter, ...] | list[ModalityWriter] = ()) -> Path:
    """Generate a session folder: session.toml, markerset.toml, mocap/*.c3d, video/*.mp4 and eyes/*.csv
    (gaze_follow takes, when ``head_camera``), face/*.csv (``face_takes``) and truth/ (npz per take,
    truth.json, README.md). ``writers`` run after the built-in ones. Same seed and config give byte-identical
    files. Returns the folder.

    The files are written into a folder beside ``out_dir`` (``.<name>.partial-<pid>``) and moved into it once
    all are written, so a failure (a full disk, say) leaves no partial session: it raises, with the other files
    of ``out_dir`` as they were. Raises :class:`OutputFolderError` when ``out_dir`` is empty or a file, and
    :class:`OSError` when the folder cannot be written (read-only, unreachable, full)."""
    if int(seed) < 0:
        raise ValueError(f"seed {seed} is negative: a seed is a whole number 0 or more")
    out = _session_folder(out_dir)
    stage = out.parent / f".{out.name}.partial-{os.getpid()}"
    shutil.rmtree(stage, ignore_errors=True)        # left by a run of this pid that was killed
    stage.mkdir()
    try:
        _generate_into(stage, int(seed), config or SynthConfig(), writers)
        _move_into(stage, out)
    finally:
        shutil.rmtree(stage, ignore_errors=True)
    return out


def _session_folder(out_dir: str | Path) -> Path:
    """``out_dir`` checked (not empty, not a file), its parent folders made."""
    if not str(out_dir).strip():
        raise OutputFolderError(repr(str(out_dir)), "no folder named: give the session folder to write")
    out = Path(out_dir)
    if out.exists() and not out.is_dir():
        raise OutputFolderError(str(out), "is a file, not a folder")
    above = next((a for a in out.parents if a.exists()), None)
    if above is not None and not above.is_dir():
        raise OutputFolderError(str(out), f"{above} is a file, not a folder")
    out.parent.mkdir(parents=True, exist_ok=True)
    return out


def _move_into(stage: Path, out: Path) -> None:
    """The generated files of ``stage`` into ``out``: the folder renamed when ``out`` does not exist, else each
    file moved over the one of the same name (the folder's other files kept)."""
    if not out.exists():
        os.replace(stage, out)
        return
    for f in sorted(stage.rglob("*")):
        if f.is_file():
            target = out / f.relative_to(stage)
            target.parent.mkdir(parents=True, exist_ok=True)
            os.replace(f, target)


def _generate_into(out: Path, seed: int, cfg: SynthConfig,
                   writers: tuple[ModalityWriter, ...] | list[ModalityWriter]) -> None:
    """Write the session of :func:`generate_session` into the folder ``out`` (it exists)."""
    all_writers = [*builtin_writers(cfg), *writers]
    (out / "mocap").mkdir(parents=True, exist_ok=True)
    (out / "truth").mkdir(exist_ok=True)
    cam = camera_to_head()
    records: list[TakeRecord] = []
    meta_takes: dict[str, Any] = {}
    n_clap_hazards = 0                   # the kinds of clap hazard take turns over the session's takes
    for index, (take_id, kind, pose, target) in enumerate(_take_plan(cfg)):
        # a stream per purpose; one added later is spawned last, so the earlier streams stay as they were
        rngs = _Streams(*(np.random.default_rng(s) for s in np.random.SeedSequence([seed, index]).spawn(11)))
        if cfg.own_motion_deg > 0:
            rngs = replace(rngs, own=np.random.default_rng(
                np.random.SeedSequence([seed, index]).spawn(14)[13]))
        if kind == "face":
            assert target is not None
            face_scalars: dict[str, Any] = {"kind": kind, "rate_hz": target[0], "duration_s": target[1]}
            if cfg.face_tracking_loss:
                face_scalars["tracking_loss_stretches"] = int(cfg.face_tracking_loss)
            rec = TakeRecord(take_id, kind, pose, index, target[0], None, None, {}, face_scalars, rngs.writer, cam,
                             {"id": take_id, "kind": kind})
        else:
            motion, still_gap_s, n_clap_hazards = _take_motion(kind, pose, target, cfg, rngs, n_clap_hazards)
            rec = _mocap_take(out, seed, index, (take_id, kind, pose, target), cfg, motion, still_gap_s, rngs, cam)
        for w in all_writers:
            rec.entries.update(w(out, rec))
        write_npz(out / "truth" / f"{take_id}.npz", rec.truth_arrays)
        meta_takes[take_id] = rec.truth_scalars
        records.append(rec)

    (out / "markerset.toml").write_text(markerset_toml(cfg.segments, cfg.up_axis))
    (out / "session.toml").write_text(session_toml(cfg, records))
    meta = _session_truth(seed, cfg, cam, meta_takes)
    (out / "truth" / "truth.json").write_text(json.dumps(meta, indent=1, sort_keys=True) + "\n")
    from gazepipe.synth.readme import TRUTH_README, UNLISTED_README
    (out / "truth" / "README.md").write_text(TRUTH_README + (UNLISTED_README if cfg.unlisted_markers else ""))


@dataclass(frozen=True)
class _Streams:
    """A take's random streams, one per purpose, in the order they are spawned."""

    motion: np.random.Generator
    noise: np.random.Generator
    gaps: np.random.Generator
    writer: np.random.Generator
    spikes: np.random.Generator
    long: np.random.Generator
    hazard: np.random.Generator
    swaps: np.random.Generator
    bursts: np.random.Generator
    claps: np.random.Generator
    rest: np.random.Generator
    #: the segments' own motion (``SynthConfig.own_motion_deg``): spawned apart (the fourteenth stream), and
    #: only when asked for, so the other streams stay as they were
    own: np.random.Generator | None = None


def _take_motion(kind: str, pose: str, target: tuple[float, float] | None, cfg: SynthConfig, rngs: _Streams,
                 n_clap_hazards: int) -> tuple[Any, float | None, int]:
    """A mocap take's motion, the length of the gap a still marker gets in its final rest (s; None for none),
    and the count of clap hazards drawn so far in the session."""
    rate = float(cfg.rate_hz)
    still_gap_s = None
    if kind == "gaze_follow":
        rebound = None
        if cfg.clap_rebounds > 0:
            bounce = rngs.hazard.random(2) < cfg.clap_rebounds
            rebound = np.stack([np.where(bounce, rngs.hazard.uniform(3.0, 6.0, 2), 0.0),
                                rngs.hazard.uniform(1.0, 2.0, 2) / rate], axis=1)
        secs = cfg.follow_duration_s if target is None else target[0]
        hazard = None
        if cfg.clap_hazards > 0 and rngs.claps.random() < cfg.clap_hazards:
            hazard = clap_hazard(rngs.claps, CLAP_HAZARDS[n_clap_hazards % len(CLAP_HAZARDS)], rate)
            n_clap_hazards += 1
        weak = None if hazard is None or hazard["kind"] != "weak" else (
            hazard["clap"], hazard["closing_s"], hazard["depth"], hazard["softness"])
        own = None if rngs.own is None else (rngs.own, cfg.own_motion_deg)
        motion = follow_motion(rngs.motion, rate, cfg.placement, pose, secs, rebound, weak, own)
        if hazard is not None:
            motion.design["clap_hazard"] = hazard
    elif kind == "gaze_shift":
        assert target is not None
        step = None
        if cfg.body_steps > 0 and rngs.hazard.random() < cfg.body_steps:
            ang = rngs.hazard.uniform(0.0, 2.0 * np.pi)
            mm = rngs.hazard.uniform(40.0, 150.0)
            step = (float(rngs.hazard.uniform(-0.8, -0.2)), float(rngs.hazard.uniform(0.8, 1.4)),
                    mm * np.array([np.cos(ang), np.sin(ang), 0.0]))
        if cfg.root_final_rest_gap_s is not None:
            still_gap_s = float(rngs.rest.uniform(*cfg.root_final_rest_gap_s))
        motion = shift_motion(rngs.motion, rate, cfg.placement, pose, *target, step=step,
                              more_rest_s=0.0 if still_gap_s is None else still_gap_s + FINAL_REST_MARGIN_S)
    else:
        motion = neutral_motion(rngs.motion, rate, cfg.placement, cfg.neutral_s)
    return motion, still_gap_s, n_clap_hazards


def _gap_mask(kind: str, cfg: SynthConfig, motion: Any, kin: Any, still_gap_s: float | None,
              rngs: _Streams) -> np.ndarray:
    """Which samples (frames, markers) the capture lost: gaps, long gaps, rest gaps, occlusion bursts, a
    clapper gap."""
    rate = float(cfg.rate_hz)
    n, m = kin.markers_true.shape[:2]
    mask = (make_gaps(rngs.gaps, kin.labels, n, kind, motion.clapper_busy) if cfg.gaps
            else np.zeros((n, m), dtype=bool))
    if cfg.gaps and (cfg.long_gaps or cfg.gaps_per_marker_min):
        rests = rest_periods(kin.markers_true[:, subject_columns(kin.labels)], rate)
        mask |= make_long_gaps(rngs.long, kin.labels, n, rate, cfg.long_gaps, cfg.gaps_per_marker_min, rests,
                               crop_bounds(rests, kind))
    if cfg.gaps and cfg.root_rest_gaps:
        rests = rest_periods(kin.markers_true[:, subject_columns(kin.labels)], rate)
        mask |= make_root_rest_gap(rngs.hazard, kin.labels, n, rate, rests)
    if cfg.gaps and still_gap_s is not None:
        rests = rest_periods(kin.markers_true[:, subject_columns(kin.labels)], rate)
        mask |= make_root_final_rest_gap(rngs.rest, kin.labels, n, rate, rests, still_gap_s)
    if cfg.gaps and cfg.occlusion_bursts:
        mask |= make_occlusion_bursts(rngs.bursts, kin.labels, kin.markers_true, rate, cfg.occlusion_bursts)
    hazard = motion.design.get("clap_hazard")
    if hazard is not None and hazard["kind"] == "clapper_gap":
        mask |= clapper_gap(kin.labels, n, rate, motion.clap_times_s, hazard)
    return mask


def _mocap_take(out: Path, seed: int, index: int, plan: tuple[str, str, str, tuple[float, float] | None],
                cfg: SynthConfig,
                motion: Any, still_gap_s: float | None, rngs: _Streams, cam: Rotation) -> TakeRecord:
    """A mocap take's capture written (C3D, or Nexus CSV when drawn), with its truth."""
    take_id, kind, pose, target = plan
    rate = float(cfg.rate_hz)
    kin = build_kinematics(motion, cfg.placement, cfg.segments)
    if cfg.unlisted_markers:   # a stream of its own (the thirteenth), drawn only when asked for
        unlisted = np.random.default_rng(np.random.SeedSequence([seed, index]).spawn(13)[12])
        kin = with_unlisted_markers(unlisted, kin, tuple(cfg.unlisted_markers), cfg.unlisted_motion)
    mask = _gap_mask(kind, cfg, motion, kin, still_gap_s, rngs)
    noisy = kin.markers_true + rngs.noise.normal(0.0, cfg.noise_mm, size=kin.markers_true.shape)
    offsets, spiked = make_spikes(rngs.spikes, kin.labels, mask, rate, cfg.spikes_per_marker_min,
                                  motion.clapper_busy)
    noisy += offsets
    swaps = make_label_swaps(rngs.swaps, kin.labels, mask, rate, cfg.label_swaps) if cfg.label_swaps else []
    swapped = apply_label_swaps(noisy, mask, swaps)
    for a, b, s, e in swaps:                 # a ghost on a swapped marker shows under the other name
        spiked[s:e, [a, b]] = spiked[s:e, [b, a]]
    noisy[mask] = np.nan
    # the export's format: a stream of its own (the twelfth: the eleventh is the rest stream), drawn only when
    # asked for (the other streams stay as they were)
    nexus = cfg.nexus_csv > 0 and np.random.default_rng(
        np.random.SeedSequence([seed, index]).spawn(12)[11]).random() < cfg.nexus_csv
    mocap_rel = f"mocap/{take_id}.csv" if nexus else f"mocap/{take_id}.c3d"
    if cfg.up_axis != "z":
        noisy = noisy @ _lab_axes(cfg.up_axis).T
    if nexus:
        write_nexus_csv(out / mocap_rel, kin.labels, noisy, rate, cfg.subject)
    else:
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
    return TakeRecord(take_id, kind, pose, index, rate, motion, kin, arrays, scalars, rngs.writer, cam, entries)


def _session_truth(seed: int, cfg: SynthConfig, cam: Rotation, meta_takes: dict[str, Any]) -> dict[str, Any]:
    """The session's ``truth.json``: the generator's settings, frames and every take's truth scalars."""
    return {
        "generator_version": GENERATOR_VERSION,
        "seed": int(seed),
        "rate_hz": float(cfg.rate_hz),
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
        **({} if not cfg.unlisted_markers else {"unlisted_markers": list(cfg.unlisted_markers)}),
        "takes": meta_takes,
    }
