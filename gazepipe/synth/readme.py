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

Per take (`takes.<id>`): `kind`, `pose`, `mocap`, `rate_hz`, `n_frames`, `clap_times_s`, `rest_periods`, `crop`,
`design` (the generating parameters: rest lengths, reaction delay, clap closing durations, target goals for
gaze_follow; per-segment onset times in seconds, duration, overshoot beta and its time, final per-segment
yaw/pitch for gaze_shift), and for gaze_shift takes the SPEC 3.6 gaze_map quantities:

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
"""
