"""`gazepipe validate` stays quick on big outputs: every take and dataset is checked, but plots are drawn for the
worst few takes only (``--plot-takes N|all`` and ``--plot-take NAME`` ask for others; the page says which) and
figures drawn before are read back from the output folder's figure cache with the same bytes.

No timing is asserted (it depends on the machine): what is drawn, what the page says, and the bytes.
"""

from __future__ import annotations

import json
import shutil
import subprocess
import sys
from pathlib import Path

import pytest
from click.testing import CliRunner

from gazepipe.cli.validate import validate
from gazepipe.report.html import anchor
from gazepipe.report.validate import (
    DEFAULT_PLOT_TAKES,
    FigureCache,
    match_takes,
    plot_limit,
    rank_takes,
    take_rank_key,
)
from tests.helpers import run_session, session_copy
from tests.helpers.shared import shared_folder

# the neutral take and seven gaze-shift takes of the sample session: eight takes with something to draw, more
# than the default number of plotted takes
TAKES = {"neutral": None, "shift_y000_p12": "train", "shift_y036_p12": "train", "shift_y036_pm12": None,
         "shift_y072_p00": None, "shift_ym036_p00": "val", "shift_ym036_pm12": None, "shift_ym072_p12": None}
KEYS = sorted(f"session01/{t}" for t in TAKES)
FILES = ("report.json", "takes.parquet", "report.html")


def _run_many(folder: Path) -> None:
    run_session(session_copy(folder / "session", TAKES), folder / "out")


@pytest.fixture(scope="module")
def many_out(tmp_path_factory) -> Path:
    """The run of the eight takes, once per test run (shared by pytest-xdist's workers), read only."""
    return shared_folder(tmp_path_factory, "validate_speed_many_out", _run_many, fixture="many_out") / "out"


@pytest.fixture
def out(many_out: Path, tmp_path: Path) -> Path:
    """A copy of the output for one test to validate and change as it likes."""
    dest = tmp_path / "out"
    shutil.copytree(many_out, dest)
    return dest


def _validate(out: Path, *args: str):
    return CliRunner().invoke(validate, [str(out), *args])


def _section(html: str, key: str) -> str:
    start = html.index(f'id="{anchor("take", key)}"')
    nxt = html.find("<h2 id=", start + 1)
    return html[start: nxt if nxt > 0 else len(html)]


def _plotted(out: Path) -> list[str]:
    html = (out / "qc" / "report.html").read_text()
    return [k for k in KEYS if "<svg" in _section(html, k)]


def _files(out: Path) -> dict[str, bytes]:
    return {n: (out / "qc" / n).read_bytes() for n in FILES}


def _cache(out: Path) -> list[Path]:
    return sorted((out / ".gazepipe" / FigureCache.DIRNAME).glob("*.json"))


# ------------------------------------------------------------------------------------------- what is drawn

def test_default_plots_the_worst_takes_only_and_checks_every_take(out: Path) -> None:
    res = _validate(out)
    assert res.exit_code == 0, res.output
    rep = json.loads((out / "qc" / "report.json").read_text())
    assert sorted(f"{t['session']}/{t['take']}" for t in rep["takes"]) == KEYS
    plotted = _plotted(out)
    assert len(plotted) == DEFAULT_PLOT_TAKES < len(KEYS)
    assert set(plotted) == set(rank_takes(rep["takes"])[:DEFAULT_PLOT_TAKES])
    # the plots are all that changes: every take has all its checks whatever is drawn
    default = _files(out)
    assert _validate(out, "--plot-takes", "all").exit_code == 0
    assert _plotted(out) == KEYS
    for name in ("report.json", "takes.parquet"):
        assert (out / "qc" / name).read_bytes() == default[name], name
    assert all(len(t["checks"]) >= 10 for t in rep["takes"])


def test_a_failed_take_is_ranked_and_plotted_first(out: Path) -> None:
    assert _validate(out, "--no-plots").exit_code == 0
    best = rank_takes(json.loads((out / "qc" / "report.json").read_text())["takes"])[-1]
    # the clean stage of the take that ranked last failed (its rests were not found, say): it fails the gate, it
    # now ranks first, and its plots (the gap timeline from the raw markers; no speed trace, which only a clean
    # unit that finished records) are the ones a single plot goes to
    record = out / ".gazepipe" / "units" / best / "clean.json"
    rec = json.loads(record.read_text())
    rec.update(status="failed", error="clean: no rest found at the start of the take")
    record.write_text(json.dumps(rec))
    res = _validate(out, "--plot-takes", "1")
    assert res.exit_code == 3, res.output
    rep = json.loads((out / "qc" / "report.json").read_text())
    assert rank_takes(rep["takes"])[0] == best
    assert _plotted(out) == [best]
    html = (out / "qc" / "report.html").read_text()
    sec = _section(html, best)
    assert "Gap timeline" in sec and "Speed and crop" not in sec
    assert "the clean stage did not finish on this take" in html
    plots = html[html.index('<div id="plots">'):html.index("</div>", html.index('<div id="plots">'))]
    assert f'href="#{anchor("take", best)}"' in plots


def test_plot_takes_all_draws_every_take(out: Path) -> None:
    res = _validate(out, "--plot-takes", "all")
    assert res.exit_code == 0, res.output
    assert _plotted(out) == KEYS
    html = (out / "qc" / "report.html").read_text()
    summary = html[html.index('id="summary"'):html.index("</table>", html.index('id="summary"'))]
    assert "not drawn" not in summary and summary.count("<td>drawn</td>") >= len(KEYS)
    assert "every take with something to draw" in html


def test_takes_asked_for_by_name_or_pattern(out: Path) -> None:
    res = _validate(out, "--plot-takes", "0", "--plot-take", "shift_y036_p12", "--plot-take", "session01/shift_ym07*")
    assert res.exit_code == 0, res.output
    assert _plotted(out) == ["session01/shift_y036_p12", "session01/shift_ym072_p12"]
    html = (out / "qc" / "report.html").read_text()
    gaze_map = html[html.index(f'id="{anchor("dataset", "gaze_map")}"'):]
    assert "<svg" in gaze_map.split("<h2 id=", 1)[0], "--plot-takes 0 leaves the datasets' plots in"
    for args, words in ((["--plot-take", "no_such_take"], "no_such_take"), (["--plot-takes", "-1"], "-1"),
                        (["--plot-takes", "lots"], "lots"), (["--no-plots", "--plot-take", "neutral"], "--no-plots")):
        res = _validate(out, *args)
        assert res.exit_code == 2 and words in res.output, (args, res.output)


def test_html_names_the_plotted_takes_and_how_to_plot_the_others(out: Path) -> None:
    assert _validate(out).exit_code == 0
    html = (out / "qc" / "report.html").read_text()
    ranked = rank_takes(json.loads((out / "qc" / "report.json").read_text())["takes"])
    plots = html[html.index('<div id="plots">'):html.index("</div>", html.index('<div id="plots">'))]
    links = [k for k in ranked if f'href="#{anchor("take", k)}"' in plots]
    assert links == ranked[:DEFAULT_PLOT_TAKES]
    assert [plots.index(f'"#{anchor("take", k)}"') for k in links] == sorted(
        plots.index(f'"#{anchor("take", k)}"') for k in links), "plotted takes listed worst first"
    assert f"drawn for {DEFAULT_PLOT_TAKES} of {len(KEYS)} takes" in plots
    assert "--plot-takes all" in plots and "--plot-take SESSION/TAKE" in plots
    summary = html[html.index('id="summary"'):html.index("</table>", html.index('id="summary"'))]
    assert summary.count("<td>not drawn</td>") == len(KEYS) - DEFAULT_PLOT_TAKES
    for key in ranked[DEFAULT_PLOT_TAKES:]:
        assert f"--plot-take {key}</code> draws them" in _section(html, key)
    assert str(out) not in html, "the page names no folder: the same outputs give the same page anywhere"


# --------------------------------------------------------------------------------------------- the cache

def test_figures_read_back_are_the_bytes_drawn_and_follow_their_data(out: Path) -> None:
    assert _validate(out).exit_code == 0
    drawn = _files(out)
    cached = _cache(out)
    assert cached, "a validation keeps the figures it drew"
    assert _validate(out).exit_code == 0
    assert _files(out) == drawn                                   # read back
    shutil.rmtree(out / ".gazepipe" / FigureCache.DIRNAME)
    assert _validate(out).exit_code == 0
    assert _files(out) == drawn                                   # drawn again
    # what a figure is drawn from changes: the crop of the worst take moves, its plots are drawn anew (the same
    # bytes as drawing them without a cache), the others are read back
    key = _plotted(out)[0]
    record = out / ".gazepipe" / "units" / key / "clean.json"
    rec = json.loads(record.read_text())
    rec["qc"]["crop"] = [rec["qc"]["crop"][0] + 5, rec["qc"]["crop"][1]]
    record.write_text(json.dumps(rec))
    assert _validate(out).exit_code == 0
    moved = _files(out)
    assert moved["report.html"] != drawn["report.html"]
    assert _section(moved["report.html"].decode(), key) != _section(drawn["report.html"].decode(), key)
    shutil.rmtree(out / ".gazepipe" / FigureCache.DIRNAME)
    assert _validate(out).exit_code == 0
    assert _files(out) == moved
    # the cache holds what the last report uses: more with every take plotted, back to the default after
    assert _validate(out, "--plot-takes", "all").exit_code == 0
    assert len(_cache(out)) == len(cached) + len(KEYS) - DEFAULT_PLOT_TAKES
    assert _validate(out).exit_code == 0
    assert len(_cache(out)) == len(cached)


def test_a_validation_after_a_run_draws_nothing_new(out: Path) -> None:
    """`gazepipe run` plots the same worst takes as `gazepipe validate`, through the same cache: the validation
    after it finds every figure it needs there."""
    before = _cache(out)
    assert before
    mtimes = [p.stat().st_mtime_ns for p in before]
    assert _validate(out).exit_code == 0
    assert _cache(out) == before and [p.stat().st_mtime_ns for p in before] == mtimes


def test_figures_read_back_need_no_matplotlib(out: Path) -> None:
    code = ("import sys; from gazepipe.report.validate import validate_output; validate_output(sys.argv[1]); "
            "print('matplotlib' in sys.modules)")

    def matplotlib_imported() -> bool:
        res = subprocess.run([sys.executable, "-c", code, str(out)], capture_output=True, text=True, timeout=300)
        assert res.returncode == 0, res.stderr[-2000:]
        return res.stdout.strip() == "True"

    shutil.rmtree(out / ".gazepipe" / FigureCache.DIRNAME)
    assert matplotlib_imported()
    assert not matplotlib_imported()


# ----------------------------------------------------------------------------------------- pure functions

def _take(name: str, severity: str, checks: list[tuple[str, str, float | None, float | None]]) -> dict:
    return {"session": "s", "take": name, "severity": severity,
            "checks": [{"id": cid, "severity": sev, "value": value, "threshold": {"warning": warn, "fail": None}}
                       for cid, sev, value, warn in checks]}


def test_ranking_failed_first_then_failing_checks_warnings_and_nearest_threshold() -> None:
    takes = [
        _take("a_pass_far", "pass", [("gap_share", "pass", 0.02, 0.2)]),
        _take("b_pass_near", "pass", [("gap_share", "pass", 0.19, 0.2)]),
        _take("c_pass_weak_clap", "pass", [("clap_confidence", "pass", 0.55, 0.5)]),   # lower is worse
        _take("d_warn_one", "warning", [("gap_share", "warning", 0.9, 0.2)]),
        _take("e_warn_two", "warning", [("gap_share", "warning", 0.3, 0.2), ("spikes", "warning", 0.02, 0.01)]),
        _take("f_fail", "fail", [("stages", "fail", 1, None)]),
        _take("g_error", "error", [("table_markers", "error", None, None)]),
        _take("h_fail_two", "fail", [("stages", "fail", 1, None), ("unfilled", "fail", 0.5, 0.05)]),
    ]
    assert rank_takes(takes) == ["s/g_error", "s/h_fail_two", "s/f_fail", "s/e_warn_two", "s/d_warn_one",
                                 "s/b_pass_near", "s/c_pass_weak_clap", "s/a_pass_far"]
    # the name breaks ties, so the order never depends on the order of the input
    assert rank_takes(list(reversed(takes))) == rank_takes(takes)
    assert take_rank_key(takes[0]) > take_rank_key(takes[1])


def test_plot_limit_and_take_names() -> None:
    assert plot_limit("all") is None and plot_limit(None) is None and plot_limit("ALL") is None
    assert plot_limit(3) == 3 and plot_limit("0") == 0
    with pytest.raises(ValueError):
        plot_limit(-1)
    keys = ["s1/face_01", "s1/shift_a", "s2/shift_a", "s2/shift_b"]
    assert match_takes(["s2/shift_a"], keys) == ["s2/shift_a"]
    assert match_takes(["shift_a"], keys) == ["s1/shift_a", "s2/shift_a"]      # a take id, in every session
    assert match_takes(["s2/*", "face_*"], keys) == ["s1/face_01", "s2/shift_a", "s2/shift_b"]
    from gazepipe.errors import ConfigError

    with pytest.raises(ConfigError, match="nothing_like_it"):
        match_takes(["nothing_like_it"], keys)


def test_cli_default_is_the_report_default() -> None:
    from gazepipe.cli.main import REPORT_PLOT_TAKES

    option = next(p for p in validate.params if p.name == "plot_takes")
    assert option.default == DEFAULT_PLOT_TAKES == REPORT_PLOT_TAKES
