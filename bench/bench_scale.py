"""Benchmark ``gazepipe run`` at scale against the I/O floor.

``python bench/bench_scale.py bench/_work/klein_x1 [--scaling 1,2,4,8,16]`` (a corpus written by
``bench/make_corpus.py``) prints:

- the physical floor: every C3D's point block decoded with numpy, every CSV read with pandas, and the output
  bytes the run wrote (its Parquet files) written raw to one file and fsynced: what no pipeline can avoid;
- the encode floor: every mocap file decoded as the pipeline decodes it, every CSV read with pandas, and the tables the pipeline produced
  re-written with pyarrow with the pipeline's own writer options (the same output bytes); the output bytes per
  mocap frame;
- the share of each run's wall time after its last take unit (dataset builds and the QC report), also from the
  unit records' times, and the CPU seconds its processes used after it (what a shared machine does not blur);
- with ``--scaling``: a process-executor run at each worker count (as far as the machine's cores go) and its
  speed-up over serial;
- end-to-end ``gazepipe run`` wall time (a fresh ``python -m gazepipe`` process, serial executor) and its ratio
  to the floor; the no-op re-run (median of five; the package's bytecode is compiled first, as an install
  does); the same run with ``--executor process -j 2`` and ``--executor dask -j 2`` and their speed-ups over
  serial;
- time per stage (sums of the unit records' ``duration_s``; dataset builds from their records);
- peak memory: resident set of the whole process tree (the run and its workers), sampled every 50 ms;
- with ``--profile``: the serial run under cProfile, top functions by own time.

With ``--against REV`` (e.g. ``ff48992``) it instead times serial runs of that commit's package (checked out under
``bench/_work/rev-<sha>``) and of this tree, interleaved in fresh processes (``--repeats`` each, the minimum
kept), and prints the CPU seconds of the whole run (its process tree), of each stage (the unit records'
``cpu_s``; a commit that did not record it gives its ``duration_s``, which a serial run on an idle machine spends
on CPU), of the dataset builds and of the tail after the last take unit (the QC report), with the encode floor,
and whether the two versions wrote the same bytes (every table under takes/ and datasets/); then the report the
run ends with timed alone (``validate_output`` on a copy of each version's run, its take checks cached, in fresh
processes interleaved: the tail's main part without the sampling's blur).

Work folders go under ``--work`` (default ``bench/_work/scale``), one per executor, recreated each time.
"""

from __future__ import annotations

import argparse
import json
import os
import pstats
import shutil
import subprocess
import sys
import threading
import time
from collections import defaultdict
from pathlib import Path

import psutil

REPO = Path(__file__).resolve().parents[1]
if str(REPO) not in sys.path:
    sys.path.insert(0, str(REPO))


# ----------------------------------------------------------------------------------------------- measuring

class TreeMemory:
    """Peak resident memory of a process and all its descendants (sum over the tree, sampled), and the CPU time
    the tree has used at each sample (``cpu``: (time.time(), CPU seconds); a process that ended counts with its
    last sample)."""

    def __init__(self, pid: int, every_s: float = 0.05) -> None:
        self.pid, self.every_s = pid, every_s
        self.peak_total = 0
        self.peak_single = 0
        self.cpu: list[tuple[float, float]] = []
        self._cpu_of: dict[int, float] = {}
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._loop, daemon=True)
        self._thread.start()

    def _loop(self) -> None:
        try:
            root = psutil.Process(self.pid)
        except psutil.NoSuchProcess:
            return
        while not self._stop.is_set():
            total = 0
            try:
                procs = [root, *root.children(recursive=True)]
            except psutil.NoSuchProcess:
                break
            for p in procs:
                try:
                    rss = p.memory_info().rss
                    times = p.cpu_times()
                except (psutil.NoSuchProcess, psutil.AccessDenied):
                    continue
                total += rss
                self.peak_single = max(self.peak_single, rss)
                self._cpu_of[p.pid] = times.user + times.system
            self.peak_total = max(self.peak_total, total)
            self.cpu.append((time.time(), sum(self._cpu_of.values())))
            self._stop.wait(self.every_s)

    def stop(self) -> None:
        self._stop.set()
        self._thread.join()


def run_cli(sessions: list[Path], out: Path, executor: str, jobs: int | None = None, fresh: bool = True,
            profile: Path | None = None, params: list[str] | None = None, tree: Path = REPO) -> dict:
    """``python -m gazepipe run`` of the package in ``tree`` in a fresh process (``params``: its ``--param``
    values); wall time, exit code, peak memory of the process tree."""
    sessions, out = [Path(s).resolve() for s in sessions], Path(out).resolve()   # the run starts in ``tree``
    if fresh and out.exists():
        shutil.rmtree(out)
    cmd = [sys.executable]
    if profile is not None:
        cmd += ["-m", "cProfile", "-o", str(profile.resolve())]
    # absolute paths, and the run started in ``tree``: ``python -m`` puts its working directory first on the
    # path, so a run started elsewhere in a checkout would import that checkout's package, not ``tree``'s
    cmd += ["-m", "gazepipe", "run", *(str(Path(s).resolve()) for s in sessions), "--out", str(out.resolve()),
            "--executor", executor, "--log-format", "json"]
    if jobs:
        cmd += ["-j", str(jobs)]
    for kv in params or []:
        cmd += ["--param", kv]
    env = dict(os.environ, PYTHONPATH=os.pathsep.join([str(tree), *filter(None, [os.environ.get("PYTHONPATH")])]))
    # as an installed package runs: Python keeps its caches beside the code (bytecode, the code digests' memo)
    env.pop("PYTHONDONTWRITEBYTECODE", None)
    log = out.parent / f"{out.name}{'' if fresh else '.rerun'}.log"
    t0 = time.perf_counter()
    with open(log, "wb") as fh:
        proc = subprocess.Popen(cmd, stdout=fh, stderr=subprocess.STDOUT, env=env, cwd=str(tree))
        mem = TreeMemory(proc.pid)
        rc = proc.wait()
    wall = time.perf_counter() - t0
    end = time.time()
    mem.stop()
    if rc != 0:
        print(f"warning: {' '.join(cmd[-8:])} exited {rc}; see {log}", file=sys.stderr)
    return {"wall_s": wall, "end": end, "cpu": mem.cpu, "out": str(out), "rc": rc, "peak_tree_mb": mem.peak_total / 2**20,
            "peak_process_mb": mem.peak_single / 2**20, "log": str(log)}


def timeline(log: Path) -> dict[str, float] | None:
    """Seconds from a run's start (its JSON log; times have 1 s resolution) to its last take unit, to its last
    dataset build and to the QC report: where the time after the takes goes."""
    from datetime import datetime

    try:
        events = [json.loads(line) for line in log.read_text().splitlines() if line.startswith("{")]
    except (OSError, ValueError):
        return None
    if not events:
        return None

    def at(e: dict) -> float:
        return datetime.fromisoformat(e["time"].replace("Z", "+00:00")).timestamp()

    t0 = at(events[0])
    last = {k: max((at(e) - t0 for e in events if e.get("event") == k), default=float("nan"))
            for k in ("unit", "dataset", "qc_report", "run_end")}
    return {"takes_done_s": last["unit"], "datasets_done_s": last["dataset"], "report_done_s": last["qc_report"],
            "end_s": last["run_end"]}


def after_takes(run: dict, out: Path) -> dict[str, float] | None:
    """Seconds from the end of the last take unit (its record's modification time: no log's 1 s resolution) to
    the end of the run, and the CPU seconds the run's process tree used in them and in all (sampled every 50 ms):
    on a machine shared with other work, the CPU seconds say what the run itself left for after its takes."""
    records = [p.stat().st_mtime for p in (out / ".gazepipe" / "units").glob("*/*/*.json")]
    if not records or not run.get("cpu"):
        return None
    last = max(records)
    cpu_end = run["cpu"][-1][1]
    cpu_at = next((c for t, c in run["cpu"] if t >= last), cpu_end)
    return {"tail_s": max(run["end"] - last, 0.0), "cpu_s": cpu_end, "cpu_after_s": cpu_end - cpu_at}


def stage_times(out: Path, key: str = "duration_s") -> dict[str, float]:
    """Seconds per stage summed over takes (unit records), per session stage (``session:<name>``, summed over
    sessions) and per dataset build: ``key`` ``duration_s`` (wall)
    or ``cpu_s`` (CPU; a record without it gives its ``duration_s``)."""
    per: dict[str, float] = defaultdict(float)
    for p in (out / ".gazepipe" / "units").glob("*/*/*.json"):
        rec = json.loads(p.read_text())
        per[rec["stage"]] += float(rec.get(key, rec.get("duration_s", 0.0)))
    for p in (out / ".gazepipe" / "session_units").glob("*/*.json"):
        rec = json.loads(p.read_text())
        per[f"session:{p.stem}"] += float(rec.get(key, rec.get("duration_s", 0.0)))
    for p in (out / ".gazepipe" / "datasets").glob("*.json"):
        rec = json.loads(p.read_text())
        per[f"build:{p.stem}"] += float(rec.get(key, rec.get("duration_s", 0.0)))
    return dict(per)


def output_files(produced: Path) -> list[Path]:
    """The Parquet files a run wrote (not its state), each once: a dataset's take file is the take's
    ``rows_<dataset>`` table linked in, the same bytes written once."""
    seen: set[tuple[int, int]] = set()
    out = []
    for p in sorted(produced.rglob("*.parquet")):
        if ".gazepipe" in p.parts:
            continue
        st = p.stat()
        if (st.st_dev, st.st_ino) not in seen:
            seen.add((st.st_dev, st.st_ino))
            out.append(p)
    return out


def io_floor(sessions: list[Path], produced: Path) -> dict[str, float]:
    """Seconds to read every input (each C3D's point block decoded as the pipeline decodes it, which no
    pipeline can do much faster; pandas for CSV) and to write the same output tables with pyarrow and the
    pipeline's writer options (tables loaded beforehand; only the writes are timed)."""
    import pandas as pd
    import pyarrow.parquet as pq

    from gazepipe.io.c3d import _decode_points
    from gazepipe.io.c3d_meta import parse_c3d_meta
    from gazepipe.io.parquet import write_options

    c3d = sorted(p for s in sessions for p in (s / "mocap").glob("*.c3d"))
    csvs = sorted(p for s in sessions for sub in ("eyes", "face") for p in (s / sub).glob("*.csv"))
    t0 = time.perf_counter()
    frames = 0
    for p in c3d:
        data = p.read_bytes()
        frames += _decode_points(data, parse_c3d_meta(data).layout(len(data)))[0].shape[0]
    t_c3d = time.perf_counter() - t0
    t0 = time.perf_counter()
    for p in csvs:
        pd.read_csv(p, skipinitialspace=True)
    t_csv = time.perf_counter() - t0
    files = output_files(produced)
    tables = [pq.read_table(p) for p in files]
    sink = produced.parent / "_floor_write"
    sink.mkdir(exist_ok=True)
    t0 = time.perf_counter()
    n_bytes = 0
    for i, t in enumerate(tables):
        dest = sink / f"{i}.parquet"
        pq.write_table(t, dest, **write_options(t.schema))
        n_bytes += dest.stat().st_size
    t_write = time.perf_counter() - t0
    shutil.rmtree(sink)
    return {"read_c3d_s": t_c3d, "read_csv_s": t_csv, "write_parquet_s": t_write,
            "total_s": t_c3d + t_csv + t_write, "c3d_files": len(c3d), "csv_files": len(csvs),
            "mocap_frames": frames, "parquet_files": len(files), "parquet_mb": n_bytes / 2**20}


def physical_floor(sessions: list[Path], produced: Path) -> dict[str, float]:
    """The physical floor: what no pipeline can avoid. Every C3D read and its point block decoded with numpy
    (gazepipe's own one-pass decode of the validated layout), every CSV read with pandas, and the output bytes
    the run wrote (Parquet files of the takes and datasets) written raw to one file and fsynced."""
    import pandas as pd

    from gazepipe.io.c3d import _decode_points
    from gazepipe.io.c3d_meta import parse_c3d_meta

    c3d = sorted(p for s in sessions for p in (s / "mocap").glob("*.c3d"))
    csvs = sorted(p for s in sessions for sub in ("eyes", "face") for p in (s / sub).glob("*.csv"))
    t0 = time.perf_counter()
    for p in c3d:
        data = p.read_bytes()
        _decode_points(data, parse_c3d_meta(data).layout(len(data)))
    t_c3d = time.perf_counter() - t0
    t0 = time.perf_counter()
    for p in csvs:
        pd.read_csv(p, skipinitialspace=True)
    t_csv = time.perf_counter() - t0
    blobs = [p.read_bytes() for p in output_files(produced)]
    dest = produced.parent / "_physical_floor.bin"
    t0 = time.perf_counter()
    with open(dest, "wb") as fh:
        for b in blobs:
            fh.write(b)
        fh.flush()
        os.fsync(fh.fileno())
    t_write = time.perf_counter() - t0
    dest.unlink()
    n_bytes = sum(len(b) for b in blobs)
    return {"read_c3d_s": t_c3d, "read_csv_s": t_csv, "write_raw_s": t_write, "total_s": t_c3d + t_csv + t_write,
            "output_bytes": n_bytes}


def top_profile(path: Path, n: int = 15) -> list[str]:
    st = pstats.Stats(str(path))
    rows = []
    total = st.total_tt
    for (file, line, fn), (_cc, nc, tt, ct, _callers) in sorted(st.stats.items(), key=lambda kv: -kv[1][2])[:n]:
        short = file.replace(str(REPO) + "/", "").split("site-packages/")[-1]
        rows.append(f"{tt:8.2f} s own {100 * tt / total:5.1f} %  {ct:8.2f} s cum  {nc:>8} calls  {short}:{line}({fn})")
    return rows


# ----------------------------------------------------------------------------------------------- main

def _tables(out: Path) -> dict[str, bytes]:
    """Every Parquet table a run wrote under takes/ and datasets/, by path relative to ``out``."""
    return {str(p.relative_to(out)): p.read_bytes() for sub in ("takes", "datasets")
            for p in sorted((out / sub).rglob("*.parquet"))}


def _cpu_total(run: dict) -> float:
    """The CPU seconds the run's process tree used (its last sample)."""
    return run["cpu"][-1][1] if run["cpu"] else float("nan")


#: the report a serial run writes at its end, timed alone in a fresh process of one tree: on a copy of a finished
#: run whose cached plots, replays and dataset parts are removed (its take checks kept, as the takes' workers
#: leave them), after importing what a run has imported by then; prints the CPU seconds of ``validate_output``
_REPORT_CHILD = """
import os, shutil, sys, time
import gazepipe.dag.takes, gazepipe.dag.builds, gazepipe.report.run_report
import gazepipe.io.tracks, gazepipe.stages.geometry, pandas, scipy.spatial  # the takes' stages loaded them
from gazepipe.report.validate import validate_output
src, dst = sys.argv[1:3]
shutil.rmtree(dst, ignore_errors=True)
drop = {os.path.join(src, '.gazepipe', n) for n in ('report_plots', 'report_replays', 'report_datasets')}
shutil.copytree(src, dst, ignore=lambda d, names: [n for n in names if os.path.join(d, n) in drop | {os.path.join(src, 'qc')}])
t = time.process_time()
validate_output(dst, lock=False)
print(time.process_time() - t)
"""


def report_alone(trees: dict[str, Path], outs: dict[str, Path], work: Path, repeats: int) -> dict[str, float]:
    """CPU seconds of the end-of-run report of each tree (:data:`_REPORT_CHILD` on its run's output ``outs``),
    interleaved, the minimum of ``repeats``."""
    best: dict[str, float] = {}
    for _ in range(repeats):
        for side, tree in trees.items():
            env = dict(os.environ, PYTHONPATH=str(tree))
            res = subprocess.run([sys.executable, "-c", _REPORT_CHILD, str(outs[side]), str(work / f"report_{side}")],
                                 capture_output=True, text=True, env=env, cwd=str(tree))
            if res.returncode == 0:
                best[side] = min(best.get(side, float("inf")), float(res.stdout.split()[-1]))
            else:
                print(f"warning: the report of {side} failed: {res.stderr[-500:]}", file=sys.stderr)
    return best


def against(a: argparse.Namespace, sessions: list[Path], work: Path) -> int:
    """Serial runs of ``a.against`` and of this tree interleaved in fresh processes; CPU per stage, old vs new."""
    import compileall

    from bench.bench_fill_speed import checkout

    trees = {"old": checkout(a.against), "new": REPO}
    for tree in trees.values():
        compileall.compile_dir(str(tree / "gazepipe"), quiet=1)
    best: dict[str, dict] = {}
    for k in range(a.repeats):
        for side, tree in trees.items():
            run = run_cli(sessions, work / f"against_{side}", "serial", params=a.param, tree=tree)
            run["cpu_s"] = _cpu_total(run)
            run["stages"] = stage_times(work / f"against_{side}", "cpu_s")
            run["tail"] = after_takes(run, work / f"against_{side}") or {}
            run["tables"] = _tables(work / f"against_{side}")
            print(f"  repeat {k + 1} {side}: {run['cpu_s']:.1f} CPU s ({run['wall_s']:.1f} s wall, exit {run['rc']}); "
                  f"load average {os.getloadavg()[0]:.1f}", flush=True)
            if side not in best or run["cpu_s"] < best[side]["cpu_s"]:
                best[side] = {key: v for key, v in run.items() if key != "cpu"}
    old, new = best["old"], best["new"]
    floor = io_floor(sessions, work / "against_new")
    print(f"\nold = {a.against}, new = this tree; serial runs, CPU seconds, minimum of {a.repeats} interleaved")
    print(f"{'':<26}{'old':>9}{'new':>9}{'new/old':>9}")
    rows = [("whole run (process tree)", old["cpu_s"], new["cpu_s"])]
    rows += [(f"  {name}", old["stages"].get(name, 0.0), new["stages"].get(name, 0.0))
             for name in sorted(set(old["stages"]) | set(new["stages"]),
                                key=lambda n: -max(old["stages"].get(n, 0.0), new["stages"].get(n, 0.0)))]
    rows.append(("after the last take unit", old["tail"].get("cpu_after_s", float("nan")),
                 new["tail"].get("cpu_after_s", float("nan"))))
    alone = report_alone(trees, {side: work / f"against_{side}" for side in trees}, work, a.repeats)
    rows.append(("  the QC report alone", alone.get("old", float("nan")), alone.get("new", float("nan"))))
    for label, o, n in rows:
        print(f"{label:<26}{o:9.2f}{n:9.2f}{n / o if o else float('nan'):9.2f}")
    print(f"encode floor (wall): {floor['total_s']:.2f} s; new run {new['cpu_s'] / floor['total_s']:.1f}x it")
    same = old["tables"] == new["tables"]
    differ = sorted(p for p in set(old["tables"]) | set(new["tables"]) if old["tables"].get(p) != new["tables"].get(p))
    print(f"same bytes: {same} ({len(new['tables'])} tables" + (f"; {len(differ)} differ, e.g. {differ[:3]})" if differ else ")"))
    return 0


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("corpus", help="A folder of session folders (bench/make_corpus.py output).")
    p.add_argument("--work", default=str(REPO / "bench" / "_work" / "scale"))
    p.add_argument("--executors", default="serial,process,dask",
                   help="Comma-separated: which end-to-end runs to time (serial is always run).")
    p.add_argument("--jobs", type=int, default=2)
    p.add_argument("--scaling", default="",
                   help="Comma-separated worker counts (e.g. 1,2,4,8,16) for a process-executor sweep: the speed-up "
                        "over serial at each, as far as the machine's cores go.")
    p.add_argument("--profile", action="store_true", help="Also profile a serial run with cProfile.")
    p.add_argument("--param", action="append", default=[], metavar="STAGE.NAME=VALUE",
                   help="Passed to every run as gazepipe's --param (repeatable), e.g. to see what a cheaper gap "
                        "filler buys: --param 'clean.fill_methods=[\"linear\"]'.")
    p.add_argument("--against", metavar="REV",
                   help="Time serial runs of this commit and of this tree interleaved (CPU per stage, old vs new).")
    p.add_argument("--repeats", type=int, default=3, help="With --against: runs of each version (minimum kept).")
    a = p.parse_args(argv)

    corpus = Path(a.corpus)
    sessions = sorted(d for d in corpus.iterdir() if (d / "session.toml").is_file())
    if not sessions:
        p.error(f"no session folders in {corpus}")
    work = Path(a.work)
    work.mkdir(parents=True, exist_ok=True)
    size_mb = sum(f.stat().st_size for s in sessions for f in s.rglob("*") if f.is_file() and "truth" not in f.parts)
    print(f"corpus {corpus}: {len(sessions)} sessions, {size_mb / 2**20:.0f} MB of inputs; "
          f"{os.cpu_count()} cores, load average {os.getloadavg()[0]:.1f}"
          + "".join(f"; --param {kv}" for kv in a.param), flush=True)

    if a.against:
        return against(a, sessions, work)
    # the package's bytecode, as a pip install compiles it: with PYTHONDONTWRITEBYTECODE set (as on some CI and
    # container images) an editable checkout would otherwise recompile every module in every run (~0.15 s,
    # a fifth of the no-op re-run)
    import compileall

    compileall.compile_dir(str(REPO / "gazepipe"), quiet=1)
    results: dict[str, dict] = {}
    results["serial"] = run_cli(sessions, work / "serial", "serial", params=a.param)
    print(f"serial run: {results['serial']['wall_s']:.1f} s", flush=True)
    # a no-op lasts under a second: the median of five, with their range (one run is at the mercy of the machine)
    noops = sorted((run_cli(sessions, work / "serial", "serial", fresh=False, params=a.param) for _ in range(5)),
                   key=lambda r: r["wall_s"])
    results["noop"] = noops[2]
    print(f"no-op re-run: {noops[2]['wall_s']:.2f} s (median of 5; {noops[0]['wall_s']:.2f}-{noops[-1]['wall_s']:.2f} s)",
          flush=True)
    floor = io_floor(sessions, work / "serial")
    print(f"I/O floor: {floor['total_s']:.1f} s", flush=True)
    phys = physical_floor(sessions, work / "serial")
    print(f"physical floor: {phys['total_s']:.1f} s", flush=True)
    for ex in [e for e in a.executors.split(",") if e and e != "serial"]:
        results[ex] = run_cli(sessions, work / ex, ex, jobs=a.jobs, params=a.param)
        print(f"{ex} run (-j {a.jobs}): {results[ex]['wall_s']:.1f} s", flush=True)
    sweep: dict[int, dict] = {}
    for j in [int(x) for x in a.scaling.split(",") if x.strip()]:
        if j > (os.cpu_count() or 1):
            print(f"-j {j}: skipped, the machine has {os.cpu_count()} cores", flush=True)
            continue
        sweep[j] = run_cli(sessions, work / f"process_j{j}", "process", jobs=j, params=a.param)
        print(f"process run (-j {j}): {sweep[j]['wall_s']:.1f} s", flush=True)
    prof_rows: list[str] = []
    if a.profile:
        prof = work / "serial.prof"
        results["profiled"] = run_cli(sessions, work / "profiled", "serial", profile=prof, params=a.param)
        prof_rows = top_profile(prof)

    serial = results["serial"]["wall_s"]
    print()
    print(f"I/O floor: {floor['total_s']:.2f} s = read {floor['c3d_files']} C3D ({floor['mocap_frames']} frames) "
          f"{floor['read_c3d_s']:.2f} s + read {floor['csv_files']} CSV {floor['read_csv_s']:.2f} s + write "
          f"{floor['parquet_files']} Parquet ({floor['parquet_mb']:.0f} MB) {floor['write_parquet_s']:.2f} s")
    print(f"physical floor: {phys['total_s']:.2f} s = numpy decode of {floor['c3d_files']} C3D "
          f"{phys['read_c3d_s']:.2f} s + read {floor['csv_files']} CSV {phys['read_csv_s']:.2f} s + raw write of "
          f"the {phys['output_bytes'] / 2**20:.0f} MB of output Parquet with fsync {phys['write_raw_s']:.2f} s")
    print(f"output bytes per mocap frame: {phys['output_bytes'] / max(floor['mocap_frames'], 1):.0f} "
          f"({phys['output_bytes']} bytes of Parquet over {floor['mocap_frames']} frames)")
    runs = {**results, **{f"process -j {j}": r for j, r in sweep.items()}}
    print(f"{'run':<24}{'wall s':>9}{'x phys':>8}{'x encode':>9}{'speed-up':>10}{'after takes':>12}"
          f"{'peak tree MB':>14}{'peak proc MB':>14}  exit{'tail s':>8}{'CPU s':>8}{'CPU after':>10}")
    for name, r in runs.items():
        label = {"serial": "end-to-end serial", "noop": "no-op re-run", "profiled": "serial under cProfile"
                 }.get(name, f"end-to-end {name}" if name.startswith("process -j") else f"end-to-end {name} -j {a.jobs}")
        speed = f"{serial / r['wall_s']:.2f}x" if name not in ("noop", "profiled") else ""
        tl = timeline(Path(r["log"])) if name not in ("noop", "profiled") else None
        if tl:
            r["timeline"] = tl
        at = after_takes(r, Path(r["out"])) if name not in ("noop", "profiled") else None
        if at:
            r["after_takes"] = at
        # the share from the unit records' times: the log's times count from its first event, which comes
        # after the interpreter's start, the planning and the session units, so they cannot be set against the
        # wall time
        tail = f"{100 * at['tail_s'] / r['wall_s']:10.1f} %" if at else ""
        cpu = (f"{at['tail_s']:8.2f}{at['cpu_s']:8.1f}{at['cpu_after_s']:6.1f} s ({100 * at['cpu_after_s'] / at['cpu_s']:.0f} %)"
               if at else "")
        print(f"{label:<24}{r['wall_s']:9.2f}{r['wall_s'] / phys['total_s']:8.2f}{r['wall_s'] / floor['total_s']:9.2f}"
              f"{speed:>10}{tail:>12}{r['peak_tree_mb']:14.0f}{r['peak_process_mb']:14.0f}  {r['rc']}   {cpu}")
    print("\n'after takes' above is the share of the wall time after the last take unit ('tail s': seconds from "
          "the last unit record's time to the run's end), 'CPU after' the CPU seconds of the run's processes after "
          "it (of 'CPU s'); timeline from the run log's first event (s, 1 s resolution): last take unit, last "
          "dataset, QC report")
    for name, r in runs.items():
        tl = r.get("timeline")
        if tl:
            print(f"  {name:<20}{tl['takes_done_s']:7.0f}{tl['datasets_done_s']:7.0f}{tl['report_done_s']:7.0f}")
    st = stage_times(work / "serial")
    total = sum(st.values())
    print(f"\nper stage (serial run; unit records, {total:.1f} s in all):")
    for name, secs in sorted(st.items(), key=lambda kv: -kv[1]):
        print(f"  {name:<22}{secs:9.2f} s {100 * secs / total:6.1f} %")
    if prof_rows:
        print("\nprofile of the serial run, top functions by own time:")
        print("\n".join("  " + r for r in prof_rows))
    for r in runs.values():
        r.pop("cpu", None)
    summary = {"corpus": str(corpus), "floor": floor, "physical_floor": phys, "runs": runs, "stages": st}
    (work / "results.json").write_text(json.dumps(summary, indent=1))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
