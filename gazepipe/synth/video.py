"""Synthetic head-camera video: a camera clock against the mocap clock, and the clapper seen by the camera.

The camera runs on its own clock. Frame k is exposed at ``t_video = k / fps`` (the container stamps it so) and
the mocap clock reads ``t_mocap = offset_s + ratio · t_video`` at that instant (SPEC §3.4). Each frame shows a
static, face-like picture with sensor noise, the subject's pupils and eyelids, and the clapper: a fixed lower
arm and an upper arm whose gap follows the same distance curve as the mocap clapper markers, averaged over the
exposure (motion blur), so the video clap is the mocap clap mapped onto the video clock.

How the clapper looks can change (:class:`ClapperLook`, :data:`LOOKS`): smaller (farther from the camera), dimmer,
under more sensor noise, another exposure or a defocus blur, with a hand-like blob swinging near it; the default
look is the sample's.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np

from gazepipe.synth.motion import CLAP_OPEN_MM, CLAP_SHUT_MM, TakeMotion, _clapper_distance

VIDEO_FPS = 60.0
WIDTH, HEIGHT = 128, 96
#: exposure time (a 1/120 s shutter), centred on the frame's timestamp, and motion-blur sub-samples
EXPOSURE_S = 0.5 / VIDEO_FPS
SUBSAMPLES = 6
#: clapper picture: pixels per millimetre of arm separation, rows of the fixed (lower) arm, columns of both arms
PX_PER_MM = 0.4
LOWER_ARM_ROWS = (82, 90)
ARM_HEIGHT_PX = 8
ARM_COLS = (14, 114)
#: image positions (x, y) of the subject's right eye (image left) and left eye (image right), pixels
EYE_CENTRES_PX = ((46.0, 38.0), (82.0, 38.0))
PUPIL_TRAVEL_PX = 7.0
NOISE_GREY = 1.2
CHUNK = 512


@dataclass(frozen=True)
class ClapperLook:
    """How the head camera sees the clapper (the default: the sample's look).

    Attributes
    ----------
    scale : size of the clapper in the picture (1: arms 100 px wide and 8 px tall, 0.4 px per mm of opening;
        0.3: the same clapper about three times farther away), shrunk about the lower arm's bottom centre.
    contrast : how far the arms' grey level goes from the background's towards white (1: white arms).
    noise_grey : sensor noise, grey levels (one standard deviation).
    exposure_s : exposure time centred on each frame's timestamp, s (motion blur).
    defocus_px : optical blur of the whole picture, pixels (a Gaussian's sigma; 0: sharp).
    distractor_px : a dark, hand-sized blob swinging to and fro beside the clapper's free end, amplitude in pixels
        (0: none); it never stops, around the claps too.
    """

    scale: float = 1.0
    contrast: float = 1.0
    noise_grey: float = NOISE_GREY
    exposure_s: float = EXPOSURE_S
    defocus_px: float = 0.0
    distractor_px: float = 0.0


#: named looks (``python -m gazepipe.synth --clapper-look NAME``): ``sample`` is the bundled sample's; the others
#: make the claps harder to see while their timing stays what the mocap says
SAMPLE_LOOK = ClapperLook()
LOOKS: dict[str, ClapperLook] = {
    "sample": SAMPLE_LOOK,
    "small": ClapperLook(scale=0.3),
    "dim": ClapperLook(contrast=0.12, noise_grey=3.0),
    "blurred": ClapperLook(exposure_s=1.0 / 60.0, defocus_px=1.2),
    "busy": ClapperLook(distractor_px=8.0),
    "far": ClapperLook(scale=0.6, contrast=0.4, noise_grey=2.5, distractor_px=5.0),
}


@dataclass(frozen=True)
class CameraClock:
    """The head camera's clock: ``t_mocap = offset_s + ratio · t_video``; frames at ``k / fps`` video seconds."""

    offset_s: float
    ratio: float
    fps: float = VIDEO_FPS

    def to_mocap(self, t_video: np.ndarray | float) -> np.ndarray:
        return self.offset_s + self.ratio * np.asarray(t_video, dtype=np.float64)

    def to_video(self, t_mocap: np.ndarray | float) -> np.ndarray:
        return (np.asarray(t_mocap, dtype=np.float64) - self.offset_s) / self.ratio


def camera_clock(rng: np.random.Generator, variant: int, mocap_end_s: float) -> tuple[CameraClock, int]:
    """A clock and a frame count for one take's video.

    ``variant % 3``: 0, a crystal running fast (ratio 1 + 2e-4 … 8e-4), camera started 2–4 s before the mocap;
    1, a 59.94 Hz camera labelled 60 (ratio exactly 1.001), started 1.5–3 s before; 2, a crystal running slow
    (ratio 1 − 2e-4 … 8e-4), camera started 0.25–0.35 s AFTER the mocap (the first mocap frames have no video).
    The video runs 1–2 s past the mocap's last frame.
    """
    v = variant % 3
    if v == 0:
        clock = CameraClock(-float(rng.uniform(2.0, 4.0)), 1.0 + float(rng.uniform(2e-4, 8e-4)))
    elif v == 1:
        clock = CameraClock(-float(rng.uniform(1.5, 3.0)), 1.001)
    else:
        clock = CameraClock(float(rng.uniform(0.25, 0.35)), 1.0 - float(rng.uniform(2e-4, 8e-4)))
    end_video = float(clock.to_video(mocap_end_s + rng.uniform(1.0, 2.0)))
    return clock, int(np.ceil(end_video * clock.fps)) + 1


def _background(rng: np.random.Generator) -> np.ndarray:
    """A static face-like grey picture (H, W) float: dim surround, a shaded oval face, eye whites, a mouth."""
    yy, xx = np.mgrid[0:HEIGHT, 0:WIDTH].astype(np.float64)
    img = 45.0 + 20.0 * yy / HEIGHT + cv2.GaussianBlur(rng.uniform(-8, 8, (HEIGHT, WIDTH)), (0, 0), 4.0)
    face = ((xx - 64.0) / 36.0) ** 2 + ((yy - 46.0) / 44.0) ** 2 < 1.0
    img = np.where(face, 150.0 - 25.0 * np.abs(xx - 64.0) / 36.0, img)
    for ex, ey in EYE_CENTRES_PX:
        white = ((xx - ex) / 9.0) ** 2 + ((yy - ey) / 4.5) ** 2 < 1.0
        img = np.where(white, 200.0, img)
        brow = (np.abs(yy - (ey - 9.0)) < 1.5) & (np.abs(xx - ex) < 10.0)
        img = np.where(brow, 70.0, img)
    mouth = (np.abs(yy - 66.0) < 1.5) & (np.abs(xx - 64.0) < 12.0)
    img = np.where(mouth, 80.0, img)
    return cv2.GaussianBlur(img, (0, 0), 0.8)


def _arm_cover(bottom: np.ndarray, top: np.ndarray) -> np.ndarray:
    """Fraction of each pixel row covered by an arm spanning [top, bottom) rows, (..., H)."""
    yy = np.arange(HEIGHT, dtype=np.float64)
    return np.clip(np.minimum(yy + 1.0, bottom[..., None]) - np.maximum(yy, top[..., None]), 0.0, 1.0)


@dataclass(frozen=True)
class _ClapperPicture:
    """Where a look puts the clapper in the picture: rows of the fixed (lower) arm, the arms' columns and height,
    and pixels per millimetre of opening."""

    lower_rows: tuple[float, float]
    cols: tuple[int, int]
    arm_h: float
    px_per_mm: float

    @classmethod
    def of(cls, look: ClapperLook) -> _ClapperPicture:
        s = float(look.scale)
        if s == 1.0:
            return cls((float(LOWER_ARM_ROWS[0]), float(LOWER_ARM_ROWS[1])), ARM_COLS, float(ARM_HEIGHT_PX), PX_PER_MM)
        bottom, centre, half = float(LOWER_ARM_ROWS[1]), 0.5 * (ARM_COLS[0] + ARM_COLS[1]), 0.5 * (ARM_COLS[1] - ARM_COLS[0])
        return cls((bottom - ARM_HEIGHT_PX * s, bottom), (int(round(centre - half * s)), int(round(centre + half * s))),
                   ARM_HEIGHT_PX * s, PX_PER_MM * s)


def _distractor(t_m: np.ndarray, pic: _ClapperPicture, look: ClapperLook, phase: float) -> np.ndarray:
    """(F, H, W) darkening by a hand-sized blob swinging beside the clapper's free end (mocap seconds ``t_m`` (F,
    ns) over each exposure), grey levels."""
    yy, xx = np.mgrid[0:HEIGHT, 0:WIDTH].astype(np.float32)
    size = max(3.0, 8.0 * float(look.scale))
    cx = pic.cols[1] + 1.2 * size + 0.5 * look.distractor_px * np.sin(2.0 * np.pi * 0.9 * t_m + phase)  # (F, ns)
    cy = pic.lower_rows[0] - 0.5 * (CLAP_OPEN_MM - CLAP_SHUT_MM) * pic.px_per_mm \
        + look.distractor_px * np.sin(2.0 * np.pi * 0.55 * t_m + 2.0 * phase)
    out = np.zeros((t_m.shape[0], HEIGHT, WIDTH), dtype=np.float32)
    for k in range(t_m.shape[1]):         # averaged over the exposure's sub-samples (motion blur)
        r2 = (xx[None] - cx[:, k, None, None].astype(np.float32)) ** 2 + (yy[None] - cy[:, k, None, None].astype(np.float32)) ** 2
        out += np.exp(-r2 / np.float32(2.0 * size * size))
    return out * np.float32(90.0 / t_m.shape[1])


def render_frames(bg: np.ndarray, frame_idx: np.ndarray, clock: CameraClock, motion: TakeMotion,
                  gaze_right_cam: np.ndarray, gaze_left_cam: np.ndarray, lid: np.ndarray,
                  noise: np.ndarray, look: ClapperLook = SAMPLE_LOOK, phase: float = 0.0) -> np.ndarray:
    """Frames ``frame_idx`` as (F, H, W) uint8.

    ``gaze_*_cam`` (F, 3): each eye's direction in camera axes (pupils move with x, y); ``lid`` (F,) in [0, 1]:
    eyelid closure; ``noise`` (F, H, W): sensor noise in grey levels. The clapper gap is averaged over
    sub-samples spread over the exposure (``SUBSAMPLES`` over the default exposure, proportionally more over a
    longer one). ``frame_idx`` counts exposures: frame k is exposed at k / fps video seconds (a dropped frame
    is an index left out). A ``hidden`` clap hazard in the motion's design puts a dark occluder over all but the
    first ``visible`` share of the clapper's arms while it is in. ``look``: how the clapper is seen;
    ``phase``: the distractor's swing phase, radians.
    """
    ns = SUBSAMPLES if look.exposure_s <= EXPOSURE_S else int(np.ceil(SUBSAMPLES * look.exposure_s / EXPOSURE_S))
    sub = ((np.arange(ns) + 0.5) / ns - 0.5) * look.exposure_s
    t_m = clock.to_mocap(frame_idx[:, None] / clock.fps + sub[None, :])        # (F, ns) mocap seconds
    closing = np.asarray(motion.design.get("clap_closing_s", []), dtype=np.float64)
    rebound = motion.design.get("clap_rebound")
    soft = motion.design.get("clap_soft")
    claps = np.asarray(motion.clap_times_s, dtype=np.float64)
    d = _clapper_distance(t_m, claps, closing, None if rebound is None else np.asarray(rebound, dtype=np.float64),
                          None if soft is None else np.asarray(soft, dtype=np.float64))
    pic = _ClapperPicture.of(look)
    bottom = pic.lower_rows[0] - (d - CLAP_SHUT_MM) * pic.px_per_mm
    cover = _arm_cover(bottom, bottom - pic.arm_h).mean(axis=1).astype(np.float32)   # (F, H)
    img = np.repeat(bg.astype(np.float32)[None], frame_idx.size, axis=0)

    yy, xx = np.mgrid[0:HEIGHT, 0:WIDTH].astype(np.float64)
    for (ex, ey), g in zip(EYE_CENTRES_PX, (gaze_right_cam, gaze_left_cam), strict=True):
        y0, y1, x0, x1 = int(ey - 6), int(ey + 7), int(ex - 11), int(ex + 12)
        py, px = yy[y0:y1, x0:x1], xx[y0:y1, x0:x1]
        cx = ex + PUPIL_TRAVEL_PX * g[:, 0]
        cy = ey + PUPIL_TRAVEL_PX * g[:, 1]
        pupil = np.exp(-((px[None] - cx[:, None, None]) ** 2 + (py[None] - cy[:, None, None]) ** 2) / 4.5)
        patch = img[:, y0:y1, x0:x1] - 150.0 * pupil.astype(np.float32)
        # the eyelid comes down from the top of the eye over the closure fraction
        edge = (ey - 5.0) + 10.0 * lid
        covered = np.clip(edge[:, None, None] - py[None], 0.0, 1.0)
        img[:, y0:y1, x0:x1] = patch + (140.0 - patch) * covered.astype(np.float32)

    c0, c1 = pic.cols
    lower = _arm_cover(np.array(pic.lower_rows[1]), np.array(pic.lower_rows[0]))
    if look.contrast != 1.0:
        lower = lower * look.contrast
        cover = cover * np.float32(look.contrast)
    rows = np.flatnonzero(lower > 0)
    img[:, rows, c0:c1] += (np.float32(210.0) - img[:, rows, c0:c1]) * lower[rows].astype(np.float32)[None, :, None]
    rows = np.flatnonzero(cover.max(axis=0) > 0)
    upper = img[:, rows, c0:c1]
    img[:, rows, c0:c1] = upper + (np.float32(225.0) - upper) * cover[:, rows, None]
    hazard = motion.design.get("clap_hazard")
    if hazard is not None and hazard["kind"] == "hidden":
        tc = claps[hazard["clap"]]
        mid = t_m[:, ns // 2]
        inside = (mid >= tc + hazard["enter_s"]) & (mid < tc + hazard["leave_s"])
        top = int(pic.lower_rows[0] - (CLAP_OPEN_MM - CLAP_SHUT_MM) * pic.px_per_mm - pic.arm_h - 2)
        x_vis = c0 + int(round(hazard["visible"] * (c1 - c0)))
        img[np.ix_(np.flatnonzero(inside), np.arange(max(top, 0), int(np.ceil(pic.lower_rows[1])) + 2),
                   np.arange(x_vis, c1 + 2))] = np.float32(55.0)
    if look.distractor_px > 0:
        img -= _distractor(t_m, pic, look, phase)
    if look.defocus_px > 0:
        for fr in img:
            cv2.GaussianBlur(fr, (0, 0), look.defocus_px, dst=fr)
    img += noise
    np.rint(img, out=img)
    np.clip(img, 0, 255, out=img)
    return img.astype(np.uint8)


def write_head_video(path: Path, rng: np.random.Generator, clock: CameraClock, n_frames: int, motion: TakeMotion,
                     gaze_right_cam: np.ndarray, gaze_left_cam: np.ndarray, lid: np.ndarray,
                     exposures: np.ndarray | None = None, look: ClapperLook = SAMPLE_LOOK) -> None:
    """Write the take's video (MPEG-4 part 2 in .mp4, labelled ``clock.fps``; OpenCV's FFmpeg writer is
    byte-deterministic for it). Per-frame arrays are (n_frames, …). ``exposures`` (n_frames,): the exposure
    index of each written frame (default 0, 1, …; a dropped frame is a skipped index, and the container still
    stamps the written frames k / fps). ``look``: how the clapper is seen (the default draws nothing more from
    ``rng`` than the sample's look does)."""
    expo = np.arange(n_frames) if exposures is None else np.asarray(exposures, dtype=np.int64)
    bg = _background(rng)
    phase = float(rng.uniform(0.0, 2.0 * np.pi)) if look.distractor_px > 0 else 0.0
    path.parent.mkdir(parents=True, exist_ok=True)
    writer = cv2.VideoWriter(str(path), cv2.VideoWriter.fourcc(*"mp4v"), clock.fps, (WIDTH, HEIGHT))
    if not writer.isOpened():
        raise RuntimeError(f"OpenCV cannot write {path} with the mp4v codec")
    try:
        for a in range(0, n_frames, CHUNK):
            idx = np.arange(a, min(a + CHUNK, n_frames))
            noise = rng.standard_normal((idx.size, HEIGHT, WIDTH), dtype=np.float32) * np.float32(look.noise_grey)
            frames = render_frames(bg, expo[idx], clock, motion, gaze_right_cam[idx], gaze_left_cam[idx],
                                   lid[idx], noise, look, phase)
            for fr in frames:
                writer.write(cv2.cvtColor(fr, cv2.COLOR_GRAY2BGR))
    finally:
        writer.release()
