"""Helpers shared by the test modules: the one place they import from (a test module never imports another).

- this module: paths of the sample session and the reference corpus, a tiny hand-made session, slices of the
  sample session, the CLI run the report tests share, file digests;
- :mod:`tests.helpers.sample`: read what ``gazepipe run`` wrote for the sample session and compare it with its
  ground truth (the acceptance tests and the dataset tests);
- :mod:`tests.helpers.captures`: small capture files (Nexus CSV, QTM TSV) and a synthetic marker body for the
  reader and gap-filler tests;
- :mod:`tests.helpers.datasets`: small but real datasets built from generated sessions;
- :mod:`tests.helpers.shared`: outputs built once per test run and shared read-only (the fixtures are in
  ``tests/conftest.py``).
"""

from __future__ import annotations

import hashlib
import json
import re
import shutil
import textwrap
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[2]
TESTS = REPO / "tests"
SAMPLE = REPO / "sample_data" / "session01"
CORPUS = REPO / "tests" / "data" / "corpus"


# ------------------------------------------------------------------------------------------- a tiny session

def write_wide_csv(path: Path, labels: list[str], xyz: np.ndarray, rate_hz: float) -> None:
    """A plain wide CSV (frame, time, <m>_x, <m>_y, <m>_z); NaN samples become empty cells."""
    T = xyz.shape[0]
    cols = ["frame", "time"] + [f"{m}_{a}" for m in labels for a in "xyz"]
    rows = [",".join(cols)]
    flat = xyz.reshape(T, -1)
    for i in range(T):
        vals = ["" if np.isnan(v) else f"{v:.4f}" for v in flat[i]]
        rows.append(",".join([str(i + 1), f"{i / rate_hz:.6f}", *vals]))
    path.write_text("\n".join(rows) + "\n")


TINY_MARKERSET = """\
schema = 1
up_axis = "z"
units = "mm"
root = "SACR"
target = "POLE"

[segments.pelvis]
markers = ["PL", "PR", "PB"]
[segments.head]
markers = ["H1", "H2", "H3"]
parent = "pelvis"
"""


def tiny_motion(seed: int, T: int = 90, rate_hz: float = 30.0) -> tuple[list[str], np.ndarray]:
    """Smooth, seeded motion of 8 markers: the root, a pelvis and a head triangle, the target (mm)."""
    rng = np.random.default_rng(seed)
    t = np.arange(T) / rate_hz
    base = np.array([[0, 0, 1000], [100, 0, 1000], [-100, 0, 1000], [0, -80, 1000],
                     [30, 0, 1650], [-30, 0, 1650], [0, 40, 1700], [0, 1500, 1600]], float)
    wobble = 20 * np.sin(2 * np.pi * 0.3 * t + rng.uniform(0, 6))[:, None, None]
    xyz = base[None] + wobble * np.array([1.0, 0.5, 0.0]) + rng.normal(0, 0.3, (T, 8, 3))
    return ["SACR", "PL", "PR", "PB", "H1", "H2", "H3", "POLE"], xyz


def make_tiny_session(root: Path, n_takes: int = 3, kind: str = "gaze_follow") -> Path:
    """A session folder with ``n_takes`` wide-CSV mocap takes and a two-segment markerset."""
    (root / "mocap").mkdir(parents=True, exist_ok=True)
    (root / "markerset.toml").write_text(TINY_MARKERSET)
    takes = []
    for i in range(n_takes):
        labels, xyz = tiny_motion(i)
        write_wide_csv(root / "mocap" / f"t{i}.csv", labels, xyz, 30.0)
        takes.append(textwrap.dedent(f"""\
            [[takes]]
            id = "t{i}"
            kind = "gaze_follow"
            pose = "standing"
            mocap = "mocap/t{i}.csv"
            """))
    (root / "session.toml").write_text(textwrap.dedent("""\
        schema = 1
        [session]
        id = "tiny"
        subject = "p01"
        markerset = "markerset.toml"
        """) + "\n" + "\n".join(takes))
    return root


# ------------------------------------------------------------------------------- slices of the sample session

def session_copy(dest: Path, takes: dict[str, str | None]) -> Path:
    """A session folder with the chosen takes of the sample session (same files, same markerset); a take's value
    is the split it is pinned to, or None."""
    from gazepipe.io.session_toml import load_session

    src = load_session(SAMPLE)
    (dest / "mocap").mkdir(parents=True)
    shutil.copy(Path(src.root) / "markerset.toml", dest / "markerset.toml")
    lines = ['schema = 1', '[session]', f'id = "{src.id}"', f'subject = "{src.subject}"',
             'markerset = "markerset.toml"', '']
    for t in src.takes:
        if t.id not in takes:
            continue
        lines += ['[[takes]]', f'id = "{t.id}"', f'kind = "{t.kind}"', f'pose = "{t.pose}"']
        for key in ("mocap", "video", "eyes"):
            path = getattr(t, key)
            if path:
                rel = Path(path).relative_to(src.root)
                (dest / rel).parent.mkdir(parents=True, exist_ok=True)
                shutil.copy(path, dest / rel)
                lines.append(f'{key} = "{rel.as_posix()}"')
        if t.target_yaw_deg is not None:
            lines.append(f"target = {{ yaw_deg = {t.target_yaw_deg}, pitch_deg = {t.target_pitch_deg} }}")
        if takes[t.id]:
            lines.append(f'split = "{takes[t.id]}"')
        lines.append("")
    (dest / "session.toml").write_text("\n".join(lines))
    return dest


def run_session(session: Path, out: Path) -> None:
    """``gazepipe run`` (serial, JSON log) in this process; a failed take is allowed (exit 0 or 1)."""
    from click.testing import CliRunner

    from gazepipe.cli.main import cli

    res = CliRunner().invoke(cli, ["run", str(session), "--out", str(out), "--executor", "serial",
                                   "--log-format", "json"])
    assert res.exit_code in (0, 1), res.output


# ------------------------------------------------------------------------------------------------ digests

def output_digests(out: Path) -> dict[str, str]:
    """sha256 of every file under OUT except the run state."""
    return {str(p.relative_to(out)): hashlib.sha256(p.read_bytes()).hexdigest()
            for p in sorted(out.rglob("*")) if p.is_file() and ".gazepipe" not in p.parts}


def tree_digest(root: Path, parts: tuple[str, ...]) -> dict[str, str]:
    """SHA-256 of every file under ``root/<part>`` for each part, keyed by relative path."""
    out = {}
    for part in parts:
        base = root / part
        for p in sorted(base.rglob("*")):
            if p.is_file():
                out[str(p.relative_to(root))] = hashlib.sha256(p.read_bytes()).hexdigest()
    return out


# --------------------------------------------------------------------------------------- pages

#: marker labels a capture may hold that must not break the page: one opening an HTML comment and a script (the
#: script element then never ends: a blank page), a closing tag, entities and line separators, a placeholder name
HOSTILE_LABELS = ["<!--<script>", "</script><b>x</b>", "a&amp;b\u2028\u2029", "INFO"]


def script_data(page: str) -> list[str]:
    """The text of each inline script element of a page (up to its first ``</script``, as a browser reads it)."""
    return [m.group(1) for m in re.finditer(r"<script>(.*?)</script", page, flags=re.S)]


def check_page_escapes(page: str, labels: list[str]) -> None:
    """Every inline script of ``page`` is whole (it holds no ``<!--``, ``<script`` or ``</`` that a browser would
    read as markup, no ``&``, U+2028 or U+2029) and its figure's JSON gives the ``labels`` back as they are."""
    data = script_data(page)
    assert data and page.count("</script>") == page.count("<script")
    for text in data[-1:]:                          # the page's own script (a stand-alone page inlines Plotly first)
        for bad in ("<!--", "<script", "</", "&", "\u2028", "\u2029"):
            assert bad not in text.lower(), bad
        fig = json.loads(re.search(r"var fig=(\{.*?\}), info=\{", text, flags=re.S).group(1))
        texts = {t for frame in fig["frames"] for d in frame["data"] for t in d.get("text", [])}
        assert set(labels) <= texts
