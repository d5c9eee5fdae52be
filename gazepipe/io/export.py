"""Writing a take back to the capture programs (``gazepipe export``), and markers to a C3D or wide CSV.

:func:`export_take` writes the whole take (every frame of its capture, the crop marked in the file's events
and in a sidecar), in the lab frame by default:

- a measured sample is the capture's own value: read again from the capture file when it is still the one the
  take was ingested from (float64; a C3D's fourth word too: its residual and camera mask), else the take's
  ``markers_raw`` table (float32, within 2e-4 mm of the file). A sample the cleaning put back under its own name
  (a repaired label swap) is the capture's value of the marker that carried it;
- a filled sample is the cleaned take's, brought from the cleaned markers' frame (root at the origin) back to
  the lab: the rigid motion of each frame is fitted on the samples measured in both (a translation, or with
  ``clean.remove_heading`` a rotation too), so a filled sample sits where the capture's own markers put it;
- in a C3D a measured sample keeps its fourth word (its residual and cameras), with a stand-in of one residual
  step and camera 1 where the file wrote 0 (:func:`gazepipe.io.c3d_write.measured_words`), and a filled sample
  gets 0: residual 0, no camera, C3D's mark of a sample not reconstructed from cameras;
- frames outside the crop are written as captured (nothing there was cleaned); samples the cleaning took out
  (spikes left unfilled, swaps it could not repair) are gaps;
- a sidecar ``<file>.gazepipe.json`` lists the crop, every filled sample (marker, first and last source frame,
  method) and every sample taken out, and says where the measured values and residuals came from.

``frame="stabilised"`` writes the cleaned markers' frame instead (the root marker at the origin in every frame;
outside the crop, the capture translated by its root marker).
"""

from __future__ import annotations

import json
import re
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from gazepipe.errors import ConfigError, InputError
from gazepipe.io.c3d import write_c3d
from gazepipe.io.c3d_write import C3DEvent, measured_words, read_point_words, word_bytes, write_c3d_points
from gazepipe.io.export_text import write_nexus_csv, write_qtm_tsv
from gazepipe.io.marker_csv import write_wide_csv
from gazepipe.io.parquet import read_table
from gazepipe.model import FILL_CODES, FILL_NAMES, Markers, filled_samples
from gazepipe.schemas.markers import MARKERS_CLEAN, MARKERS_RAW, table_to_markers

#: export formats: name → (file extension, what it is)
FORMATS: dict[str, tuple[str, str]] = {
    "c3d": (".c3d", "C3D (float storage; residuals, events, the GAZEPIPE parameter group)"),
    "nexus": (".csv", "Vicon Nexus 'Trajectories' CSV"),
    "qtm": (".tsv", "Qualisys QTM 3D TSV (the crop as EVENT lines)"),
    "wide": (".csv", "plain wide CSV: frame, time, <marker>_x/_y/_z"),
}
#: the format a file extension means when none is asked for
BY_SUFFIX = {".c3d": "c3d", ".tsv": "qtm", ".csv": "wide"}
#: POINT:SCALE of an export whose capture gives no residuals: a stand-in residual is one step, 0.01 mm
DEFAULT_SCALE = -0.01
#: the sidecar's suffix, added to the exported file's name
SIDECAR_SUFFIX = ".gazepipe.json"

_MEASURED = FILL_CODES["measured"]
_UNFILLED = FILL_CODES["unfilled"]
_SWAP = FILL_CODES["swap_repaired"]


def write_markers(path: Path, markers: Markers, times: np.ndarray | None = None) -> None:
    """Write ``markers`` as C3D (``.c3d``) or a plain wide CSV (``.csv``; ``times``: its time column, s);
    invalid samples become gaps."""
    suffix = path.suffix.lower()
    if suffix == ".c3d":
        write_c3d(path, markers)
    elif suffix == ".csv":
        write_wide_csv(path, markers, times)
    else:
        raise ConfigError(path, f"cannot write '{suffix or 'no extension'}': use .c3d or .csv")


def export_format(dest: Path, fmt: str | None) -> str:
    """The format to write ``dest`` in: ``fmt`` when given (its extension must match), else the one its
    extension means (:data:`BY_SUFFIX`); :class:`ConfigError` otherwise."""
    suffix = dest.suffix.lower()
    if fmt is None:
        if suffix not in BY_SUFFIX:
            raise ConfigError(dest, f"cannot tell the format from '{suffix or 'no extension'}': use .c3d, .csv "
                                    "or .tsv, or give --format")
        return BY_SUFFIX[suffix]
    if fmt not in FORMATS:
        raise ConfigError(None, f"--format {fmt}: one of {', '.join(FORMATS)}")
    if suffix != FORMATS[fmt][0]:
        raise ConfigError(dest, f"a {fmt} export is a {FORMATS[fmt][0]} file")
    return fmt


def sidecar_path(dest: Path) -> Path:
    """Where the sidecar of an exported or filled file goes: ``<file>.gazepipe.json`` beside it."""
    return dest.with_name(dest.name + SIDECAR_SUFFIX)


# ------------------------------------------------------------------------------------------ the inputs

@dataclass(frozen=True)
class SourceCapture:
    """A take's capture file read again: its markers (labels renamed as at ingest) and, for a C3D, the fourth
    word of every sample and ``|POINT:SCALE|``."""

    path: Path
    markers: Markers
    words: np.ndarray | None = None
    scale: float | None = None


def read_source(path: str | Path, *, rate_hz: float | None, default_units: str,
                renamed: Mapping[str, str] | None = None) -> SourceCapture:
    """Read a take's capture file as ingest read it (:func:`gazepipe.io.capture.read_markers`, the same rate and
    units, the labels renamed by ``renamed``, capture label → markerset name); for a C3D also its fourth words."""
    from gazepipe.io.capture import read_markers, sniff_format

    p = Path(path)
    markers = read_markers(p, rate_hz=rate_hz, default_units=default_units)
    if renamed:
        markers.labels = [renamed.get(lab, lab) for lab in markers.labels]
    words = scale = None
    if sniff_format(p) == "c3d":
        words, scale = read_point_words(p)
    return SourceCapture(p, markers, words, scale)


@dataclass
class TakeTables:
    """A take's tables as the export reads them: the raw capture (every frame) and, when cleaned, the kept
    frames' cleaned markers, their rows in the capture, fill codes and removed spikes, and the crop."""

    raw: Markers
    clean: Markers | None = None
    frames: np.ndarray | None = None
    fill: np.ndarray | None = None
    spike: np.ndarray | None = None
    crop: tuple[int, int] | None = None
    #: capture label → markerset name, where ingest renamed a label (a Vicon ``Subject:`` prefix dropped)
    renamed: dict[str, str] = field(default_factory=dict)


def load_take_tables(take_dir: Path, *, cleaned: bool) -> TakeTables:
    """Read ``markers_raw`` and, with ``cleaned`` (or where it exists), ``markers`` from a take's folder."""
    raw_path, clean_path = take_dir / "markers_raw.parquet", take_dir / "markers.parquet"
    if not raw_path.is_file():
        raise InputError(raw_path, "not found: has `gazepipe ingest` run on this take?")
    raw, frames, _, raw_meta = table_to_markers(read_table(raw_path, MARKERS_RAW))
    if not np.array_equal(frames, np.arange(raw.n_frames)):
        raise InputError(raw_path, "rows are not the capture's frames in order")
    got = raw_meta.get("renamed_labels")
    renamed = {str(k): str(v) for k, v in got.items()} if isinstance(got, dict) else {}
    if not clean_path.is_file():
        if cleaned:
            raise InputError(clean_path, "not found: has `gazepipe clean` run on this take?")
        return TakeTables(raw, renamed=renamed)
    table = read_table(clean_path, MARKERS_CLEAN)
    clean, kept, fill, meta = table_to_markers(table)
    if clean.labels != raw.labels:
        raise InputError(clean_path, "its markers are not those of markers_raw.parquet (re-run `gazepipe clean`)")
    if len(kept) and (kept[0] < 0 or kept[-1] >= raw.n_frames
                      or not np.array_equal(kept, np.arange(kept[0], kept[0] + len(kept)))):
        raise InputError(clean_path, "rows are not consecutive frames of the capture")
    spike = table.column("spike").to_numpy(zero_copy_only=False).reshape(clean.n_markers, len(kept)).T
    crop_meta = meta.get("crop")
    crop = (int(kept[0]), int(kept[-1]) + 1) if len(kept) else (
        (int(crop_meta[0]), int(crop_meta[1])) if isinstance(crop_meta, list) and len(crop_meta) == 2 else (0, 0))
    return TakeTables(raw, clean, kept, fill, spike, crop, renamed)


# ------------------------------------------------------------------------------------------ the take

@dataclass
class Assembled:
    """The whole take as it is written: (T, M, 3) mm, (T, M) written samples, (T, M) :data:`FILL_CODES` of each
    (``measured`` outside the crop where captured), (T, M) samples the cleaning took out, (T, M) fourth words
    (C3D), and facts for the sidecar."""

    xyz: np.ndarray
    valid: np.ndarray
    code: np.ndarray
    removed: np.ndarray
    words: np.ndarray
    notes: list[str] = field(default_factory=list)
    counts: dict[str, int] = field(default_factory=dict)


def _usable_source(source: SourceCapture | None, raw: Markers, notes: list[str]) -> SourceCapture | None:
    """``source`` when it is the capture the take was ingested from (the same markers and frames, and every
    sample equal to the table's at its float32 precision), else None with a note saying why."""
    if source is None:
        return None
    m = source.markers
    same = (m.labels == raw.labels and m.xyz.shape == raw.xyz.shape and np.array_equal(m.valid, raw.valid)
            and m.first_frame == raw.first_frame)
    if same:
        a = m.xyz[m.valid].astype(np.float32)
        same = bool(np.array_equal(a, raw.xyz[raw.valid].astype(np.float32)))
    if not same:
        notes.append(f"{source.path} is no longer the capture this take was ingested from: measured samples are "
                     "the markers_raw table's (float32), residuals stand-ins")
        return None
    return source


def _rigid_fit(clean: np.ndarray, lab: np.ndarray, pairs: np.ndarray, rotate: bool
               ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Per frame, the rigid motion taking ``clean`` (N, M, 3) to ``lab`` (N, M, 3) fitted on the samples of
    ``pairs`` (N, M): (N, 3, 3) rotations (identity unless ``rotate``), (N, 3) shifts, and (N,) whether the frame
    had enough samples (1 for a shift, 3 not on a line for a rotation)."""
    n = pairs.shape[0]
    w = pairs.astype(np.float64)[..., None]
    count = w.sum(axis=1)                                           # (N, 1)
    c0 = np.where(pairs[..., None], clean, 0.0)
    l0 = np.where(pairs[..., None], lab, 0.0)
    safe = np.maximum(count, 1.0)
    cc, lc = c0.sum(axis=1) / safe, l0.sum(axis=1) / safe           # centroids (N, 3)
    rot = np.broadcast_to(np.eye(3), (n, 3, 3)).copy()
    ok = count[:, 0] >= 1
    if rotate:
        h = np.einsum("nmi,nmj->nij", (c0 - cc[:, None]) * w, (l0 - lc[:, None]) * w)
        u, s, vt = np.linalg.svd(h)
        d = np.sign(np.linalg.det(np.einsum("nji,nkj->nik", vt, u)))
        fix = np.ones((n, 3))
        fix[:, 2] = np.where(d == 0, 1.0, d)
        rot = np.einsum("nji,nj,nkj->nik", vt, fix, u)              # V · diag(1, 1, d) · Uᵀ
        ok &= (count[:, 0] >= 3) & (s[:, 1] > 1e-9 * np.maximum(s[:, 0], 1e-300))
    shift = lc - np.einsum("nij,nj->ni", rot, cc)
    return rot, shift, ok


def _near(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Whether positions ``a`` and ``b`` (..., 3) are the same sample up to the float32 rounding of the take's
    tables (2^-23 of the coordinates, with a margin)."""
    tol = 1e-3 + 4e-7 * np.maximum(np.abs(a), np.abs(b)).max(axis=-1)
    return np.linalg.norm(a - b, axis=-1) <= tol


def _swap_sources(est: np.ndarray, raw_xyz: np.ndarray, raw_ok: np.ndarray, rows: np.ndarray, cols: np.ndarray
                  ) -> np.ndarray:
    """For each repaired-swap sample (``rows``, ``cols`` of the kept frames; ``est`` (n, 3) its lab position), the
    capture's marker that carried it in that frame (the one at its position), or -1."""
    if rows.size == 0:
        return np.zeros(0, dtype=np.int64)
    cand = raw_xyz[rows]                                            # (n, M, 3)
    hit = _near(cand, est[:, None, :]) & raw_ok[rows]
    d = np.where(hit, np.linalg.norm(cand - est[:, None, :], axis=-1), np.inf)
    best = np.argmin(d, axis=1)
    return np.where(hit[np.arange(rows.size), best], best, -1)


def assemble(tables: TakeTables, source: SourceCapture | None, *, frame: str = "lab", heading: bool = False
             ) -> Assembled:
    """The whole take as :func:`export_take` writes it (see the module's docstring); ``heading``: whether the
    clean stage also removed the heading (``clean.remove_heading``), so each frame's fit has a rotation."""
    raw = tables.raw
    notes: list[str] = []
    src = _usable_source(source, raw, notes)
    exact = src.markers.xyz if src is not None else raw.xyz         # the capture's values, NaN at gaps
    t, m = raw.valid.shape
    words = np.where(raw.valid, 0.0, -1.0) if src is None or src.words is None else src.words.copy()
    words, stand_in = measured_words(words)
    code = np.where(raw.valid, _MEASURED, _UNFILLED).astype(np.int8)
    xyz = np.where(raw.valid[..., None], exact, np.nan)
    removed = np.zeros((t, m), dtype=bool)
    counts = {"unplaced": 0, "smoothed": 0}
    if tables.clean is not None and tables.frames is not None and tables.fill is not None and len(tables.frames):
        _cleaned_frames(tables, exact, xyz, code, words, removed, counts, frame, heading, notes)
    if frame == "stabilised":
        _stabilise_outside(tables, xyz, heading, notes)
    valid = np.isfinite(xyz).all(axis=2) & (code != _UNFILLED)
    xyz[~valid] = np.nan
    words = np.where(valid, words, -1.0)
    filled = valid & (code != _MEASURED) & (code != _SWAP)
    words[filled] = 0.0
    counts.update(frames=t, markers=m, measured=int((valid & ~filled).sum()), filled=int(filled.sum()),
                  gaps=int((~valid).sum()), removed=int(removed.sum()),
                  residual_stand_ins=int((stand_in & valid & ~filled).sum()))
    return Assembled(xyz, valid, code, removed, words, notes, counts)


def _cleaned_frames(tables: TakeTables, exact: np.ndarray, xyz: np.ndarray, code: np.ndarray, words: np.ndarray,
                    removed: np.ndarray, counts: dict[str, int], frame: str, heading: bool,
                    notes: list[str]) -> None:
    """Write the kept frames' cleaned samples into ``xyz``, ``code``, ``words`` and ``removed`` (in place)."""
    assert tables.clean is not None and tables.frames is not None and tables.fill is not None
    raw, clean, rows, fill = tables.raw, tables.clean.xyz, tables.frames, tables.fill
    raw_ok = raw.valid[rows]
    raw_at = exact[rows]
    c_ok = np.isfinite(clean).all(axis=2)
    pairs = (fill == _MEASURED) & raw_ok & c_ok
    rot, shift, fit_ok = _rigid_fit(clean, raw_at, pairs, heading)
    est = np.einsum("nij,nmj->nmi", rot, np.where(c_ok[..., None], clean, 0.0)) + shift[:, None, :]
    est[~c_ok] = np.nan
    out = est.copy() if frame == "lab" else np.where(c_ok[..., None], clean, np.nan)
    kept_words = words[rows].copy()
    # measured: the capture's value where the cleaning left it (no low-pass), bit for bit
    measured = (fill == _MEASURED) & c_ok
    same = measured & raw_ok & _near(est, raw_at)
    if frame == "lab":
        out[same] = raw_at[same]
    counts["smoothed"] = int((measured & ~same).sum())
    # repaired swaps: the capture's value (and word) of the marker that carried the sample
    r, c = np.nonzero((fill == _SWAP) & c_ok)
    carrier = _swap_sources(est[r, c], raw_at, raw_ok, r, c)
    found = carrier >= 0
    if frame == "lab":
        out[r[found], c[found]] = raw_at[r[found], carrier[found]]
    kept_words[r[found], c[found]] = words[rows][r[found], carrier[found]]
    kept_words[r[~found], c[~found]] = 257.0     # measured, but its carrier not found: a stand-in word
    # filled: placed in the lab by the frame's fit; a frame without one leaves them unplaced (gaps)
    filled = (fill != _MEASURED) & (fill != _SWAP) & (fill != _UNFILLED) & c_ok
    unplaced = filled & ~fit_ok[:, None] if frame == "lab" else np.zeros_like(filled)
    counts["unplaced"] = int(unplaced.sum())
    if unplaced.any():
        notes.append(f"{int(unplaced.sum())} filled samples in {int(unplaced.any(axis=1).sum())} frames without "
                     f"{'3 measured markers' if heading else 'a measured marker'} to place them in the lab "
                     "frame are written as gaps")
    code_k = np.where(unplaced, _UNFILLED, fill).astype(np.int8)
    code_k[~c_ok & (code_k != _UNFILLED)] = _UNFILLED
    out[code_k == _UNFILLED] = np.nan
    xyz[rows] = out
    code[rows] = code_k
    words[rows] = kept_words
    removed[rows] = raw_ok & (code_k == _UNFILLED)
    if counts["smoothed"]:
        notes.append(f"{counts['smoothed']} measured samples were smoothed by the cleaning (clean.lowpass_hz): "
                     "written as cleaned, not as captured")


def _stabilise_outside(tables: TakeTables, xyz: np.ndarray, heading: bool, notes: list[str]) -> None:
    """Outside the crop, the capture translated by its root marker (the cleaned table's marker that is at the
    origin in every kept frame); gaps where that is unknown (no root, or the heading was removed)."""
    t = xyz.shape[0]
    inside = np.zeros(t, dtype=bool)
    if tables.frames is not None and len(tables.frames):
        inside[tables.frames] = True
    outside = ~inside
    if not outside.any():
        return
    root = _root_column(tables)
    if root is None or heading:
        xyz[outside] = np.nan
        why = "the heading was removed (clean.remove_heading)" if heading else "no root marker was found"
        notes.append(f"{int(outside.sum())} frames outside the crop written as gaps: {why}")
        return
    xyz[outside] -= xyz[outside][:, root: root + 1, :]


def _root_column(tables: TakeTables) -> int | None:
    """The cleaned markers' root: the marker at exactly the origin wherever it is valid in the kept frames."""
    if tables.clean is None or not tables.clean.n_frames:
        return None
    c = tables.clean
    at0 = np.where(c.valid[..., None], c.xyz == 0.0, True).all(axis=(0, 2)) & c.valid.any(axis=0)
    found = np.flatnonzero(at0)
    return int(found[0]) if found.size == 1 else None


# ------------------------------------------------------------------------------------------ listings

def sample_runs(mask: np.ndarray, code: np.ndarray, labels: list[str], first_frame: int
                ) -> dict[str, list[list[Any]]]:
    """Runs of ``mask`` (T, M) with one ``code`` (T, M :data:`FILL_CODES`), per marker:
    ``{label: [[first source frame, last source frame, method], …]}`` (inclusive), markers without one left out."""
    mk = np.asarray(mask, dtype=bool).T                              # (M, T)
    cd = np.asarray(code).T
    prev = np.zeros_like(mk)
    prev[:, 1:] = mk[:, :-1] & (cd[:, 1:] == cd[:, :-1])
    nxt = np.zeros_like(mk)
    nxt[:, :-1] = mk[:, 1:] & (cd[:, 1:] == cd[:, :-1])
    sm, st = np.nonzero(mk & ~prev)
    _, et = np.nonzero(mk & ~nxt)
    out: dict[str, list[list[Any]]] = {}
    for marker, a, b in zip(sm.tolist(), st.tolist(), et.tolist(), strict=True):
        out.setdefault(labels[marker], []).append([first_frame + a, first_frame + b, FILL_NAMES[int(cd[marker, a])]])
    return out


def fill_listing(orig: Markers, filled: Markers, removed: np.ndarray | None, gap_list: list[dict[str, Any]]
                 ) -> dict[str, Any]:
    """The samples ``gazepipe fill`` wrote into a copy of a capture: ``filled`` (per marker, runs of first and last
    file frame with their method, from the summary's ``gap_list``) and ``removed`` (measured samples made gaps:
    spikes, unrepairable swaps), as the export's sidecar lists them."""
    write, valid = filled_samples(orig, filled, removed)
    code = np.full(write.shape, _MEASURED, dtype=np.int8)
    col = {lab: i for i, lab in enumerate(orig.labels)}
    for g in gap_list:
        if g.get("method") in FILL_CODES and g["method"] != "unfilled" and g.get("marker") in col:
            a, b = int(g["first_frame"]) - orig.first_frame, int(g["last_frame"]) - orig.first_frame + 1
            code[max(a, 0): max(b, 0), col[g["marker"]]] = FILL_CODES[g["method"]]
    code[write & valid & (code == _MEASURED)] = _SWAP        # a measured sample written anew: a repaired swap
    gone = write & ~valid
    return {"filled": sample_runs(write & valid, code, orig.labels, orig.first_frame),
            "removed": {k: [r[:2] for r in v] for k, v in
                        sample_runs(gone, np.full(write.shape, _UNFILLED), orig.labels, orig.first_frame).items()}}


def write_sidecar(path: Path, facts: dict[str, Any]) -> None:
    """Write a sidecar JSON (``facts``): one key a line, each innermost list (a run of samples) on one line."""
    text = re.sub(r"\[\s+([^\[\]{}]*?)\s+\]", lambda mt: "[" + " ".join(mt.group(1).split()) + "]",
                  json.dumps(facts, indent=1, ensure_ascii=False))
    try:
        path.write_text(text + "\n", encoding="utf-8")
    except OSError as e:
        raise InputError(path, f"cannot write file ({e.strerror or e})") from None


# ------------------------------------------------------------------------------------------ the export

@dataclass
class ExportResult:
    """What :func:`export_take` wrote."""

    path: Path
    sidecar: Path
    fmt: str
    counts: dict[str, int]
    crop: tuple[int, int] | None
    notes: list[str]


def export_take(tables: TakeTables, dest: Path, *, take: str, fmt: str, frame: str = "lab",
                source: SourceCapture | None = None, heading: bool = False, sidecar: Path | None = None,
                name: str | None = None, version: str = "") -> ExportResult:
    """Write a take (``tables``) to ``dest`` in ``fmt`` (:data:`FORMATS`) and its sidecar (default
    :func:`sidecar_path`), as the module's docstring says. ``take``: ``session/take``, for the file's
    parameters and the sidecar. ``source``: the capture file read again (:func:`read_source`), or None.
    ``name``: the file's name for the sidecar (default ``dest``'s, which may be a temporary file's);
    ``version``: gazepipe's, written into the file's parameters and the sidecar."""
    raw = tables.raw
    asm = assemble(tables, source, frame=frame, heading=heading)
    crop = None
    events: list[C3DEvent] = []
    if tables.crop is not None and tables.crop[1] > tables.crop[0]:
        crop = (raw.first_frame + tables.crop[0], raw.first_frame + tables.crop[1] - 1)   # inclusive
        events = [C3DEvent("gazepipe crop start", crop[0], description="first frame gazepipe keeps (rest cropping)"),
                  C3DEvent("gazepipe crop end", crop[1], description="last frame gazepipe keeps (rest cropping)")]
    src = _usable_source(source, raw, [])
    scale = _export_scale(src)
    if fmt == "c3d":
        groups: dict[str, dict[str, str | float | list[float]]] = {
            "GAZEPIPE": {"TAKE": take, "FRAME": frame, "VERSION": version},
            "MANUFACTURER": {"COMPANY": "gazepipe", "SOFTWARE": "gazepipe export", "VERSION_LABEL": version}}
        if crop is not None:
            groups["GAZEPIPE"]["CROP"] = [float(crop[0]), float(crop[1])]
        write_c3d_points(dest, raw.labels, asm.xyz, asm.words, rate_hz=raw.rate_hz, first_frame=raw.first_frame,
                         scale=scale, events=events, groups=groups)
    elif fmt == "nexus":
        write_nexus_csv(dest, raw.labels, asm.xyz, asm.valid, rate_hz=raw.rate_hz, first_frame=raw.first_frame)
    elif fmt == "qtm":
        write_qtm_tsv(dest, raw.labels, asm.xyz, asm.valid, rate_hz=raw.rate_hz, first_frame=raw.first_frame,
                      events=[(e.label, e.frame) for e in events], trajectory_types=_trajectory_types(asm))
    elif fmt == "wide":
        out = Markers(labels=list(raw.labels), xyz=asm.xyz, valid=asm.valid, rate_hz=raw.rate_hz,
                      first_frame=raw.first_frame)
        try:
            write_wide_csv(dest, out)
        except OSError as e:
            raise InputError(dest, f"cannot write file ({e.strerror or e})") from None
    else:
        raise ConfigError(None, f"unknown export format {fmt!r}")
    side = sidecar or sidecar_path(dest)
    write_sidecar(side, {"gazepipe_version": version,
                         **_facts(tables, asm, name or dest.name, take, fmt, frame, crop, src, scale)})
    return ExportResult(dest, side, fmt, asm.counts, crop, asm.notes)


def _export_scale(src: SourceCapture | None) -> float:
    """POINT:SCALE of the export: the capture's own where its measured samples' words hold residuals (so they
    keep their meaning), else :data:`DEFAULT_SCALE`."""
    if src is None or src.words is None or not src.scale or not np.isfinite(src.scale):
        return DEFAULT_SCALE
    low, _ = word_bytes(src.words[src.markers.valid])
    return -abs(float(src.scale)) if (low > 0).any() else DEFAULT_SCALE


def _trajectory_types(asm: Assembled) -> list[str]:
    """QTM's type of each trajectory: Measured (nothing filled), Gap-filled (nothing measured) or Mixed."""
    filled = asm.valid & (asm.code != _MEASURED) & (asm.code != _SWAP)
    measured = asm.valid & ~filled
    return ["Mixed" if f and m else "Gap-filled" if f else "Measured"
            for f, m in zip(filled.any(axis=0).tolist(), measured.any(axis=0).tolist(), strict=True)]


def _facts(tables: TakeTables, asm: Assembled, name: str, take: str, fmt: str, frame: str,
           crop: tuple[int, int] | None, src: SourceCapture | None, scale: float) -> dict[str, Any]:
    """The sidecar's contents."""
    raw = tables.raw
    filled = asm.valid & (asm.code != _MEASURED) & (asm.code != _SWAP)
    removed_code = np.where(asm.removed, _UNFILLED, _MEASURED)
    residuals: dict[str, Any] = {"source": "capture file" if src is not None and src.words is not None else "none",
                                 "stand_in_mm": abs(scale), "stand_ins": asm.counts["residual_stand_ins"]}
    return {
        "take": take, "file": name, "format": fmt,
        "frame": frame, "units": "mm", "rate_hz": raw.rate_hz, "first_frame": raw.first_frame,
        "frames": raw.n_frames, "frame_numbers": "the capture's own; ranges are first and last frame, inclusive",
        "crop": None if crop is None else {"first": crop[0], "last": crop[1],
                                           "note": "the frames gazepipe keeps; outside them the take is written "
                                                   "as captured (nothing there was cleaned)"},
        "measured_values": "capture file" if src is not None else "markers_raw table (float32)",
        "capture_file": None if src is None else str(src.path),
        "residuals": residuals,
        "counts": dict(asm.counts),
        "notes": list(asm.notes),
        "filled": sample_runs(filled, asm.code, raw.labels, raw.first_frame),
        "removed": {k: [r[:2] for r in v] for k, v in
                    sample_runs(asm.removed, removed_code, raw.labels, raw.first_frame).items()},
    }
