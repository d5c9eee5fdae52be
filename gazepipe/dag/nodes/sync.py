"""The sync stage's run: the clapper's claps found on the mocap and video clocks
(:func:`gazepipe.stages.sync.stage.sync_take`), written as the take's ``sync`` table."""

from __future__ import annotations

from gazepipe.dag.nodes.common import TakeContext, file_notes, given
from gazepipe.pipeline.registry import UnitResult, params_from


def run_sync(ctx: TakeContext) -> UnitResult:
    from gazepipe.io.video import FrameReader, probe_video
    from gazepipe.schemas.markers import table_to_markers
    from gazepipe.schemas.sync_table import sync_to_table
    from gazepipe.schemas.tracks import SYNC
    from gazepipe.stages.sync.coverage import short_video_note
    from gazepipe.stages.sync.stage import SyncParams, sync_take

    take, ms = ctx.take, given(ctx.session.markerset, "markerset")
    video = given(take.video, "video")
    p = params_from(SyncParams, ctx.params)
    raw = table_to_markers(ctx.load("markers_raw"))[0]
    a, b = raw.index(ms.clapper[0]), raw.index(ms.clapper[1])
    probe = probe_video(video)
    ts = probe.timestamps_s
    # one open capture for all of the take's windows, read forward
    with FrameReader(video, gray=True, scale=p.video_scale, timestamps_s=ts) as read_window:
        res = sync_take(raw.xyz[:, a], raw.xyz[:, b], raw.valid[:, a], raw.valid[:, b], raw.rate_hz, ts,
                        read_window, p, mocap_path=take.mocap, video_path=take.video, take=take.id)
        damage = read_window.damage_warning()
    table = sync_to_table(res, int(ts.size), probe.nominal_fps)
    qc = dict(res.qc)
    notes = probe.warnings + ([damage] if damage else []) + short_video_note(ts, raw.n_frames / raw.rate_hz)
    qc["warnings"] = list(qc.get("warnings", [])) + file_notes(ctx.session, video, notes)
    return UnitResult(tables={"sync": (table, SYNC)}, qc=qc, warnings=qc["warnings"])
