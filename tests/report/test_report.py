"""`gazepipe validate`: checks and severities, report.json against its schema, takes.parquet, the HTML page
(self-contained, rendered by headless Chromium), the QC gate's exit codes, byte-identical reruns."""

from __future__ import annotations

import dataclasses
import json
import os
import shutil
import subprocess
from pathlib import Path

import numpy as np
import pandas as pd
import pyarrow.parquet as pq
import pytest
from click.testing import CliRunner

from gazepipe.cli.validate import validate
from gazepipe.io.session_toml import load_session
from gazepipe.report import checks as C
from gazepipe.report import checks_datasets as D
from gazepipe.report.schema import REPORT_JSON_SCHEMA, REPORT_SCHEMA_VERSION, validate_report
from gazepipe.stages.clean.qc import CleanQC
from gazepipe.stages.eyes.qc import EyesQC
from gazepipe.stages.face.qc import FaceQC
from gazepipe.stages.sync.qc import SyncQC
from tests.helpers import run_session, session_copy

CHROMIUM = Path("/usr/bin/chromium")

# a slice of the sample session: the neutral take, one gaze_follow take, three gaze_shift takes (one pinned to
# train and one to val so that the gaze_map dataset built below has both splits whatever the hash says)
TAKES = {"neutral": None, "follow_sitting_01": "train", "shift_y036_p12": "train", "shift_ym036_p00": "val",
         "shift_y072_p00": None}


@pytest.fixture(scope="module")
def clean_out(tmp_path_factory) -> Path:
    """The whole pipeline's output for the sample slice (take stages and datasets)."""
    root = tmp_path_factory.mktemp("report_clean")
    out = root / "out"
    run_session(session_copy(root / "session", TAKES), out)
    return out


@pytest.fixture(scope="module")
def broken_out(tmp_path_factory) -> Path:
    """Two good takes and one whose C3D file is cut in half."""
    root = tmp_path_factory.mktemp("report_broken")
    session = session_copy(root / "session", {"neutral": None, "shift_y036_p12": None, "shift_ym036_p00": "train"})
    c3d = session / "mocap" / "shift_y036_p12.c3d"
    data = c3d.read_bytes()
    c3d.write_bytes(data[: len(data) // 2])
    out = root / "out"
    run_session(session, out)
    return out


def _validate(out: Path, *args: str):
    return CliRunner().invoke(validate, [str(out), *args])


def _report(out: Path) -> dict:
    return json.loads((out / "qc" / "report.json").read_text())


# ----------------------------------------------------------------------------------------------- the gate

def test_clean_sample_passes_fail_gate_and_report_is_valid(clean_out: Path) -> None:
    res = _validate(clean_out, "--fail-on", "fail")
    assert res.exit_code == 0, res.output
    rep = _report(clean_out)
    assert validate_report(rep) == []
    assert rep["schema_version"] == REPORT_SCHEMA_VERSION
    assert rep["gate"] == {"fail_on": "fail", "passed": True, "hit": []}
    assert sorted(t["take"] for t in rep["takes"]) == sorted(TAKES)
    for t in rep["takes"]:
        assert t["stages"], t["take"]
        assert all(v == "ok" for v in t["stages"].values())
        assert t["severity"] in ("pass", "warning")
        sevs = [C.RANK[c["severity"]] for c in t["checks"]]
        assert sevs == sorted(sevs, reverse=True), "checks must be listed worst first"
    # the follow take has a video and eye tracking: its sync and eyes records are checked; the shift takes
    # have neither: those checks are not applicable there (skipped), not passed
    follow = {c["id"]: c for c in next(t for t in rep["takes"] if t["take"] == "follow_sitting_01")["checks"]}
    shift = {c["id"]: c for c in next(t for t in rep["takes"] if t["take"] == "shift_y036_p12")["checks"]}
    for cid in ("clap_offset", "clap_confidence", "clock_drift", "frames_without_video", "eye_gated",
                "eye_longest_invalid", "camera_residual"):
        assert follow[cid]["severity"] in ("pass", "warning"), follow[cid]
    for cid in ("clap_offset", "clap_confidence", "clock_drift", "frames_without_video"):
        assert shift[cid]["severity"] == "skipped" and "no video" in shift[cid]["message"]
    assert "eye_gated" not in shift
    sync = json.loads((clean_out / ".gazepipe" / "units" / "session01" / "follow_sitting_01" / "sync.json")
                      .read_text())["qc"]
    lowest = min(min(c["mocap_confidence"], c["video_confidence"]) for c in sync["claps"])
    assert follow["clap_confidence"]["value"] == lowest
    assert {d["name"] for d in rep["datasets"]} == {"gaze_rnn", "gaze_rnn_lod", "gaze_map"}
    assert rep["thresholds"]["unfilled_warn"] == C.Thresholds().unfilled_warn


def test_validation_report_is_not_a_schema_rubber_stamp() -> None:
    rep = {"schema": "gazepipe.qc_report", "schema_version": REPORT_SCHEMA_VERSION}
    problems = validate_report(rep)
    assert any("missing 'takes'" in p for p in problems)
    check = C.Check("x", "pass", "fine").to_dict()
    take = {"session": "s", "take": "t", "kind": "gaze_shift", "pose": "standing", "severity": "pass",
            "stages": {}, "checks": [check]}
    takes_schema = REPORT_JSON_SCHEMA["properties"]["takes"]
    assert validate_report([take], takes_schema) == []
    assert any("'awful' is not one of" in p for p in validate_report(
        [{**take, "checks": [{**check, "severity": "awful"}]}], takes_schema))
    assert any("unexpected 'extra'" in p for p in validate_report([{**take, "extra": 1}], takes_schema))


def test_thresholds_drive_the_gate(clean_out: Path) -> None:
    # any gap at all is a warning with a zero threshold: --fail-on warning now fails, --fail-on fail does not
    gaps0 = ("--no-plots", "--threshold", "gap_share_warn=0")
    strict = _validate(clean_out, *gaps0, "--fail-on", "warning")
    assert strict.exit_code == 3
    # the warnings that fail the gate are named, one per line (up to 25, then counted)
    named = [ln for ln in strict.output.splitlines() if ln.startswith("  warning ") and ": gap_share: " in ln]
    n_takes = len(_report(clean_out)["takes"])
    assert len(named) == min(n_takes, 25)
    lenient = _validate(clean_out, *gaps0, "--fail-on", "fail")
    assert lenient.exit_code == 0 and not any(ln.startswith("  warning ") for ln in lenient.output.splitlines())
    rep = _report(clean_out)
    assert rep["thresholds"]["gap_share_warn"] == 0
    assert all(any(c["id"] == "gap_share" and c["severity"] == "warning" for c in t["checks"])
               for t in rep["takes"])
    # a fail threshold below a take's camera residual makes that take fail
    res = _validate(clean_out, "--no-plots", "--threshold", "camera_residual_warn_deg=0",
                    "--threshold", "camera_residual_fail_deg=0.0")
    assert res.exit_code == 3
    assert "camera_residual" in res.output
    bad = _validate(clean_out, "--no-plots", "--threshold", "no_such=1")
    assert bad.exit_code == 2 and "no_such" in bad.output


def test_broken_take_fails_the_gate_and_is_named(broken_out: Path) -> None:
    res = _validate(broken_out, "--fail-on", "fail")
    assert res.exit_code == 3, res.output
    assert "shift_y036_p12" in res.output
    rep = _report(broken_out)
    assert validate_report(rep) == []
    assert not rep["gate"]["passed"]
    hit = {(h["target"], h["id"]) for h in rep["gate"]["hit"]}
    assert ("session01/shift_y036_p12", "stages") in hit
    assert all(h["target"] == "session01/shift_y036_p12" for h in rep["gate"]["hit"])
    broken = next(t for t in rep["takes"] if t["take"] == "shift_y036_p12")
    assert broken["severity"] == "fail" and broken["stages"]["ingest"] == "failed"
    assert rep["summary"]["failing"][0]["target"] == "session01/shift_y036_p12"
    html = (broken_out / "qc" / "report.html").read_text()
    summary = html[html.index('id="summary"'):]
    assert summary.index("shift_y036_p12") < summary.index("shift_ym036_p00"), "failing takes first"
    # the failed take ranks first for the plots too, but its ingest failed: it has no table to draw from, so the
    # plots go to the takes that have, and the page says why it has none
    from gazepipe.report.validate import rank_takes

    assert rank_takes(rep["takes"])[0] == "session01/shift_y036_p12"
    row = summary[summary.index("shift_y036_p12"):]
    assert row[:row.index("</tr>")].endswith("<td>nothing to draw</td>")
    assert "No plots: nothing to draw for this take" in _section(html, "take-session01-shift_y036_p12")
    assert "<svg" in _section(html, "take-session01-shift_ym036_p00")


def test_unreadable_table_is_an_error_that_fails_the_gate(broken_out: Path, tmp_path: Path) -> None:
    out = tmp_path / "out"
    shutil.copytree(broken_out, out)
    table = out / "takes" / "session01" / "shift_ym036_p00" / "markers.parquet"
    table.write_bytes(table.read_bytes()[:200])
    res = _validate(out, "--no-plots")
    assert res.exit_code == 3
    take = next(t for t in _report(out)["takes"] if t["take"] == "shift_ym036_p00")
    checks = {c["id"]: c for c in take["checks"]}
    assert checks["table_markers"]["severity"] == "error" and str(table) in checks["table_markers"]["message"]
    assert checks["unfilled"]["severity"] == "error"
    assert take["severity"] == "error" and take["checks"][0]["severity"] == "error"
    # a table the checks do not decode (only its footer and schema are read) is reported just the same
    raw = out / "takes" / "session01" / "neutral" / "markers_raw.parquet"
    raw.write_bytes(raw.read_bytes()[:-100])
    assert _validate(out, "--no-plots").exit_code == 3
    take = next(t for t in _report(out)["takes"] if t["take"] == "neutral")
    checks = {c["id"]: c for c in take["checks"]}
    assert checks["table_markers_raw"]["severity"] == "error" and str(raw) in checks["table_markers_raw"]["message"]


def test_outputs_older_than_their_inputs_are_flagged(tmp_path: Path) -> None:
    session = session_copy(tmp_path / "session", {"neutral": None, "shift_y036_p12": "train"})
    out = tmp_path / "out"
    run_session(session, out)
    assert _validate(out, "--no-plots").exit_code == 0
    stages = {t["take"]: next(c for c in t["checks"] if c["id"] == "stages") for t in _report(out)["takes"]}
    assert all(c["severity"] == "pass" and "up to date" in c["message"] for c in stages.values())
    with (session / "markerset.toml").open("a") as f:   # every unit's fingerprint covers the markerset
        f.write("\n# edited after the run\n")
    assert _validate(out, "--no-plots", "--fail-on", "warning").exit_code == 3
    assert {h["target"] for h in _report(out)["gate"]["hit"] if h["id"] == "stages"} == \
        {"session01/neutral", "session01/shift_y036_p12"}
    stages = {t["take"]: next(c for c in t["checks"] if c["id"] == "stages") for t in _report(out)["takes"]}
    for take, c in stages.items():
        assert c["severity"] == "warning", take
        assert all(v.startswith("stale") for v in c["details"]["not_up_to_date"].values())
        assert "ingest" in c["details"]["not_up_to_date"]


def test_not_an_output_folder_is_a_usage_error(tmp_path: Path) -> None:
    res = CliRunner().invoke(validate, [str(tmp_path)])
    assert res.exit_code == 2
    assert "not a gazepipe output folder" in res.output and str(tmp_path) in res.output


# ------------------------------------------------------------------------------------------ the files

def test_takes_parquet_matches_the_tables(clean_out: Path) -> None:
    assert _validate(clean_out, "--no-plots").exit_code == 0
    takes = pd.read_parquet(clean_out / "qc" / "takes.parquet")
    assert sorted(takes["take"]) == sorted(TAKES)
    for take in ("follow_sitting_01", "shift_y036_p12"):
        row = takes.set_index("take").loc[take]
        # unfilled share of kept frames, worst marker, recomputed here from the cleaned markers table
        m = pd.read_parquet(clean_out / "takes" / "session01" / take / "markers.parquet")
        share = (m["fill"].astype(str) == "unfilled").groupby(m["marker"].astype(str), observed=True).mean()
        assert row["unfilled_share_max"] == pytest.approx(share.max(), abs=1e-12)
        filled = (~m["fill"].astype(str).isin(["measured", "unfilled"])).mean()
        assert row["filled_share"] == pytest.approx(filled, abs=1e-12)
        clean = json.loads((clean_out / ".gazepipe" / "units" / "session01" / take / "clean.json").read_text())
        assert [row["crop_start"], row["crop_stop"]] == clean["qc"]["crop"]
        assert row["kept_frames"] == m["frame"].nunique()
    assert (takes["n_fail"] == 0).all()


def test_report_is_byte_identical_on_a_second_run(clean_out: Path) -> None:
    assert _validate(clean_out).exit_code == 0
    first = {n: (clean_out / "qc" / n).read_bytes() for n in ("report.json", "takes.parquet", "report.html")}
    assert _validate(clean_out).exit_code == 0
    for n, data in first.items():
        assert (clean_out / "qc" / n).read_bytes() == data, n
    # without plots only the page changes, and it loses none: nothing is drawn, the plots drawn before stay
    assert _validate(clean_out, "--no-plots").exit_code == 0
    for n in ("report.json", "takes.parquet"):
        assert (clean_out / "qc" / n).read_bytes() == first[n], n
    page = (clean_out / "qc" / "report.html").read_text()
    assert page != first["report.html"].decode() and "none drawn (--no-plots)" in page
    assert page.count("<svg") == first["report.html"].decode().count("<svg") > 0


def test_run_report_starts_with_the_takes_and_equals_validate(tmp_path: Path) -> None:
    """A run starts the report's take checks once its takes and dataset builds are done (the builds are not held
    up by the report's work in the run's process), finishes it after the datasets, and writes what `gazepipe
    validate` writes; a run with nothing to do keeps it."""
    import io

    from gazepipe.cli.main import REPORT_PLOT_TAKES, _RunReport
    from gazepipe.dag import run_pipeline
    from gazepipe.pipeline.events import EventLog
    from gazepipe.report.validate import validate_output

    session = session_copy(tmp_path / "session", {"neutral": None, "shift_y036_p12": "train",
                                                    "shift_ym036_p00": "val"})
    out = tmp_path / "out"
    calls: list[tuple[str, bool]] = []

    class Spy(_RunReport):
        def takes_done(self) -> None:
            calls.append(("takes_done", (out / "datasets").is_dir() and any((out / "datasets").iterdir())))
            super().takes_done()

        def finish(self) -> None:
            calls.append(("finish", (out / "datasets" / "gaze_map" / "_dataset.json").is_file()))
            super().finish()

    def run() -> None:
        log = EventLog("json", stream=io.StringIO())
        run_pipeline([load_session(session)], out, executor="serial", log=log, report=Spy(out, log))

    run()
    assert calls == [("takes_done", True), ("finish", True)]
    written = {n: (out / "qc" / n).read_bytes() for n in ("report.json", "takes.parquet", "report.html")}
    validate_output(out, plot_takes=REPORT_PLOT_TAKES)
    for n, data in written.items():
        assert (out / "qc" / n).read_bytes() == data, n
    calls.clear()
    stamp = (out / "qc" / "report.html").stat().st_mtime_ns
    run()
    assert calls == [("finish", True)]
    assert (out / "qc" / "report.html").stat().st_mtime_ns == stamp


def _section(html: str, anchor: str) -> str:
    start = html.index(f'id="{anchor}"')
    nxt = html.find("<h2 id=", start + 1)
    return html[start: nxt if nxt > 0 else len(html)]


def test_html_is_self_contained(clean_out: Path) -> None:
    assert _validate(clean_out).exit_code == 0
    html = (clean_out / "qc" / "report.html").read_text()
    assert "http" not in html and "<script" not in html and "<link" not in html
    assert html.count('id="summary"') == 1
    assert html.count("<svg") == html.count('<figure class="plot">') == html.count("</svg>")
    # every take with markers has a gap timeline and a speed trace; the take with a video and eye tracking also
    # the clap alignment and the eye confidence
    for take in TAKES:
        sec = _section(html, f"take-session01-{take}")
        titles = [t for t in ("Gap timeline", "Speed and crop", "Clap alignment", "Eye confidence") if t in sec]
        want = 4 if take == "follow_sitting_01" else 2
        assert len(titles) == want and sec.count("<svg") == want, (take, titles)
    # feature distributions of every dataset
    assert _section(html, "dataset-gaze_rnn").count("<svg") == 2          # x and y
    assert _section(html, "dataset-gaze_map").count("<svg") == 3          # scalars, p_plus, start_times
    # with a cap, only the worst take keeps its plots; the page names it and says how to plot the others (the
    # default cap, 6, plots all five takes of this slice: tests/report/test_validate_speed.py covers a capped default)
    assert _validate(clean_out, "--plot-takes", "1").exit_code == 0
    html = (clean_out / "qc" / "report.html").read_text()
    plotted = [t for t in TAKES if "<svg" in _section(html, f"take-session01-{t}")]
    sev = {t["take"]: C.RANK[t["severity"]] for t in _report(clean_out)["takes"]}
    assert len(plotted) == 1 and sev[plotted[0]] == max(sev.values())
    assert "drawn for 1 of 5 takes (the 1 worst with something to draw)" in html
    assert f'href="#take-session01-{plotted[0]}"' in html[html.index('<div id="plots">'):]
    assert "--plot-takes all" in html


def _chromium(args: list[str], tmp: Path) -> subprocess.CompletedProcess:
    base = [str(CHROMIUM), "--headless", "--no-sandbox", "--disable-gpu", "--disable-background-networking",
            "--disable-component-update", "--disable-sync", "--no-first-run", f"--user-data-dir={tmp / 'profile'}"]
    return subprocess.run(base + args, capture_output=True, text=True, timeout=120,
                          env={**os.environ, "HOME": str(tmp)})


@pytest.mark.skipif(not CHROMIUM.exists(), reason="Chromium not installed here (/usr/bin/chromium; "
                    "apt-get install chromium): CI installs it")
def test_chromium_renders_summary_and_plots(clean_out: Path, tmp_path: Path) -> None:
    assert _validate(clean_out).exit_code == 0
    url = (clean_out / "qc" / "report.html").resolve().as_uri()
    dom = _chromium(["--dump-dom", url], tmp_path)
    assert dom.returncode == 0, dom.stderr[-2000:]
    html = dom.stdout
    assert 'id="summary"' in html and 'id="gate"' in html
    summary = html[html.index('id="summary"'):html.index("</table>", html.index('id="summary"'))]
    assert summary.count("<tr>") == 1 + len(TAKES) + 3                    # header, takes, datasets
    n_figs = (clean_out / "qc" / "report.html").read_text().count('<figure class="plot">')
    assert n_figs >= 2 * len(TAKES) + 2 + 7
    assert html.count("<svg") == n_figs
    shot = tmp_path / "shot.png"
    res = _chromium([f"--screenshot={shot}", "--window-size=1200,2400", url], tmp_path)
    assert res.returncode == 0 and shot.exists(), res.stderr[-2000:]
    from PIL import Image

    img = np.asarray(Image.open(shot).convert("L"), dtype=np.float64)
    assert img.shape == (2400, 1200)
    assert img.std() > 20, "the page rendered blank"


# ------------------------------------------------------------------------------------------------ datasets

@pytest.fixture(scope="module")
def dataset_out(clean_out: Path, tmp_path_factory) -> Path:
    """A copy of the sample output (it holds the datasets the engine built) to validate with other options."""
    out = tmp_path_factory.mktemp("report_ds") / "out"
    shutil.copytree(clean_out, out)
    assert (out / "datasets" / "gaze_map" / "_dataset.json").exists()
    return out


def _ds_checks(out: Path, *args: str, name: str = "gaze_map") -> dict[str, dict]:
    _validate(out, "--no-plots", *args)
    rep = _report(out)
    assert validate_report(rep) == []
    (ds,) = [d for d in rep["datasets"] if d["name"] == name]
    return {c["id"]: c for c in ds["checks"]}


def test_dataset_checks_pass_on_a_built_dataset(dataset_out: Path) -> None:
    for rows in ("20000", "1"):   # all training rows, and a one-row sample
        checks = _ds_checks(dataset_out, "--threshold", f"stats_sample_rows={rows}")
        for cid in ("build", "dataset_read", "schema_hash", "split_disjoint", "counts", "stats_sanity"):
            assert checks[cid]["severity"] in ("pass", "warning"), (cid, checks[cid])
        assert checks["stats_sanity"]["severity"] != "fail"
    assert checks["stats_sanity"]["details"]["sample_rows"] == 1
    assert checks["split_disjoint"]["details"]["takes_per_split"]["train"] >= 1


def _corrupt_copy(src: Path, dest: Path) -> Path:
    shutil.copytree(src, dest)
    return dest / "datasets" / "gaze_map"


def test_dataset_checks_catch_bad_statistics_split_and_schema(dataset_out: Path, tmp_path: Path) -> None:
    import pyarrow as pa

    ds = _corrupt_copy(dataset_out, tmp_path / "a")
    info = json.loads((ds / "_dataset.json").read_text())
    std = info["stats"]["overall"]["yaw_deg"]["std"][0]
    info["stats"]["overall"]["yaw_deg"]["mean"][0] += 10 * std + 1.0
    (ds / "_dataset.json").write_text(json.dumps(info))
    checks = _ds_checks(ds.parents[1], "--fail-on", "fail")
    assert checks["stats_sanity"]["severity"] == "fail"
    assert "yaw_deg" in checks["stats_sanity"]["message"]

    ds = _corrupt_copy(dataset_out, tmp_path / "b")
    rel = sorted(p.relative_to(ds) for p in ds.glob("*/*/*.parquet"))[0]
    t = pq.read_table(ds / rel)
    split = t.column("split").to_pylist()
    other = "test" if split[0] != "test" else "val"
    t = t.set_column(t.schema.get_field_index("split"), t.schema.field("split"),
                     pa.array([split[0]] + [other] * (len(split) - 1), pa.string()))
    pq.write_table(t, ds / rel)
    checks = _ds_checks(ds.parents[1])
    assert checks["split_disjoint"]["severity"] == "fail"
    assert checks["counts"]["severity"] == "fail"

    ds = _corrupt_copy(dataset_out, tmp_path / "c")
    t = pq.read_table(ds / rel)
    i = t.schema.get_field_index("yaw_deg")
    t = t.set_column(i, pa.field("yaw_deg", pa.float64(), nullable=False), t.column(i).cast(pa.float64()))
    pq.write_table(t, ds / rel)
    checks = _ds_checks(ds.parents[1])
    assert checks["schema_hash"]["severity"] == "fail"
    assert list(checks["schema_hash"]["details"]["mismatched"]) == [str(rel)]


# ----------------------------------------------------------------------------------------- pure checks

def test_unfilled_share_and_grading() -> None:
    th = C.Thresholds()
    fill = np.zeros((100, 3), np.int8)
    fill[:4, 0] = C.UNFILLED            # 4 %: below the warning
    fill[:10, 1] = C.UNFILLED           # 10 %: a warning
    fill[50:52, 2] = 1                  # linear-filled samples
    c = C.check_unfilled(fill, ["a", "b", "c"], th)
    assert c.severity == "warning" and c.value == pytest.approx(0.10)
    assert c.details["per_marker"]["a"] == pytest.approx(0.04)
    assert c.details["filled_share"] == pytest.approx(2 / 300)
    fill[:40, 2] = C.UNFILLED           # 40 %: a failure
    assert C.check_unfilled(fill, ["a", "b", "c"], th).severity == "fail"
    assert C.grade(0.3, 0.3, None) == "pass" and C.grade(0.31, 0.3, 0.6) == "warning"
    assert C.grade(0.4, 0.5, None, below=True) == "warning"


def _clap(mocap_s: float, mocap_confidence: float, video_s: float, video_confidence: float) -> dict:
    return {"mocap_s": mocap_s, "mocap_confidence": mocap_confidence, "mocap_timing_ms": 1.0, "video_s": video_s,
            "video_confidence": video_confidence, "video_match": 0.9, "video_timing_ms": 1.0,
            "video_timed_by": "displacement", "mocap_gap_frames": 0, "used": True, "set_aside": False}


def test_sync_and_eye_checks_read_their_stage_records() -> None:
    th = C.Thresholds()
    sync = SyncQC.from_record({
        "offset_s": 1.25, "offset_at_video_zero_s": 1.25, "ratio": 1.0025, "drift_ppm": 2500.0,
        "drift_ms_over_take": 90.0, "n_claps": 2, "residual_ms": 0.0,
        "claps": [_clap(2.0, 0.9, 0.75, 0.3), _clap(60.0, 0.8, 58.66, 0.9)],
        "frames_without_video": 300, "frames_decoded": 120, "video_frames": 3600, "video_span_s": [0.0, 60.0],
        "clock_bound_ms": 1.0, "clock_ref_s": 30.0, "clock_cov": [2.5e-7, 0.0, 4e-10], "clock_prior_ppm": 600.0,
        "clock_bound_sigmas": 2.0, "claps_used": [1, 2], "warnings": []})
    got = {c.id: c for c in C.sync_checks(sync, True, 1800, 30.0, th)}
    assert got["clap_offset"].value == 1.25
    assert got["clap_confidence"].severity == "warning" and got["clap_confidence"].value == 0.3
    assert got["clock_drift"].severity == "warning"          # 2500 ppm > 2000 ppm
    assert got["clap_residual"].severity == "skipped"        # two claps fit exactly
    assert got["frames_without_video"].severity == "warning" and got["frames_without_video"].value == \
        pytest.approx(300 / 1800)
    assert all(c.severity == "skipped" for c in C.sync_checks(None, False, 1800, 30.0, th))
    no_clap = dataclasses.replace(sync, claps=())
    assert {c.id: c for c in C.sync_checks(no_clap, True, 1800, 30.0, th)}["clap_confidence"].severity == "error"

    eyes = EyesQC.from_record({
        "samples": 3600, "video_rate_hz": 60.0, "gated_share": 0.65, "gated_by": {"confidence": 0.5, "blink": 0.15},
        "filled_samples": 0, "invalid_share": 0.65, "longest_invalid_run_s": 0.4, "missing_video_frames": 0,
        "min_confidence": 0.8, "max_eye_gap_s": 0.1, "warnings": [], "frames": 1800, "valid_frames": 630,
        "valid_share": 0.35, "frames_without_coverage": 0, "frames_without_head": 0, "clock_offset_s": 0.0,
        "clock_ratio": 1.0, "camera_rotation": [1.0, 0.0, 0.0, 0.0], "camera_rotation_source": "estimated",
        "camera_residual_deg": 3.5, "camera_frames_used": 200, "eye_lag_s": 0.2, "camera_target_spread_deg": 40.0})
    got = {c.id: c for c in C.eyes_checks(eyes, True, th)}
    assert got["eye_gated"].severity == "fail"
    assert got["eye_longest_invalid"].severity == "pass"
    assert got["camera_residual"].severity == "warning"
    eyes = dataclasses.replace(eyes, camera_residual_deg=None)
    assert {c.id: c for c in C.eyes_checks(eyes, True, th)}["camera_residual"].severity == "skipped"


def test_stage_warnings_are_surfaced() -> None:
    recs = {"ingest": {"status": "ok", "warnings": []},
            "face": {"status": "ok", "warnings": ["tracked: head rotations are all zero", "clean: 8 dropped"]}}
    c = C.check_stage_warnings(recs)
    assert c.severity == "warning" and c.value == 2 and "head rotations are all zero" in c.message
    assert c.details["warnings"] == {"face": recs["face"]["warnings"]}
    recs["face"]["warnings"] = []
    assert C.check_stage_warnings(recs).severity == "pass"


def test_face_checks() -> None:
    th = C.Thresholds()
    qc = FaceQC.from_record({
        "rows_tracked": 1000, "rows_clean": 990, "dropped_frames_tracked": 80, "dropped_frames_clean": 2,
        "rows_matched": 970, "unmatched_tracked": 30, "unmatched_clean": 20, "last_frames_dropped": 1, "rows_out": 969,
        "k": 1, "max_match_error_s": 0.0, "dt_min_s": 0.016, "dt_median_s": 0.016, "dt_max_s": 0.05, "warnings": []})
    got = {c.id: c for c in C.face_checks(qc, th)}
    assert got["face_unmatched"].severity == "pass" and got["face_unmatched"].value == pytest.approx(0.03)
    assert got["face_dropped"].severity == "warning" and got["face_dropped"].value == pytest.approx(80 / 1080)
    qc = dataclasses.replace(qc, unmatched_tracked=600)
    assert {c.id: c for c in C.face_checks(qc, th)}["face_unmatched"].severity == "fail"
    assert [c.severity for c in C.face_checks(None, th)] == ["skipped", "skipped"]


def test_stats_recomputation_detects_a_biased_mean() -> None:
    rng = np.random.default_rng(3)
    n_total = 5000
    x = rng.normal(2.0, 3.0, (n_total, 4))
    info = {"features": {"f": ["a", "b", "c", "d"]},
            "stats": {"overall": {"rows": n_total, "f": {"mean": x.mean(0).tolist(), "std": x.std(0).tolist()}},
                      "per_pose": {}}}
    th = C.Thresholds()
    idx = np.sort(rng.choice(n_total, 500, replace=False))
    sample = D.StatsSample({"f": x[idx]}, np.array(["standing"] * 500), n_total, {"standing": n_total})
    assert D.check_stats(info, sample, th).severity == "pass"
    full = D.StatsSample({"f": x}, np.array(["standing"] * n_total), n_total, {"standing": n_total})
    assert D.check_stats(info, full, th).severity == "pass"
    info["stats"]["overall"]["f"]["mean"][2] += 1.5      # half a std: ~12 standard errors at n = 500
    assert D.check_stats(info, sample, th).severity == "fail"
    assert D.check_stats(info, full, th).severity == "fail"
    info["stats"]["overall"]["f"]["mean"][2] = float("nan")
    assert D.check_stats(info, None, th).severity == "fail"


def test_stats_recomputation_leaves_null_values_out() -> None:
    """With null (NaN) values the statistics are per element over the values that are not null, ``count`` each:
    the recomputation leaves them out the same way (full sample: exact; a sample: within standard errors),
    still catches a biased mean, and does not take NaN for agreement."""
    rng = np.random.default_rng(5)
    n_total = 4000
    x = rng.normal(1.0, 2.0, (n_total, 3))
    x[rng.random(n_total) < 0.3, 1] = np.nan              # element 1: 30 % null
    x[:, 2] = np.nan                                      # element 2: never known
    ok = ~np.isnan(x)
    cols = [x[ok[:, j], j] for j in range(3)]
    st = {"mean": [float(v.mean()) if v.size else 0.0 for v in cols],
          "std": [float(v.std()) if v.size else 0.0 for v in cols], "count": ok.sum(0).tolist()}
    info = {"features": {"f": ["a", "b", "c"]}, "stats": {"overall": {"rows": n_total, "f": st}, "per_pose": {}}}
    th = C.Thresholds()
    full = D.StatsSample({"f": x}, np.array(["standing"] * n_total), n_total, {"standing": n_total})
    idx = np.sort(rng.choice(n_total, 500, replace=False))
    part = D.StatsSample({"f": x[idx]}, np.array(["standing"] * 500), n_total, {"standing": n_total})
    for sample in (full, part):
        c = D.check_stats(info, sample, th)
        assert c.severity == "pass" and np.isfinite(c.value), c.message
        assert "null in every training row (mean 0, std 0): f[2]" in c.message and not c.details["constant"]
    info["stats"]["overall"]["f"]["mean"][1] += 1.0      # half a std: ~10 standard errors at n = 350
    for sample in (full, part):
        assert D.check_stats(info, sample, th).severity == "fail"
    info["stats"]["overall"]["f"]["mean"][1] -= 1.0
    info["stats"]["overall"]["f"]["count"][1] -= 10       # the full sample holds more values than counted
    assert D.check_stats(info, full, th).severity == "fail"


def test_null_parameters_are_counted_and_warned_not_failed() -> None:
    info = {"counts": {"null_segments": {"neck2": 2, "head": 1},
                       "per_take": {"s/a": {"null_segments": ["neck2", "head"],
                                            "null_reasons": {"neck2": "P+: no measured rotation in the crop's "
                                                                      "final rest (frames 60–90)"}},
                                    "s/b": {"null_segments": ["neck2"], "null_reasons": {"neck2": "x"}},
                                    "s/c": {"null_segments": []}}}}
    c = D.check_null_parameters(info)
    assert c.severity == "warning" and c.value == 2
    assert c.message.startswith("2 of 3 take(s) have null parameters (neck2 2, head 1)")
    assert "s/a: neck2, head (P+: no measured rotation in the crop's final rest" in c.message
    assert c.details["takes"] == {"s/a": ["neck2", "head"], "s/b": ["neck2"]}
    info["counts"]["null_segments"] = {}
    for t in info["counts"]["per_take"].values():
        t["null_segments"] = []
    assert D.check_null_parameters(info).severity == "pass"
    assert D.check_null_parameters({"counts": {"rows": 3}}).severity == "skipped"     # e.g. gaze_rnn


def test_windowed_rows_warns_when_most_rows_feed_no_training_window() -> None:
    from gazepipe.report import checks_datasets as D

    info = {"window": 120, "counts": {"rows": 5128, "segments": 47, "segments_with_a_window": 3,
                                      "rows_in_segments_with_a_window": 492}}
    c = D.check_windowed_rows(info, C.Thresholds())
    assert c.severity == "warning" and c.value == pytest.approx(492 / 5128)
    assert "3 of 47 segments (492 of 5128 rows, 10 %)" in c.message
    info["counts"]["rows_in_segments_with_a_window"] = 4000
    assert D.check_windowed_rows(info, C.Thresholds()).severity == "pass"
    assert D.check_windowed_rows(info, C.Thresholds(windowed_rows_warn=0.9)).severity == "warning"
    assert D.check_windowed_rows({"window": None, "counts": {"rows": 10}}, C.Thresholds()).severity == "skipped"


def test_crop_check_warns_when_a_gaze_shift_lacks_a_rest():
    """A gaze_shift take whose markers were hidden through a rest is kept whole by clean (no failed take); the
    crop check says why it gives no gaze_map row."""
    from gazepipe.report.checks import Thresholds, check_crop

    def clean(crop: list[int], rests: list[list[int]]) -> CleanQC:
        return CleanQC.from_record({"warnings": [], "failures": [], "swaps": [], "swap_pairs": {},
                                    "spikes_removed": 0, "gaps": [], "markers": {}, "root_missing_frames": 0,
                                    "rests": rests, "crop": crop, "kept_frames": crop[1] - crop[0]})

    got = check_crop(clean([0, 118], [[89, 118]]), "gaze_shift", 118, 29.97, Thresholds())
    assert got.severity == "warning" and "gaze shift needs two" in got.message
    ok = check_crop(clean([42, 118], [[0, 42], [63, 118]]), "gaze_shift", 118, 29.97, Thresholds())
    assert ok.severity == "pass"
