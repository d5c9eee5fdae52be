"""The README written into every generated session's truth/ folder."""

TRUTH_README = """\
# Ground truth of this synthetic session

Written by `gazepipe.synth.generate_session` (`python -m gazepipe.synth OUT_DIR --seed N`); the same seed and
configuration give byte-identical files. Read it back with `gazepipe.synth.load_truth(session_dir, take_id)`,
which returns the take's arrays, its `truth.json` entry under `"scalars"` and the session entries under
`"session"`.

Everything here is computed from the NOISE-FREE kinematics. The mocap files (`mocap/*.c3d`) hold the same
positions plus Gaussian noise (sigma `noise_mm`, 0.5 mm) with the occlusion gaps written as gaps (residual -1,
coordinates 0; ezc3d reads them as NaN). C3D: float storage, POINT:UNITS "mm", POINT:RATE 30000/1001 Hz,
header first frame 1. Frame `i` of a take is at `time_s = i * 1001 / 30000` s.

## Frames and conventions

* Lab: Z up (`up_axis = "z"`), millimetres. The subject stands at `subject_floor_lab_mm` facing
  `heading_deg` = 35 degrees from lab +Y about +Z, so the lab frame is not the character frame.
  `char_to_lab_quat` is the rotation H from character axes to lab axes of that stance (v_lab = H v_char).
* Character frame (SPEC section 2), built per frame from the noise-free markers: origin SACR,
  left = horizontal part of (PEL_L - PEL_R), up = lab Z, forward = left x up. +X left, +Y up, +Z forward.
  `char_quat_lab[t]` / `char_origin_lab[t]` give it per frame (the pelvis turns, so the heading moves).
* Segment rotations are the identity in the neutral pose (standing or sitting still, looking ahead; every
  take starts that way, and the `neutral` take is 4 s of it). Quaternions are w, x, y, z with w >= 0.
* Head axes = the head segment's axes: X left, Y up, Z forward in the neutral pose.
* Gaze angles: yaw positive to the character's left, pitch positive up; rotation Ry(yaw) Rx(-pitch).
* Frame ranges are half-open [start, stop).

## truth/<take>.npz (T frames, M markers, S = 10 segments)

| array | shape, dtype | meaning |
|---|---|---|
| time_s | (T,) f8 | seconds from the first frame |
| labels | (M,) str | marker labels in C3D order |
| segments | (S,) str | pelvis, spine1..spine4, chest, neck1..neck3, head (each the parent of the next) |
| markers_true | (T, M, 3) f4 | noise-free marker positions, lab mm (also inside gaps) |
| gap_mask | (T, M) bool | True where the C3D sample is a gap |
| spike_mask | (T, M) bool | True where a ghost-reflection spike (15–50 mm, 1–2 frames) displaces the C3D sample |
| swap_mask | (T, M) bool | (``label_swaps`` only) True where the C3D sample is another marker's, written under this name by a label swap; ``markers_true`` column m is always marker m's own path |
| swaps | (n, 4) int64 | (``label_swaps`` only) each swap's two marker columns and its frames, start and stop (half-open) |
| gaps | (K, 3) i8 | every gap as (marker column, start frame, stop frame) |
| seg_quat_char | (T, S, 4) f4 | segment rotation in the per-frame character frame (calibrated to neutral) |
| seg_quat_local | (T, S, 4) f4 | parent-relative rotation (the root's is its seg_quat_char) |
| seg_quat_lab | (T, S, 4) f4 | rotation from character axes of the neutral stance to the lab: H Q_k(t) |
| joints_lab | (T, S, 3) f4 | joint positions, lab mm |
| char_quat_lab | (T, 4) f8 | per-frame character frame -> lab rotation |
| char_origin_lab | (T, 3) f8 | per-frame character frame origin (SACR), lab mm |
| head_centre_char | (T, 3) f4 | HEADC (between the eyes) in the character frame, mm |
| target_dir_char | (T, 3) f4 | unit vector HEADC -> target, character frame. gaze_follow: the pole tip POLE; gaze_shift: the sign the subject turns to (3 m from the neutral eye position along the requested direction; no marker); neutral: a point 3 m straight ahead |
| eye_dir_char | (T, 3) f4 | cyclopean gaze direction (unit), character frame |
| eye_dir_head | (T, 3) f4 | the same in head axes |
| eye_left_dir_char, eye_right_dir_char | (T, 3) f4 | per-eye directions (eyes at HEADC +/- 32 mm along head X; left = +X) |
| fixation_lab | (T, 3) f4 | the point the eyes aim at, lab mm |
| clap_times_s | (2,) f8 | clap contact instants (gaze_follow), mocap seconds; empty otherwise |
| rest_periods | (R, 2) i8 | rest periods [start, stop) by SPEC 3.2's rule (see below) |
| crop | (2,) i8 | crop bounds [start, stop); (-1, -1) when there are fewer than two rests (neutral take) |

The eyes rotate at most 45 degrees from the head's forward axis; when the target is farther round (behind
the subject) the eyes stop at that limit, so eye_dir and target_dir then differ by more than the lag.

## truth.json

Session: `seed`, `generator_version`, `rate_hz`, `noise_mm`, `subject_floor_lab_mm`, `heading_deg`,
`char_to_lab_quat`, `camera_to_head_quat` (the TRUE head-camera rotation, v_head = R v_cam, camera axes x right,
y down, z forward; markerset.toml deliberately has no [camera] so the pipeline must estimate it; the camera sits
below and in front of the face looking back at it, tilted up 20 degrees and turned 5 degrees), `eye_offset_mm`
(HEADC relative to the head markers' centroid, head axes; the same numbers as in markerset.toml), `segments`.
With a reduced marker layout, `marker_segments` lists the segments that carry markers (the markerset's
segments, each the parent of the next); `segments` and every per-segment truth array still hold the ten segments of
the moving chain, so compare a markerset segment with the truth segment of the same name. With `up_axis` = "y" the
C3D files and the lab arrays (`markers_true`, `joints_lab`, `char_origin_lab`, `fixation_lab`, `seg_quat_lab`,
`char_quat_lab`) are in y-up lab axes (the z-up ones turned -90 degrees about x).

Per take (`takes.<id>`): `kind`, `pose`, `mocap`, `rate_hz`, `n_frames`, `spike_samples`, `clap_times_s`,
`rest_periods`, `crop`,
`design` (the generating parameters: rest lengths, reaction delay, clap closing durations, target goals for
gaze_follow, and `clap_rebound` (mm, s per clap) when the stick bounces, `clap_soft` (share of the opening,
softness per clap) and `clap_hazard` (`kind`: weak, hidden, dropped_frames or clapper_gap; `clap`: 0 or 1; and
its drawn parameters, seconds relative to the contact) when the take has a clap hazard; per-segment onset times in seconds,
duration, overshoot beta and its time, final per-segment yaw/pitch for gaze_shift, and `step` (start_s,
duration_s, lab_mm) when the whole body steps), and for gaze_shift takes the SPEC 3.6 gaze_map quantities:

* `target`: requested `yaw_deg`, `pitch_deg`.
* `l_s`: (start of the second rest - end of the first rest) / rate, seconds.
* `start_frac[segment]`: first frame in the crop where the segment's parent-relative angular speed (central
  differences) exceeds 18 deg/s, as (frame - crop start) / rate / l; 0 when it never does. Small local
  rotations (the spine segments, the necks in most takes) never reach 18 deg/s, so 0 there means "none".
* `t_beta_frac`, `t_beta_frame`, `beta`: the head's displacement D(t) = F_head(t) F_head(c0)^-1 in the character
  frame held fixed at the crop's first frame c0; theta(t) = rotvec(D(t)) . n with n the unit axis of D(last);
  angular velocity by central differences; t_beta is the first + to - sign change inside the crop whose mean
  velocity over 0.1 s (3 frames) before is > 0 and after is < 0, placed by linear interpolation between the two
  frames (t_beta_frame = the first frame with velocity <= 0); `beta` = theta(t_beta) / theta(last) - 1 with theta
  interpolated likewise. No sign change: t_beta_frac = 1, beta = 0. The design's beta (in `design`) is the
  overshoot of each segment's own profile; the measured head beta is smaller because the chain segments
  overshoot at other times. `overshoot_head_local` gives the same rule applied to the head's parent-relative
  rotation instead (it recovers the design's t_beta_s to within a frame, and its beta once the part of the
  rise before the crop's first frame is taken out: beta / (1 - profile(c0))).
* `p_plus[segment]`: parent-relative displacement L(last) L(c0)^-1 over the crop (last = crop stop - 1), w,x,y,z;
  `p_plus.eyes` = D_head^T Ry(yaw) Rx(-pitch), so the eyes' global displacement equals the requested change.

## Rest periods and crops

Computed with SPEC 3.2's rule on the noise-free subject markers (every marker except POLE and the clapper):
per-frame mean marker speed by central differences (np.gradient, one-sided at the ends) WITHOUT the low-pass
the pipeline applies to noisy data; still below 6 mm/s; rests separated by less than 1/6 s merge; rests shorter
than 0.25 s are dropped. gaze_shift: crop = [end of the first rest, end of the second rest) (the second rest runs
to the end of the take). Other kinds: [end of the first rest, start of the last rest). A pipeline working on the
noisy files with its low-pass may differ by a frame or two at each bound. Short rests inside gaze_follow takes
(the subject briefly still) are listed too.

## Motion model (what the data contains)

* Kinematics: 10-segment chain, joint positions on a vertical-ish line (pelvis 1000 mm, head 1610 mm; sitting
  lowers everything by 450 mm). Global segment rotation G_k(t) = H Q_k(t), Q_k in the initial character axes.
  Markers are rigid offsets on their segment; all clusters are exactly rigid in markers_true.
* gaze_follow (Klein 5.1): 2.3-2.8 s neutral rest; the pole tip moves linearly to random goals in a 6 x 6 x 3 m
  box (heights 0.2-3.2 m) around the subject, 3.33 s per goal, never within 0.8 m of the head; it starts and ends
  2 m straight ahead at eye height. The subject sees the target with a reaction delay (0.18-0.23 s); the eyes
  pursue it at 85 % gain with catch-up saccades every 0.2-0.45 s (about 50 ms each); the body's share of the
  gaze change goes through an underdamped second-order response (overshoot) with later onsets down the chain
  (head, neck3..neck1, chest, spine4..spine1, pelvis), shares decreasing down the chain; small smooth sway.
  When the pole passes behind the subject the body swings round through the front over about a second.
  Settle, then 2.3-2.8 s neutral rest. Pose limits differ (standing: body up to 130 degrees of yaw; sitting:
  no pelvis rotation, 85 degrees). Poses without a profile of their own (laying, walking) move like standing.
* Clapper: CLAP1/CLAP2 on the two arms, held about 0.5 m in front of the face; opens to 150 mm, closes with an
  accelerating motion in 60-100 ms to the shut distance of 25 mm (the markers sit on the arms) and stays shut.
  One clap in the leading rest, one in the trailing rest; `clap_times_s` is the instant the closing ends, exact
  (sub-frame) from the motion curve.
* gaze_shift (Pejsa 5.2.1): 1.2-1.6 s neutral rest, then a saccade of the eyes (start of the shift), the head
  0.05-0.1 s later and the other segments after known delays (`design.onset_s`), each following the same
  profile: a quintic rise to (1 + beta) of its final rotation at u_beta, then a quintic settle to the final
  rotation; then 1.3-1.6 s of rest. Small yaw shifts move the neck and the head most.
* Occlusion gaps: lengths 1-5, 6-15, 16-30, 31-90 and 31-120 frames, some on two markers of one segment at once
  or on four markers of different segments at once,
  one at the very start and one at the very end of each gaze_follow take; SACR and the pelvis markers only get
  gaps of at most 3 frames; the clapper has no gap from 1.2 s before to 0.6 s after a clap.

## Head camera: video/<take>.mp4 (gaze_follow takes)

128 x 96 grey pictures (written as BGR), MPEG-4 part 2 (`mp4v`) in .mp4, labelled 60 fps. Frame k is stamped
`k / 60` s: that is the video clock. The camera's clock against the mocap clock is
`t_mocap = offset_s + ratio * t_video` (SPEC 3.4). The clock variant cycles with the take's position in the
session: (a) a crystal running fast, ratio 1 + 2e-4..8e-4, camera started 2-4 s before the mocap; (b) a
59.94 Hz camera labelled 60, ratio exactly 1.001, started 1.5-3 s before; (c) a crystal running slow,
ratio 1 - 2e-4..8e-4, camera started 0.25-0.35 s AFTER the mocap, so the first mocap frames have no video
(`mocap_has_video`). Every video runs 1-2 s past the mocap's last frame. In session01: follow_standing_01 is
(b), follow_standing_02 is (c), follow_sitting_01 is (a).

Picture: a static face-like image with Gaussian sensor noise (sigma 1.2 grey levels, new every frame), pupils
that follow each eye's true direction in camera axes, eyelids that close during the blinks of the OpenFace file,
and the clapper: a fixed lower arm and an upper arm whose gap is 0.4 px per mm of the SAME clapper distance
curve as the mocap markers CLAP1-CLAP2, evaluated at the frame's mocap time. The exposure is 1/120 s centred
on the frame's timestamp, integrated with 6 sub-samples (motion blur). The closing burst of motion energy
therefore ends at the mocap clap mapped to the video clock, `video_clap_times_s = (clap_times_s - offset_s) /
ratio`; the largest frame difference is the last frame pair before contact. No blink happens from 1.5 s before
to 1 s after a clap (mocap clock), so the clapper is the only thing moving there.

## Eyes: eyes/<take>.csv (OpenFace FeatureExtraction layout)

One row per video frame: `frame` 1..N, `timestamp` = (frame - 1) / 60 written with 3 decimals (video clock).
`gaze_0_*` = the subject's RIGHT eye (image left), `gaze_1_*` = the LEFT eye, unit vectors in camera axes
(x right, y down, z forward; into the camera ~ (0, 0, -1)): v_cam = R^T v_head with R = `camera_to_head_quat`,
v_head = each eye's true direction in head axes at the frame's mocap time (linear interpolation of the 29.97 Hz
truth, renormalised; held at either end outside the mocap), turned by a random rotation of RMS 2 degrees.
Confidence 0.90-0.98 on good frames; dips to 0.30-0.78 in runs of 1-20 frames (noise 8 degrees there); blinks
of 100-300 ms every 2-6 s: `AU45_c` = 1 and `AU45_r` >= 1 inside, < 1 outside, the vectors drop 15-30 degrees
and scatter; a few rows with `success` = 0 and zeros for every value (never inside a blink). The take of
variant (a) is written in the older style: no `face_id` or `gaze_angle_*`, ", " separators in the header and
between values. The others are OpenFace 2.x (`face_id`, `gaze_angle_x/y`, `pose_*`, eye-corner landmarks
`x_36..y_45`, a few AUs).

## Truth of the head camera (in truth/<take>.npz, N video frames)

| array | shape, dtype | meaning |
|---|---|---|
| video_time_s | (N,) f8 | frame timestamps on the video clock (k / 60) |
| video_mocap_time_s | (N,) f8 | the same instants on the mocap clock |
| video_clap_times_s | (2,) f8 | the claps on the video clock |
| mocap_has_video | (T,) bool | mocap frames inside the video's time span |
| eyes_dir_head, eyes_dir_cam | (N, 3) f4 | true cyclopean direction (HEADC to the fixation point), head / camera axes |
| eyes_left_head, eyes_right_head | (N, 3) f4 | each eye's true direction, head axes |
| eyes_valid | (N,) bool | what gating should keep: success, confidence >= 0.8, no blink |
| eyes_blink, eyes_success, eyes_low_conf | (N,) bool | injected blinks, success flags, confidence dips |
| eyes_in_mocap | (N,) bool | frames whose mocap time lies inside the mocap take |

truth.json `takes.<id>.video`: `offset_s`, `ratio`, `offset_at_first_clap_s` (mocap clap - video clap, the
first clap), `clap_times_mocap_s`, `clap_times_video_s`, `n_frames`, `fps`, `width`, `height`, `exposure_s`,
`codec`, `starts_after_mocap`, `mocap_frames_without_video`, `dropped_frames` (video frames never written: after
them the stamps run behind the exposures, and `video_mocap_time_s` holds the true instants); `takes.<id>.eyes`: `layout`, `rows`,
`noise_deg`, `confidence_threshold`, `blink_frames`, `failed_frames`, `low_confidence_frames`,
`valid_fraction`.

## Face takes: face/<take>_clean.csv and face/<take>_tracked.csv (Live Link Face)

No mocap. Columns exactly as the real Live Link Face export in corpus/livelinkface: `Timecode`,
`BlendShapeCount` (61), the 52 blendshapes in the app's PascalCase order, `HeadYaw/Pitch/Roll`, then
`LeftEyeYaw/Pitch/Roll`, `RightEyeYaw/Pitch/Roll` (radians), 10 decimals. Timecode `HH:MM:SS:FF.fff` with FF
counting 60 frames a second (`timecode_fps = 60` on the take) and `.fff` the fraction of a frame; capture frame
k is at `k / rate_hz * (1 + clock_drift)` s after the first (the phone's clock drifts by a few 1e-5 against the
timecode). face_01: 60 Hz, 16 s, head tracking on; face_02: 30 Hz (FF steps by 2), 20 s, head tracking off
(head angles all zero, as in the real take). Dropped frames: about one capture frame in 80, singles plus one
double drop, at different places in the clean and the tracked file (rows missing; a larger timecode step).

clean = smooth, plausible curves in [0, 1]: latent speech (jaw), smile, brow raise, frown, pucker, lateral jaw,
saccadic eye yaw/pitch driving the eyeLook channels, blinks every 2-5 s; left/right pairs share the latent with
a fixed asymmetry of up to 12 % and a little independent drift. tracked = what a tracker reports: the clean
curve sampled with a timing jitter of 0.25 frame RMS, times a per-channel gain 0.85-1.15 (blinks 0.65-0.8),
plus an offset 0-0.04, cross-talk (0.15 jawOpen into mouthClose, 0.25 mouthSmile into eyeSquint), white noise
0.012, outlier spikes (+0.3..0.7 on 1-6 channels in ~0.6 % of frames), clipped to [0, 1]; angles + 0.01 rad noise.

| array | shape, dtype | meaning |
|---|---|---|
| face_names | (52,) str | ARKit names, canonical order (gazepipe.arkit.ARKIT_NAMES) |
| face_time_s | (n,) f8 | capture instant of every capture frame, seconds from the first |
| face_timecode | (n,) str | its timecode |
| face_clean, face_tracked | (n, 52) f4 | values of every capture frame, ARKit order (also where dropped) |
| face_clean_angles, face_tracked_angles | (n, 9) f4 | head yaw/pitch/roll, left eye, right eye (radians) |
| face_clean_dropped, face_tracked_dropped | (n,) bool | capture frames missing from that file |
| face_spikes | (n, 52) bool | where an outlier spike was added to the tracked values |
| face_gain, face_offset | (52,) f8 | the tracked track's per-channel gain and offset |

truth.json `takes.<id>`: `rate_hz`, `timecode_fps`, `duration_s`, `n_frames`, `clock_drift`, `head_tracking`,
`clean`, `tracked`, `dropped_clean`, `dropped_tracked`, `first_timecode`.
"""

#: appended to :data:`TRUTH_README` for a session with markers in no segment (``SynthConfig.unlisted_markers``)
UNLISTED_README = """
## Markers in no segment

The capture also carries markers that markerset.toml lists in no segment (`unlisted_markers` in truth.json),
after the listed subject markers: LSHO and RSHO (the shoulders, 340 mm apart, moving with the chest plus up to
20 mm of shrugging and 15 mm of reaching of their own) and, with `arms`, LELB and RELB (the elbows, on upper
arms swinging up to 20 degrees about the shoulder joints); `unlisted_motion` scales that motion. They move on
their own only while the body moves (the rests are the body's), get gaps, spikes and bursts like any marker,
and label swaps exchange them too (the mirror pairs, a shoulder and its elbow, a shoulder and the chest's marker
on its side).
"""
