"""What a first run shows: the report's order (contents, summary worst first by the plots' rank, takes before
datasets), its plots' labels (crop region, element names, units), and a log without repeated session facts but
with the dataset card's split warnings."""

from __future__ import annotations

import json
import re
from pathlib import Path

import pytest
from click.testing import CliRunner

from gazepipe.cli.main import cli
from gazepipe.report.validate import rank_takes, validate_output

SHIFTS = ((36.0, 12.0), (-72.0, 0.0), (0.0, -12.0))


@pytest.fixture(scope="module")
def small_run(tmp_path_factory) -> tuple[Path, list[dict]]:
    """Three gaze_shift takes and a neutral take, with a markerset that names no head_centre marker and no
    eye offset; run, then validated with every take plotted."""
    from gazepipe.synth.session import SynthConfig, generate_session

    root = tmp_path_factory.mktemp("first_day")
    cfg = SynthConfig(follow_poses=(), shift_targets=SHIFTS, face_takes=(), head_camera=False, gaps_per_marker_min=3.0)
    session = generate_session(root / "session", 0, cfg)
    ms = session / "markerset.toml"
    ms.write_text("".join(line for line in ms.read_text().splitlines(keepends=True)
                          if not line.startswith(("head_centre", "eye_offset_mm"))))
    out = root / "out"
    res = CliRunner().invoke(cli, ["run", str(session), "--out", str(out), "--executor", "serial",
                                   "--log-format", "json"])
    assert res.exit_code == 0, res.output[-3000:]
    validate_output(out, plot_takes="all")
    return out, [json.loads(line) for line in res.output.splitlines() if line.startswith("{")]


def test_session_fact_is_one_warning_line(small_run):
    out, events = small_run
    lines = [e for e in events if "no head_centre marker" in e.get("message", "")]
    assert len(lines) == 1, [e["message"] for e in lines]
    assert lines[0]["level"] == "warning" and "session01" in lines[0]["message"]
    assert "markerset.toml" in lines[0]["message"]
    report = json.loads((out / "qc" / "report.json").read_text())
    for t in report["takes"]:
        for c in t["checks"]:
            assert "head_centre" not in c["message"], (t["take"], c)


def test_split_warnings_are_in_the_log(small_run):
    _, events = small_run
    warned = [e["message"] for e in events if e.get("event") == "qc_warning" and e.get("dataset") == "gaze_map"]
    card = json.loads((small_run[0] / "datasets" / "gaze_map" / "_dataset.json").read_text())
    assert card["warnings"], "three takes: a split is empty or a take moved"
    for w in card["warnings"]:
        assert f"gaze_map: {w}" in warned
    assert any("moved from" in w or "is empty" in w for w in warned)


def _section(html: str, anchor: str) -> str:
    start = html.index(f'id="{anchor}"')
    nxt = html.find("<h2 id=", start + 1)
    return html[start: nxt if nxt > 0 else len(html)]


def test_contents_and_order(small_run):
    out, _ = small_run
    html = (out / "qc" / "report.html").read_text()
    toc = html[html.index('<nav id="toc">'):html.index("</nav>")]
    for target in ("summary-heading", "problems", "takes", "datasets", "output", "grading"):
        assert f'href="#{target}"' in toc and f'id="{target}"' in html
    assert html.index('id="toc"') < html.index('id="summary"') < html.index('id="takes"') \
        < html.index('id="datasets"') < html.index('id="dataset-gaze_map"')
    report = json.loads((out / "qc" / "report.json").read_text())
    ranked = rank_takes(report["takes"])
    summary = html[html.index('id="summary"'):html.index("</table>", html.index('id="summary"'))]
    rows = re.findall(r'href="#take-([^"]+)"', summary)
    assert rows == [f"take-{k}".replace("/", "-")[5:] for k in ranked]
    sections = re.findall(r'<h2 id="take-([^"]+)"', html)
    assert sections == rows


def test_plots_say_what_they_show(small_run):
    out, _ = small_run
    html = (out / "qc" / "report.html").read_text()
    take = _section(html, "take-session01-shift_y036_p12")
    assert "Grey: the frames cropped out" in take and "crop bounds" in take
    assert "cropped out (before/after the rests)" in take          # the timeline's legend
    ds = _section(html, "dataset-gaze_map")
    assert "pelvis" in ds and "spine1" in ds and ">w<" in ds      # element names, grouped by segment
    assert "quaternion w, x, y, z" in ds                          # the unit on the value axis
    assert "How checks are graded" in html and "rows lost" in html
