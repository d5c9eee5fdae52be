"""Time of the sync and eyes stages per take, on a generated corpus (default: Klein's, ``bench/_work/klein_x1``).

The stages' inputs are the tables ``gazepipe run`` writes: when ``--out`` has none, the sessions are run once
(serial) into it. Then, per take, the registered stages (``gazepipe.pipeline.steps`` ``run_sync`` and
``run_eyes``) run on those tables ``--repeats`` times, with one BLAS thread as in a run, and the minimum is kept:

- ``sync``: the whole unit as the pipeline wires it (video probe, frame reading, clap search, table);
- ``probe``: the video probe alone (part of ``sync``);
- ``clap search``: ``sync_take`` alone, reading the video through one ``read_frames`` call per window (as
  ``run_sync`` does), and, when ``gazepipe.io.video`` has it, through one ``FrameReader`` for the take;
- ``eyes``: the whole unit (OpenFace CSV, joints table, gating, camera rotation and lag fit, table);
- ``eyes_take``: the stage function alone.

Last, each unit's output is compared with the table the run stored (written by the code of that run): the
largest change of the clock offset (ms), ratio (ppm) and video clap times (ms), and of the eye directions
(degrees) and validity, and whether the tables are equal value for value, so that a change of results shows
next to a change of speed.

Usage: ``PYTHONPATH=. python bench/bench_stage_speed.py [SESSION ...] [--out DIR] [--repeats N] [--takes N]``
"""

from __future__ import annotations

import argparse
import subprocess
import sys
import time
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pyarrow as pa
from threadpoolctl import threadpool_limits

from gazepipe.io.openface import read_openface
from gazepipe.io.session_toml import load_session
from gazepipe.io.video import probe_video, read_frames
from gazepipe.pipeline import registry
from gazepipe.pipeline.registry import UnitContext
from gazepipe.pipeline.runner import _loader, stage_params
from gazepipe.pipeline.state import OutLayout
from gazepipe.pipeline.steps import EyesParams, SyncParams
from gazepipe.schemas.joints import joints_arrays
from gazepipe.schemas.markers import table_to_markers
from gazepipe.stages.eyes import eyes_take
from gazepipe.stages.sync import ClockMap, sync_take

try:
    from gazepipe.io.video import FrameReader
except ImportError:  # the older layout: one read_frames call per window only
    FrameReader = None

BENCH = Path(__file__).resolve().parent
ROOT = BENCH.parent
CORPUS = BENCH / "_work" / "klein_x1"


def _best(fn, repeats: int) -> tuple[float, object]:
    """Smallest wall time of ``repeats`` calls of ``fn`` (ms), and its last result."""
    best, out = np.inf, None
    for _ in range(repeats):
        t0 = time.perf_counter()
        out = fn()
        best = min(best, time.perf_counter() - t0)
    return best * 1e3, out


def _ensure_tables(sessions: list[Path], out: Path) -> None:
    layout = OutLayout(out)
    missing = [s for s in sessions for t in load_session(s / "session.toml").takes
               if t.eyes is not None and not layout.table(s.name, t.id, "eyes").exists()]
    if missing:
        print(f"running gazepipe once into {out} for the stages' inputs ...", flush=True)
        subprocess.run([sys.executable, "-m", "gazepipe", "run", *map(str, sessions), "--out", str(out),
                        "--executor", "serial", "--log-format", "text", "--heartbeat", "0"],
                       check=False, cwd=ROOT, stdout=subprocess.DEVNULL)


def _angle_deg(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    return np.rad2deg(np.arctan2(np.linalg.norm(np.cross(a, b), axis=-1), np.sum(a * b, axis=-1)))


def _sync_change(new, old) -> tuple[float, float, float]:
    """Largest |change| of offset (ms), ratio (ppm), video clap time (ms) between two sync tables."""
    col = lambda t, c: np.asarray(t.column(c).to_numpy(zero_copy_only=False), float)  # noqa: E731
    d_off = np.max(np.abs(col(new, "offset_s") - col(old, "offset_s"))) * 1e3
    d_ratio = np.max(np.abs(col(new, "ratio") - col(old, "ratio"))) * 1e6
    dv = col(new, "video_s") - col(old, "video_s")
    return float(d_off), float(d_ratio), float(np.nanmax(np.abs(dv)) * 1e3) if np.isfinite(dv).any() else 0.0


def _eyes_change(new, old) -> tuple[float, int]:
    """Largest eye-direction change (degrees) over frames valid in both, and frames whose validity changed."""
    vn = np.asarray(new.column("valid").to_numpy(zero_copy_only=False), bool)
    vo = np.asarray(old.column("valid").to_numpy(zero_copy_only=False), bool)
    dn = np.asarray(new.column("eye_dir_char").combine_chunks().flatten().to_numpy(zero_copy_only=False),
                    float).reshape(-1, 3)
    do = np.asarray(old.column("eye_dir_char").combine_chunks().flatten().to_numpy(zero_copy_only=False),
                    float).reshape(-1, 3)
    both = vn & vo
    ang = _angle_deg(dn[both], do[both])
    return (float(np.nanmax(ang)) if ang.size else 0.0), int(np.count_nonzero(vn != vo))


def _sync_parts(ctx: UnitContext, repeats: int) -> tuple[float, float, float]:
    """(probe, clap search with one read_frames call per window, clap search with one FrameReader) in ms."""
    take, ms = ctx.take, ctx.session.markerset
    p = SyncParams()
    ms_probe, probe = _best(lambda: probe_video(take.video), repeats)
    ts = probe.timestamps_s
    mk = table_to_markers(ctx.load("markers_raw"))[0]
    a, b = mk.labels.index(ms.clapper[0]), mk.labels.index(ms.clapper[1])
    args = (mk.xyz[:, a], mk.xyz[:, b], mk.valid[:, a], mk.valid[:, b], mk.rate_hz, ts)
    kw = dict(window_s=p.window_s, search_s=p.search_s, max_drift=p.max_drift, min_confidence=p.min_confidence)

    def per_window():
        def rw(start: int, stop: int):
            return read_frames(take.video, start, stop, gray=True, scale=p.video_scale, timestamps_s=ts)
        return sync_take(*args, rw, **kw)

    def one_reader():
        with FrameReader(take.video, gray=True, scale=p.video_scale, timestamps_s=ts) as rw:
            return sync_take(*args, rw, **kw)

    ms_window = _best(per_window, repeats)[0]
    ms_reader = _best(one_reader, repeats)[0] if FrameReader is not None else np.nan
    return ms_probe, ms_window, ms_reader


def _eyes_take_ms(ctx: UnitContext, repeats: int) -> float:
    """eyes_take alone, on the inputs run_eyes gives it, in ms."""
    eye = read_openface(ctx.take.eyes)
    ja = joints_arrays(ctx.load("joints"))
    joints = SimpleNamespace(segments=ja["segments"], quat=ja["quat"], target_dir=ja["target_dir"],
                             char_rot=ja["char_rot"], rate_hz=ja["meta"]["rate_hz"])
    st = ctx.load("sync")
    clock = ClockMap(offset_s=float(st.column("offset_s")[0].as_py()), ratio=float(st.column("ratio")[0].as_py()),
                     n_claps=st.num_rows)
    cam = ctx.session.markerset.camera_rotation
    cam = None if cam is None else np.asarray(cam, dtype=np.float64)
    return _best(lambda: eyes_take(eye, joints, ja["time_s"], clock, camera_rotation=cam, params=EyesParams()),
                 repeats)[0]


def _same(new, old) -> bool:
    """Tables equal value for value (NaN equal to NaN), with the same columns and metadata."""
    if new.column_names != old.column_names or new.schema.metadata != old.schema.metadata:
        return False
    for name in new.column_names:
        a, b = new.column(name).combine_chunks(), old.column(name).combine_chunks()
        while pa.types.is_list(a.type) or pa.types.is_fixed_size_list(a.type):
            a, b = a.flatten(), b.flatten()
        x, y = a.to_numpy(zero_copy_only=False), b.to_numpy(zero_copy_only=False)
        if x.shape != y.shape or not np.array_equal(x, y, equal_nan=x.dtype.kind == "f"):
            return False
    return True


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("sessions", nargs="*", type=Path, help="session folders (default: every one in klein_x1)")
    ap.add_argument("--out", type=Path, default=BENCH / "_work" / "stage_speed", help="the run's output folder")
    ap.add_argument("--repeats", type=int, default=5)
    ap.add_argument("--takes", type=int, default=0, help="time only the first N takes (0: all)")
    args = ap.parse_args()
    sessions = [s.resolve() for s in (args.sessions or sorted(p for p in CORPUS.iterdir() if p.is_dir()))]
    out = args.out.resolve()
    _ensure_tables(sessions, out)
    load = _loader(OutLayout(out))
    sync_st, eyes_st = registry.get("sync"), registry.get("eyes")
    rows = []
    print(f"{'take':<34} {'sync':>7} {'probe':>7} {'search':>7} {'search1':>8} {'eyes':>7} {'eyes_take':>9} | "
          f"{'d off ms':>8} {'d ratio':>8} {'d clap ms':>9} {'d eye deg':>9} {'d valid':>7} {'same':>4}")
    with threadpool_limits(limits=1):
        for s in sessions:
            session = load_session(s / "session.toml")
            for take in session.takes:
                if not (sync_st.applies(session, take) and eyes_st.applies(session, take)):
                    continue
                if args.takes and len(rows) >= args.takes:
                    break
                ctx_s = UnitContext(session, take, stage_params(sync_st, {}), out, load, {})
                ctx_e = UnitContext(session, take, stage_params(eyes_st, {}), out, load, {})
                ms_sync, res_s = _best(lambda c=ctx_s: sync_st.run(c), args.repeats)
                ms_eyes, res_e = _best(lambda c=ctx_e: eyes_st.run(c), args.repeats)
                ms_probe, ms_search, ms_search1 = _sync_parts(ctx_s, args.repeats)
                ms_et = _eyes_take_ms(ctx_e, args.repeats)
                new_s, new_e = res_s.tables["sync"][0], res_e.tables["eyes"][0]
                old_s, old_e = ctx_s.load("sync"), ctx_e.load("eyes")
                d_off, d_ratio, d_clap = _sync_change(new_s, old_s)
                d_eye, d_valid = _eyes_change(new_e, old_e)
                same = ("s" if _same(new_s, old_s) else "-") + ("e" if _same(new_e, old_e) else "-")
                row = (ms_sync, ms_probe, ms_search, ms_search1, ms_eyes, ms_et)
                rows.append(row)
                print(f"{s.name + '/' + take.id:<34} {ms_sync:7.1f} {ms_probe:7.1f} {ms_search:7.1f} "
                      f"{ms_search1:8.1f} {ms_eyes:7.1f} {ms_et:9.1f} | {d_off:8.4f} {d_ratio:8.3f} {d_clap:9.4f} "
                      f"{d_eye:9.2e} {d_valid:7d} {same:>4}", flush=True)
    r = np.array(rows)
    widths = (7, 7, 7, 8, 7, 9)
    print(f"{'mean over ' + str(len(rows)) + ' takes (ms)':<34} "
          + " ".join(f"{x:{w}.1f}" for x, w in zip(r.mean(axis=0), widths, strict=True)))
    print(f"{'total (s)':<34} " + " ".join(f"{x / 1e3:{w}.2f}" for x, w in zip(r.sum(axis=0), widths, strict=True)))
    print("(minimum of --repeats runs per take; search: sync_take with one read_frames call per window, "
          "search1: with one FrameReader per take; d: change against the tables the run stored; same: s and/or e "
          "when the sync and/or eyes table equals the stored one value for value)")


if __name__ == "__main__":
    main()
