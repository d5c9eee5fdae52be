"""Time of the sync and eyes stages per take, on a generated corpus (default: Klein's, ``bench/_work/klein_x1``).

The stages' inputs are the tables ``gazepipe run`` writes: when ``--out`` has none, the sessions are run once
(serial) into it. Then, per take, the registered stages (declared in ``gazepipe.dag.takes``; their runs
``run_sync`` and ``run_eyes`` in ``gazepipe.dag.nodes``) run on those tables ``--repeats`` times, with one BLAS thread as in a run, and the minimum is kept:

- ``sync``: the whole unit as the pipeline wires it (video probe, frame reading, clap search, table);
- ``probe``: the video probe alone (part of ``sync``);
- ``search``: ``sync_take`` alone, reading the video through one ``read_frames`` call per window (as
  ``run_sync`` does); ``search1``: through one ``FrameReader`` for the take, when ``gazepipe.io.video`` has it;
- ``eyes``: the whole unit (OpenFace CSV, joints table, gating, camera rotation and lag fit, table);
- ``eyes_take``: the stage function alone.

Each unit's output is compared with the table the run stored (written by the code of that run): the largest
change of the clock offset (ms), ratio (ppm) and video clap times (ms), and of the eye directions (degrees) and
validity, and whether the tables are equal value for value, so that a change of results shows next to a change
of speed.

``--baseline DIR`` times another checkout of the package (e.g. ``git worktree add /tmp/base <commit>``) back to
back with this one: a worker process imports it, and every repeat of every take runs once here and once there,
alternately, so that both see the same load; the table then gives both minima and their ratio.

Times are wall times, or with ``--cpu`` the process's CPU time (all its threads: less sensitive to other
processes, and it counts the work of extra decoding threads).

Usage: ``PYTHONPATH=. python bench/bench_stage_speed.py [SESSION ...] [--out DIR] [--repeats N] [--takes N]
[--baseline DIR] [--cpu]``
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import time
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pyarrow as pa
from threadpoolctl import threadpool_limits

import gazepipe.dag
from gazepipe.io.openface import read_openface
from gazepipe.io.session_toml import load_session
from gazepipe.io.video import probe_video, read_frames
from gazepipe.model import Session, Take
from gazepipe.pipeline import registry
from gazepipe.pipeline.registry import UnitContext
from gazepipe.pipeline.runner import _loader, stage_params
from gazepipe.pipeline.state import OutLayout
from gazepipe.schemas.joints import joints_arrays
from gazepipe.schemas.markers import table_to_markers
from gazepipe.stages.eyes.params import EyesParams
from gazepipe.stages.eyes.stage import eyes_take
from gazepipe.stages.sync.clock import ClockMap
from gazepipe.stages.sync.stage import SyncParams, sync_take

gazepipe.dag.declare()   # the stages run below

try:
    from gazepipe.io.video import FrameReader
except ImportError:  # the older layout: one read_frames call per window only
    FrameReader = None

BENCH = Path(__file__).resolve().parent
ROOT = BENCH.parent
CORPUS = BENCH / "_work" / "klein_x1"
COLUMNS = ("sync", "probe", "search", "search1", "eyes", "eyes_take")


_CLOCK = time.perf_counter  # time.process_time with --cpu


def _ms(fn) -> tuple[float, object]:
    """Time of one call of ``fn`` in ms (wall, or CPU with --cpu), and its result."""
    t0 = _CLOCK()
    out = fn()
    return (_CLOCK() - t0) * 1e3, out


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


class _Take:
    """One take's inputs, prepared once, and one timed pass over every measurement (:meth:`once`)."""

    def __init__(self, session: Session, take: Take, out: Path) -> None:
        load = _loader(OutLayout(out))
        self.sync_st, self.eyes_st = registry.get("sync"), registry.get("eyes")
        self.ctx_s = UnitContext(session, take, stage_params(self.sync_st, {}), out, load, {})
        self.ctx_e = UnitContext(session, take, stage_params(self.eyes_st, {}), out, load, {})
        self.results: dict[str, object] = {}
        p, ms = SyncParams(), session.markerset
        self.video, self.scale = take.video, p.video_scale
        self.ts = probe_video(take.video).timestamps_s
        mk = table_to_markers(self.ctx_s.load("markers_raw"))[0]
        a, b = mk.labels.index(ms.clapper[0]), mk.labels.index(ms.clapper[1])
        self.sync_args = (mk.xyz[:, a], mk.xyz[:, b], mk.valid[:, a], mk.valid[:, b], mk.rate_hz, self.ts)
        self.sync_params = p
        self.eye = read_openface(take.eyes)
        ja = joints_arrays(self.ctx_e.load("joints"))
        self.mocap_time_s = ja["time_s"]
        self.joints = SimpleNamespace(segments=ja["segments"], quat=ja["quat"], target_dir=ja["target_dir"],
                                      char_rot=ja["char_rot"], rate_hz=ja["meta"]["rate_hz"])
        st = self.ctx_e.load("sync")
        self.clock = ClockMap(offset_s=float(st.column("offset_s")[0].as_py()),
                              ratio=float(st.column("ratio")[0].as_py()), n_claps=st.num_rows)
        cam = ms.camera_rotation
        self.camera = None if cam is None else np.asarray(cam, dtype=np.float64)

    def _per_window(self):
        def rw(start: int, stop: int):
            return read_frames(self.video, start, stop, gray=True, scale=self.scale, timestamps_s=self.ts)
        return sync_take(*self.sync_args, rw, self.sync_params)

    def _one_reader(self):
        with FrameReader(self.video, gray=True, scale=self.scale, timestamps_s=self.ts) as rw:
            return sync_take(*self.sync_args, rw, self.sync_params)

    def _eyes_take(self):
        return eyes_take(self.eye, self.joints, self.mocap_time_s, self.clock, camera_rotation=self.camera,
                         params=EyesParams())

    def once(self) -> dict[str, float]:
        """ms per measurement (:data:`COLUMNS`) of one pass; the units' results are kept in ``results``."""
        t: dict[str, float] = {}
        t["sync"], self.results["sync"] = _ms(lambda: self.sync_st.run(self.ctx_s))
        t["probe"] = _ms(lambda: probe_video(self.video))[0]
        t["search"] = _ms(self._per_window)[0]
        t["search1"] = _ms(self._one_reader)[0] if FrameReader is not None else float("nan")
        t["eyes"], self.results["eyes"] = _ms(lambda: self.eyes_st.run(self.ctx_e))
        t["eyes_take"] = _ms(self._eyes_take)[0]
        return t

    def changes(self) -> str:
        """The last results against the stored tables (see the module docstring)."""
        new_s, new_e = self.results["sync"].tables["sync"][0], self.results["eyes"].tables["eyes"][0]
        old_s, old_e = self.ctx_s.load("sync"), self.ctx_e.load("eyes")
        d_off, d_ratio, d_clap = _sync_change(new_s, old_s)
        d_eye, d_valid = _eyes_change(new_e, old_e)
        same = ("s" if _same(new_s, old_s) else "-") + ("e" if _same(new_e, old_e) else "-")
        return f"{d_off:8.4f} {d_ratio:8.3f} {d_clap:9.4f} {d_eye:9.2e} {d_valid:7d} {same:>4}"


def _takes(sessions: list[Path]):
    """(session folder, Session, Take) of every take both stages apply to."""
    sync_st, eyes_st = registry.get("sync"), registry.get("eyes")
    for s in sessions:
        session = load_session(s / "session.toml")
        for take in session.takes:
            if sync_st.applies(session, take) and eyes_st.applies(session, take):
                yield s, session, take


def _worker(out: Path) -> None:
    """Serve timed passes on stdin/stdout, one JSON line each way: {"session": folder, "take": id}."""
    prepared: dict[tuple[str, str], _Take] = {}
    with threadpool_limits(limits=1):
        for line in sys.stdin:
            req = json.loads(line)
            key = (req["session"], req["take"])
            if key not in prepared:
                session = load_session(Path(req["session"]) / "session.toml")
                take = next(t for t in session.takes if t.id == req["take"])
                prepared[key] = _Take(session, take, out)
            print(json.dumps(prepared[key].once()), flush=True)


def _start_baseline(path: Path, out: Path) -> subprocess.Popen:
    env = dict(os.environ, PYTHONPATH=str(path.resolve()))
    cmd = [sys.executable, str(Path(__file__).resolve()), "--worker", "--out", str(out)]
    cmd += ["--cpu"] if _CLOCK is time.process_time else []
    return subprocess.Popen(cmd, cwd=ROOT, env=env, stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True)


def _ask(worker: subprocess.Popen, session: Path, take: str) -> dict[str, float]:
    worker.stdin.write(json.dumps({"session": str(session), "take": take}) + "\n")
    worker.stdin.flush()
    line = worker.stdout.readline()
    if not line:
        raise SystemExit("the baseline worker stopped (see its error above)")
    return json.loads(line)


def _min(passes: list[dict[str, float]]) -> dict[str, float]:
    return {c: float(np.min([p[c] for p in passes])) for c in COLUMNS}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("sessions", nargs="*", type=Path, help="session folders (default: every one in klein_x1)")
    ap.add_argument("--out", type=Path, default=BENCH / "_work" / "stage_speed", help="the run's output folder")
    ap.add_argument("--repeats", type=int, default=5)
    ap.add_argument("--takes", type=int, default=0, help="time only the first N takes (0: all)")
    ap.add_argument("--baseline", type=Path, help="another checkout to time back to back with this one")
    ap.add_argument("--cpu", action="store_true",
                    help="CPU time of this process (all its threads) instead of wall time: less sensitive to other "
                         "processes on the machine, and it counts the work of extra decoding threads")
    ap.add_argument("--worker", action="store_true", help=argparse.SUPPRESS)
    args = ap.parse_args()
    global _CLOCK
    _CLOCK = time.process_time if args.cpu else time.perf_counter
    out = args.out.resolve()
    if args.worker:
        _worker(out)
        return
    sessions = [s.resolve() for s in (args.sessions or sorted(p for p in CORPUS.iterdir() if p.is_dir()))]
    _ensure_tables(sessions, out)
    worker = _start_baseline(args.baseline, out) if args.baseline else None
    rows, base_rows = [], []
    if worker is None:
        print(f"{'take':<34} " + " ".join(f"{c:>9}" for c in COLUMNS) + " | "
              f"{'d off ms':>8} {'d ratio':>8} {'d clap ms':>9} {'d eye deg':>9} {'d valid':>7} {'same':>4}")
    else:
        print(f"{'take':<34} " + " ".join(f"{c + ' base/new':>20}" for c in ("sync", "search1", "eyes", "eyes_take"))
              + f" | {'same':>4}")
    with threadpool_limits(limits=1):
        for s, session, take in _takes(sessions):
            if args.takes and len(rows) >= args.takes:
                break
            t = _Take(session, take, out)
            passes, base = [], []
            for _ in range(args.repeats):
                passes.append(t.once())
                if worker is not None:
                    base.append(_ask(worker, s, take.id))
            row = _min(passes)
            rows.append(row)
            name = f"{s.name}/{take.id}"
            if worker is None:
                print(f"{name:<34} " + " ".join(f"{row[c]:9.1f}" for c in COLUMNS) + f" | {t.changes()}", flush=True)
                continue
            b = _min(base)
            if not np.isfinite(b["search1"]):
                b["search1"] = b["search"]  # a baseline without FrameReader: its clap search as wired
            base_rows.append(b)
            cells = [f"{b[c]:7.1f} {row[c]:6.1f} {b[c] / row[c]:4.1f}x" for c in ("sync", "search1", "eyes", "eyes_take")]
            print(f"{name:<34} " + " ".join(f"{x:>20}" for x in cells) + f" | {t.changes()[-4:]}", flush=True)
    if worker is not None:
        worker.stdin.close()
        worker.wait()
    mean = {c: float(np.mean([r[c] for r in rows])) for c in COLUMNS}
    if not base_rows:
        print(f"{'mean over ' + str(len(rows)) + ' takes (ms)':<34} " + " ".join(f"{mean[c]:9.1f}" for c in COLUMNS))
        print("(minimum of --repeats runs per take; search: sync_take with one read_frames call per window, "
              "search1: with one FrameReader per take; d: change against the tables the run stored; same: s "
              "and/or e when the sync and/or eyes table equals the stored one value for value)")
        return
    bmean = {c: float(np.mean([r[c] for r in base_rows])) for c in COLUMNS}
    print(f"\nmean over {len(rows)} takes, ms (baseline -> this tree, ratio):")
    for c in COLUMNS:
        print(f"  {c:<10} {bmean[c]:8.1f} -> {mean[c]:7.1f}   {bmean[c] / mean[c]:5.2f}x")
    print(f"  sync with one FrameReader per take (sync - search + search1): {bmean['sync']:.1f} -> "
          f"{mean['sync'] - mean['search'] + mean['search1']:.1f} ms")
    print("(per take the minimum of --repeats passes, each pass here and in the baseline alternately; a baseline "
          "without FrameReader has its search as search1)")


if __name__ == "__main__":
    main()
