"""The built-in stages, registered in dependency order.

Each entry wires a pure function of :mod:`gazepipe.stages` to the engine: which takes it applies to, which raw
files it reads (through :mod:`gazepipe.io`), which upstream tables it loads and which tables it returns.
"""

from __future__ import annotations

from gazepipe.io.capture import read_markers
from gazepipe.io.session_toml import check_capture_labels
from gazepipe.model import Session, Take
from gazepipe.pipeline.registry import Stage, UnitContext, UnitResult, register
from gazepipe.schemas.markers import MARKERS_RAW, markers_to_table


def _has_mocap(session: Session, take: Take) -> bool:
    return take.mocap is not None


def _markerset_file(session: Session) -> list[str]:
    return [session.markerset.path] if session.markerset else []


# ------------------------------------------------------------------------------------------------ ingest

def _required_markers(ms, take: Take) -> list[str]:
    """Markers a take of this kind cannot do without: the subject's, the target when the subject follows it,
    the clapper when a video must be synchronised."""
    names = list(ms.subject_markers)
    if take.kind == "gaze_follow" and ms.target:
        names.append(ms.target)
    if take.video and ms.clapper:
        names.extend(ms.clapper)
    return names


def run_ingest(ctx: UnitContext) -> UnitResult:
    take, ms = ctx.take, ctx.session.markerset
    markers = read_markers(take.mocap, rate_hz=take.rate_hz, default_units=ms.units if ms else "mm")
    meta: dict = {}
    if ms is not None:
        mapping = check_capture_labels(ms, markers.labels, take.mocap, take.id, required=_required_markers(ms, take))
        renamed = {markers.labels[i]: name for name, i in mapping.items() if markers.labels[i] != name}
        if renamed:
            labels = [renamed.get(lab, lab) for lab in markers.labels]
            if len(set(labels)) == len(labels):
                markers.labels = labels
                meta["renamed_labels"] = renamed
    gap = markers.gap_fraction()
    qc = {
        "frames": markers.n_frames, "rate_hz": markers.rate_hz, "first_frame": markers.first_frame,
        "units_found": markers.units, "markers": markers.n_markers,
        "gap_fraction": {lab: round(float(g), 6) for lab, g in zip(markers.labels, gap, strict=True)},
        "model_outputs": len(markers.model_outputs),
    }
    table = markers_to_table(markers, meta=meta)
    return UnitResult(tables={"markers_raw": (table, MARKERS_RAW)}, qc=qc, warnings=list(markers.warnings))


register(Stage(
    name="ingest", version="1", requires=(), params={},
    outputs=("markers_raw",), applies=_has_mocap,
    sources=lambda s, t: [t.mocap, *_markerset_file(s)],
    run=run_ingest,
    help="read the take's capture files into canonical tables",
))
