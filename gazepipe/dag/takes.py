"""gazepipe's take stages and session stages, as declarations, in dependency order.

Each declaration names the tables a stage reads (``inputs``: of the same take; ``session_inputs``: of a session
stage; the engine derives the stages it follows from them and refuses a load of any other) and writes
(``outputs``), its parameters dataclass (the one source of their defaults, value rules and help), which takes it applies to, the raw files
it reads (content-hashed into its fingerprint) and its run. A run (:mod:`gazepipe.dag.nodes`) is glue: it reads
files through :mod:`gazepipe.io` and tables through its context, calls its stage's pure function
(:mod:`gazepipe.stages`) and returns the tables laid out by :mod:`gazepipe.schemas`. The runs import their
readers and stage functions when they run: planning needs only these declarations, so a run with nothing to do
never pays for importing scipy.signal, pandas or OpenCV. Nothing is registered on import:
:func:`gazepipe.dag.declare` hands these declarations to the engine.
"""

from __future__ import annotations

from gazepipe.dag.nodes.clean import run_clean
from gazepipe.dag.nodes.common import (
    eyes_take,
    face_take,
    frames_take,
    has_frames,
    has_mocap,
    has_subject,
    markerset_file,
    subject_files,
    subject_take,
    sync_take,
)
from gazepipe.dag.nodes.eyes import run_eyes
from gazepipe.dag.nodes.face import run_face
from gazepipe.dag.nodes.frames import run_frames
from gazepipe.dag.nodes.ingest import run_ingest
from gazepipe.dag.nodes.neutral import run_neutral_poses
from gazepipe.dag.nodes.subject import run_subject_geometry
from gazepipe.dag.nodes.sync import run_sync
from gazepipe.pipeline.registry import SessionStage, Stage
from gazepipe.stages.clean.stage import CleanParams
from gazepipe.stages.eyes.params import EyesParams
from gazepipe.stages.face.params import FaceParams
from gazepipe.stages.frames.stage import FramesParams
from gazepipe.stages.sync.stage import SyncParams

#: work done once per session, before its take units, that take stages read
SESSION_STAGES: tuple[SessionStage, ...] = (
    SessionStage(
        name="subject_geometry", version="2", uses=(), outputs=("subject_geometry",),
        applies=has_subject, sources=lambda s: [*markerset_file(s), *subject_files(s)],
        run=run_subject_geometry,
        help="the subject's marker geometry from every subject capture of the session, that label swaps are "
             "judged against",
    ),
    SessionStage(
        name="neutral_poses", version="1", inputs=("subject_geometry",), uses=("clean", "frames"),
        outputs=("neutral_poses",), applies=has_frames,
        sources=lambda s: [*markerset_file(s), *subject_files(s)],
        run=run_neutral_poses,
        help="the neutral take's pose and, for segments it lacks, other takes' first rest periods, cleaned once",
    ),
)

#: the stages that run once per take, each after the stages whose tables it reads
TAKE_STAGES: tuple[Stage, ...] = (
    Stage(
        name="ingest", version="2",
        outputs=("markers_raw",), applies=has_mocap,
        sources=lambda s, t: [t.mocap, *markerset_file(s)],
        run=run_ingest,
        help="read the take's capture files into canonical tables",
    ),
    Stage(
        name="clean", version="27", inputs=("markers_raw",), params_class=CleanParams,
        outputs=("markers", "neutral", "rest_speed"), applies=subject_take,
        # label swaps are judged against the subject's geometry from every subject capture of the session
        sources=lambda s, t: markerset_file(s), session_inputs=("subject_geometry",),
        run=run_clean,
        help="spikes, gap filling, root stabilisation, optional low-pass, rest cropping",
    ),
    Stage(
        name="frames", version="14", inputs=("markers", "neutral"), params_class=FramesParams,
        outputs=("joints",), applies=frames_take,
        sources=lambda s, t: markerset_file(s), session_inputs=("neutral_poses",),
        run=run_frames,
        help="segment orientations in the character frame, head centre, target direction",
    ),
    Stage(
        name="face", version="2", params_class=FaceParams,
        outputs=("face",), applies=face_take,
        sources=lambda s, t: [t.tracked, t.clean],
        run=run_face,
        help="tracked and clean Live Link Face tracks aligned on timecode, dt and derivatives",
    ),
    Stage(
        name="sync", version="5", inputs=("markers_raw",), params_class=SyncParams,
        outputs=("sync",), applies=sync_take,
        sources=lambda s, t: [t.video, *markerset_file(s)],
        run=run_sync,
        help="clapper claps on the mocap and video clocks, the clock map between them",
    ),
    Stage(
        name="eyes", version="2", inputs=("joints", "sync"), params_class=EyesParams,
        outputs=("eyes",), applies=eyes_take,
        sources=lambda s, t: [t.eyes, *markerset_file(s)],
        run=run_eyes,
        help="OpenFace gaze gated, blink-masked, bridged and rotated into the character frame",
    ),
)

