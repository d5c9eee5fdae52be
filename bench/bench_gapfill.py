"""Gap-filling accuracy and speed (Gløersen & Federolf 2016 protocol).

From complete marker data, hide samples in realistic occlusion patterns (several markers at once,
gap lengths in bins of 1–5, 6–15, 16–30 and 31–90 frames, capped at ``max_gap_s``), fill, and report the error of
the hidden samples only (mean and 95th percentile, mm) per bin for every method forced on every gap, for the
per-gap choice of :func:`gazepipe.stages.clean.gapfill.fill_gaps`, for the best method in hindsight per gap, and for
kineticstoolkit's cubic fill when it is installed.

Data: the sample session's truth (``sample_data/session01``, with 0.5 mm noise added to the input and errors
measured against the noise-free truth; gaps in the subject's markers, segments from its markerset), and the gap-free stretches of two real C3D files: Walking_Hybrid_2
(trajectories de-duplicated; rigid clusters found from the data) and ART-Human (whole ART triplets hidden).
The per-gap choice may leave a gap unfilled (no error estimate, every fill faster than the capture's fastest
measured step): ``choice`` is then over the gaps it filled, with its coverage, and ``choice/hind`` compares it
with the best method in hindsight on those same gaps.

``--data corpus``: what ``gazepipe fill`` (:func:`gazepipe.stages.clean.standalone.fill_capture`, defaults) does
to every real C3D in tests/data/corpus/c3d as it comes: gaps filled and left (per reason), filled gaps
without an error estimate, the fastest filled step (into, across or out of a fill) against the file's fastest
measured step (spikes left out, and all of them), and samples of unlabeled trajectories filled.

Usage: ``PYTHONPATH=. python bench/bench_gapfill.py [--trials N] [--seeds K] [--seed S]
[--data all|session|real|corpus]``
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

from gazepipe.model import FILL_CODES
from gazepipe.stages.clean.gapfill import METHODS, fill_gaps, find_gaps, find_rigid_clusters
from gazepipe.stages.clean.spikes import remove_spikes

ROOT = Path(__file__).resolve().parents[1]
CORPUS = ROOT / "tests" / "data" / "corpus" / "c3d"
BINS = ((1, 5), (6, 15), (16, 30), (31, 90))
MAX_GAP_S = 1.0
LONG_S = 0.25


# ----------------------------------------------------------------------------------------------- data
def read_c3d(path: Path) -> tuple[list[str], np.ndarray, np.ndarray, float]:
    """Labels, xyz (T, M, 3) mm, valid (T, M), rate: through gazepipe's reader when it exists, else ezc3d."""
    try:
        from gazepipe.io.capture import read_markers  # type: ignore[import-not-found]
    except ImportError:
        read_markers = None
    if read_markers is not None:
        mk = read_markers(path)
        return list(mk.labels), mk.xyz, mk.valid, float(mk.rate_hz)
    import ezc3d

    c = ezc3d.c3d(str(path))
    pts = c["data"]["points"]
    xyz = np.ascontiguousarray(pts[:3].transpose(2, 1, 0), dtype=np.float64)
    res = c["data"]["meta_points"]["residuals"][0].T
    valid = (res >= 0) & ~np.all(xyz == 0, axis=2) & np.isfinite(xyz).all(axis=2)
    labels = list(c["parameters"]["POINT"]["LABELS"]["value"])[: xyz.shape[1]]
    return labels, np.where(valid[..., None], xyz, np.nan), valid, float(c["parameters"]["POINT"]["RATE"]["value"][0])


def dedupe(xyz: np.ndarray, valid: np.ndarray) -> list[int]:
    """Columns to keep: the first of every set of bit-identical trajectories."""
    keep: list[int] = []
    for m in range(xyz.shape[1]):
        if not any(np.array_equal(valid[:, m], valid[:, k]) and
                   np.array_equal(xyz[valid[:, m], m], xyz[valid[:, k], k]) for k in keep):
            keep.append(m)
    return keep


def gap_free_window(valid: np.ndarray, min_share: float = 0.75) -> tuple[int, int, np.ndarray]:
    """The frame window and markers maximising (markers fully measured) × (frames), with at least
    ``min_share`` of the markers."""
    n_t, n_m = valid.shape
    best = (0, 0, 0, np.zeros(n_m, bool))
    for frac in np.linspace(1.0, 0.3, 15):
        w = int(n_t * frac)
        for t0 in range(0, n_t - w + 1, max(1, n_t // 100)):
            ok = valid[t0:t0 + w].all(axis=0)
            if ok.sum() >= min_share * n_m and ok.sum() * w > best[0]:
                best = (int(ok.sum() * w), t0, t0 + w, ok)
    return best[1], best[2], best[3]


def real_dataset(name: str) -> dict | None:
    path = CORPUS / f"{name}.c3d"
    if not path.exists():
        print(f"[{name}] not found at {path}: skipped")
        return None
    labels, xyz, valid, rate = read_c3d(path)
    keep = dedupe(xyz, valid)
    n_dup = xyz.shape[1] - len(keep)
    labels = [labels[k] for k in keep]
    xyz, valid = xyz[:, keep], valid[:, keep]
    valid, n_spk = remove_spikes(xyz, valid, rate)
    t0, t1, ok = gap_free_window(valid)
    cols = np.flatnonzero(ok)
    truth = xyz[t0:t1][:, cols]
    labels = [labels[c] for c in cols]
    note = (f"{len(keep)} distinct of {len(keep) + n_dup} trajectories, {int(n_spk.sum())} spike samples removed, "
            f"gap-free window frames [{t0}, {t1}) with {cols.size} markers")
    if name.startswith("ART"):
        # ART bodies: origin X and XY, XZ 20 mm along its axes; hide whole triplets
        groups: dict[str, list[int]] = {}
        for i, lab in enumerate(labels):
            base = lab[:-1] if lab.endswith(("Y", "Z")) and lab[:-1] in labels else lab
            groups.setdefault(base, []).append(i)
        hide_groups = [g for g in groups.values()]
    else:
        hide_groups = [[i] for i in range(len(labels))]
    clusters = find_rigid_clusters(truth, np.ones(truth.shape[:2], bool))
    return {"name": name, "truth": truth, "input": truth, "rate": rate, "labels": labels,
            "groups": hide_groups, "clusters": clusters, "note": note}


def session_datasets(n_takes: int = 0) -> list[dict]:
    sess = ROOT / "sample_data" / "session01"
    try:
        from gazepipe.synth import load_truth
    except ImportError:
        load_truth = None
    if load_truth is None or not (sess / "truth").is_dir():
        print(f"[sample session] {sess} or gazepipe.synth.load_truth absent: skipped")
        return []
    clusters_by_label: list[list[str]] = []
    subject: set[str] | None = None
    try:
        from gazepipe.io.session_toml import load_markerset

        ms = load_markerset(sess / "markerset.toml")
        clusters_by_label = [list(s.markers) for s in ms.segments]
        subject = set(ms.subject_markers)
    except Exception as exc:  # the benchmark still runs without segment clusters
        print(f"[sample session] markerset not loaded ({exc}); rigid clusters from the data")
    out = []
    rng = np.random.default_rng(7)
    files = [f for f in sorted((sess / "truth").glob("*.npz")) if "markers_true" in np.load(f).files]
    if n_takes:
        files = files[::max(1, len(files) // n_takes)][:n_takes]
    for f in files:
        tr = load_truth(sess, f.stem)
        truth = np.asarray(tr["markers_true"], dtype=np.float64)
        rate = float(1.0 / np.median(np.diff(tr["time_s"])))
        labels = list(tr["labels"])
        if clusters_by_label:
            clusters = [[labels.index(x) for x in c if x in labels] for c in clusters_by_label]
            clusters = [c for c in clusters if len(c) >= 3]
        else:
            clusters = find_rigid_clusters(truth, np.ones(truth.shape[:2], bool))
        noisy = truth + rng.normal(0.0, 0.5, truth.shape)
        # gaps go into the subject's markers only: the target and the clapper are separate objects that
        # nothing else predicts (they are filled too, but a gap during a fast move of the target is a guess)
        hide = [[i] for i, lab in enumerate(labels) if subject is None or lab in subject]
        out.append({"name": f"session01/{f.stem}", "truth": truth, "input": noisy, "rate": rate,
                    "labels": labels, "groups": hide, "clusters": clusters,
                    "note": f"{truth.shape[0]} frames at {rate:.2f} Hz, {truth.shape[1]} markers "
                            f"({len(hide)} subject markers get gaps), 0.5 mm noise"})
    return out


# ------------------------------------------------------------------------------------------ occlusions
def occlude(rng: np.random.Generator, n_t: int, groups: list[list[int]], centres: np.ndarray, lo: int, hi: int,
            n_events: int, pattern: str = "random") -> np.ndarray:
    """valid (T, M) with ``n_events`` occlusions: a random group and, half the time, 1–2 more groups (random
    ones as in Gløersen & Federolf's protocol, or with ``pattern="neighbours"`` its nearest ones, which hides
    segment mates together), each hidden for a length drawn in [lo, hi] with a jittered start around a common
    time; gaps never touch the take's ends and keep 3 frames from any other gap of the same marker."""
    n_m = centres.shape[0]
    valid = np.ones((n_t, n_m), bool)
    gc = np.array([centres[g].mean(axis=0) for g in groups])
    n_placed = 0
    for _ in range(n_events * 20):
        if n_placed >= n_events:
            break
        g0 = int(rng.integers(len(groups)))
        n_more = int(rng.integers(1, 3)) if rng.random() < 0.5 else 0
        if pattern == "neighbours":
            near = np.argsort(np.linalg.norm(gc - gc[g0], axis=1), kind="stable")[1:1 + n_more]
        else:
            near = rng.choice(np.delete(np.arange(len(groups)), g0), size=n_more, replace=False)
        t_c = int(rng.integers(0, n_t))
        placed = []
        for g in [g0, *near.tolist()]:
            length = int(rng.integers(lo, hi + 1))
            s = t_c + int(rng.integers(-length // 2, length // 2 + 1)) - length // 2
            s = min(max(s, 5), n_t - 5 - length)
            if s < 5:
                continue
            cols = groups[g]
            if not valid[max(0, s - 3):s + length + 3, cols].all():
                continue
            placed.append((s, length, cols))
        for s, length, cols in placed:
            valid[s:s + length, cols] = False
        n_placed += bool(placed)
    return valid


def find_all(valid: np.ndarray) -> list[tuple[int, int, int]]:
    return [(m, s, e) for m in range(valid.shape[1]) for s, e in find_gaps(valid[:, m])]


# -------------------------------------------------------------------------------------------- peers
def ktk_fill(xyz: np.ndarray, rate: float) -> np.ndarray | None:
    try:
        import kineticstoolkit as ktk
    except ImportError:
        return None
    n_t, n_m, _ = xyz.shape
    ts = ktk.TimeSeries(time=np.arange(n_t) / rate)
    for m in range(n_m):
        ts.data[f"m{m}"] = np.concatenate([xyz[:, m], np.ones((n_t, 1))], axis=1)
    out = ts.fill_missing_samples(0, method="cubic")
    return np.stack([out.data[f"m{m}"][:, :3] for m in range(n_m)], axis=1)


# -------------------------------------------------------------------------------------------- bench
def run(ds: dict, trials: int, seed: int, pattern: str = "random") -> dict:
    rng = np.random.default_rng(seed)
    truth, inp, rate = ds["truth"], ds["input"], ds["rate"]
    n_t = truth.shape[0]
    max_len = int(MAX_GAP_S * rate)
    cols = ("choice", "hindsight", *METHODS, "ktk")
    per_bin = {b: {c: [] for c in cols} for b in BINS}
    cover = {b: {c: [0, 0] for c in METHODS} for b in BINS}
    chosen = {b: [0, 0] for b in BINS}          # [gaps the choice filled, gaps]
    # choice-vs-method on the gaps a method could fill: [sum choice err, sum method err]
    paired = {b: {c: [0.0, 0.0] for c in METHODS} for b in BINS}
    long_gaps = {c: [] for c in cols}
    changed = 0
    t_fill = t_ktk = 0.0
    n_calls = 0
    centres = truth.mean(axis=0)
    for lo, hi in BINS:
        hi_c = min(hi, max_len)
        if lo > hi_c:
            continue
        for _ in range(trials):
            valid = occlude(rng, n_t, ds["groups"], centres, lo, hi_c, n_events=6, pattern=pattern)
            x = np.where(valid[..., None], inp, np.nan)
            t0 = time.perf_counter()
            res = fill_gaps(x, valid, rate, clusters=ds["clusters"], max_gap_s=MAX_GAP_S)
            t_fill += time.perf_counter() - t0
            n_calls += 1
            changed += int(((res.xyz != x) & valid[..., None]).sum())
            forced = {m: fill_gaps(x, valid, rate, clusters=ds["clusters"], max_gap_s=MAX_GAP_S, methods=(m,))
                      for m in METHODS}
            t0 = time.perf_counter()
            kx = ktk_fill(x, rate)
            t_ktk += time.perf_counter() - t0
            for m, s, e in find_all(valid):
                sl = np.s_[s:e, m]
                chosen[(lo, hi)][1] += 1
                if (res.fill_code[sl] == FILL_CODES["unfilled"]).any():
                    continue            # left unfilled: the errors below are over the gaps it filled
                chosen[(lo, hi)][0] += 1
                err = {"choice": np.linalg.norm(res.xyz[sl] - truth[sl], axis=1)}
                for meth, r in forced.items():
                    cover[(lo, hi)][meth][1] += 1
                    if (r.fill_code[sl] == FILL_CODES["unfilled"]).any():
                        continue
                    cover[(lo, hi)][meth][0] += 1
                    err[meth] = np.linalg.norm(r.xyz[sl] - truth[sl], axis=1)
                    paired[(lo, hi)][meth][0] += err["choice"].sum()
                    paired[(lo, hi)][meth][1] += err[meth].sum()
                if kx is not None:
                    err["ktk"] = np.linalg.norm(kx[sl] - truth[sl], axis=1)
                meths = [k for k in METHODS if k in err]
                if meths:
                    err["hindsight"] = err[min(meths, key=lambda k: err[k].mean())]
                for k, v in err.items():
                    per_bin[(lo, hi)][k].append(v)
                    if (e - s) / rate > LONG_S:
                        long_gaps[k].append(v)
    return {"per_bin": per_bin, "cover": cover, "chosen": chosen, "paired": paired, "long": long_gaps,
            "changed": changed,
            "t_fill": t_fill / max(n_calls, 1), "t_ktk": t_ktk / max(n_calls, 1), "pattern": pattern}


def fmt(v: list[np.ndarray]) -> str:
    if not v:
        return "      —      "
    a = np.concatenate(v)
    a = a[np.isfinite(a)]
    return f"{a.mean():6.2f}/{np.percentile(a, 95):6.2f}"


def mean(v: list[np.ndarray]) -> float:
    return float(np.concatenate(v).mean()) if v else float("nan")


def merge(outs: list[dict]) -> dict:
    """Pool the runs of several seeds; ``per_seed`` keeps each run for the spread of the ratios."""
    first = outs[0]
    pooled = {
        "per_bin": {b: {c: [v for o in outs for v in o["per_bin"][b][c]] for c in first["per_bin"][b]}
                    for b in first["per_bin"]},
        "cover": {b: {c: [sum(o["cover"][b][c][i] for o in outs) for i in range(2)] for c in first["cover"][b]}
                  for b in first["cover"]},
        "chosen": {b: [sum(o["chosen"][b][i] for o in outs) for i in range(2)] for b in first["chosen"]},
        "paired": {b: {c: [sum(o["paired"][b][c][i] for o in outs) for i in range(2)] for c in first["paired"][b]}
                   for b in first["paired"]},
        "long": {c: [v for o in outs for v in o["long"][c]] for c in first["long"]},
        "changed": sum(o["changed"] for o in outs),
        "t_fill": float(np.mean([o["t_fill"] for o in outs])),
        "t_ktk": float(np.mean([o["t_ktk"] for o in outs])),
        "pattern": first["pattern"],
        "per_seed": outs,
    }
    return pooled


def spread(out: dict, key: tuple[int, int] | None, num: str, den: str) -> str:
    """``± std`` of the ratio mean(num) / mean(den) over the seeds' runs (empty with one seed)."""
    runs = out.get("per_seed", [])
    if len(runs) < 2:
        return ""
    r = []
    for o in runs:
        d = o["long"] if key is None else o["per_bin"][key]
        if d[num] and d[den]:
            r.append(mean(d[num]) / mean(d[den]))
    return f"±{np.std(r, ddof=1):.2f}" if len(r) >= 2 else ""


def report(ds: dict, out: dict, has_ktk: bool) -> None:
    n_seeds = len(out.get("per_seed", [])) or 1
    print(f"\n== {ds['name']}: {ds['note']}; {len(ds['clusters'])} rigid clusters; occlusion: {out['pattern']}; "
          f"{n_seeds} seed(s), ratios as pooled value ± std over seeds")
    cols = ["choice", "hindsight", *METHODS] + (["ktk"] if has_ktk else [])
    head = ("bin (frames)  n_gaps " + " ".join(f"{c:>13s}" for c in cols)
            + "  choice/hind        choice/ktk  worst choice/method")
    print("mean/p95 error (mm) of hidden samples; methods forced on every gap they can fill (coverage in %)")
    print(head)
    rows = [(f"{lo}-{hi}", out["per_bin"][(lo, hi)], (lo, hi)) for lo, hi in BINS]
    rows.append((f">{LONG_S:g} s", out["long"], None))
    for name, d, key in rows:
        if not d["choice"]:
            continue
        cells = " ".join(f"{fmt(d[c]):>13s}" for c in cols)
        r_h = mean(d["choice"]) / mean(d["hindsight"])
        r_k = mean(d["ktk"]) / mean(d["choice"]) if has_ktk and d["ktk"] else float("nan")
        s_h = spread(out, key, "choice", "hindsight")
        s_k = spread(out, key, "ktk", "choice") if has_ktk else ""
        worst = ""
        if key is not None:
            ratios = {m: p[0] / p[1] for m, p in out["paired"][key].items() if p[1] > 0}
            wm = max(ratios, key=ratios.get)
            worst = f"{ratios[wm]:.2f} ({wm})"
        print(f"{name:>12s} {len(d['choice']):7d} {cells}  {format(r_h, '.2f') + s_h:>11s}  "
              f"{('ktk ' + format(r_k, '.1f') + s_k + 'x lower'):>16s}  {worst}")
    cov = " ".join(f"{m} {100 * sum(out['cover'][b][m][0] for b in BINS) / max(1, sum(out['cover'][b][m][1] for b in BINS)):.0f}%"
                   for m in METHODS)
    ch = [sum(out["chosen"][b][i] for b in BINS) for i in range(2)]
    cov = f"choice {100 * ch[0] / max(1, ch[1]):.1f}% ({ch[1] - ch[0]} gaps left), " + cov
    print(f"coverage: {cov}; measured samples changed: {out['changed']}; "
          f"time per take: fill_gaps {out['t_fill'] * 1000:.0f} ms"
          + (f", kineticstoolkit cubic {out['t_ktk'] * 1000:.0f} ms" if has_ktk else ""))


# ---------------------------------------------------------------------------------------------- corpus
def _unlabeled(labels: list[str]) -> list[int]:
    """Unlabeled trajectories by the filler's rule when it has one (else Vicon ``*N`` and ``Unlabeled...``)."""
    try:
        from gazepipe.stages.clean.gapfill import unlabeled_markers
    except ImportError:
        return [i for i, lab in enumerate(labels) if lab.split(":")[-1].startswith("*")
                or lab.lower().startswith("unlabel")]
    return unlabeled_markers(labels)


def corpus_audit() -> None:
    """``gazepipe fill``'s rules on every real C3D of the corpus, as the files come (defaults)."""
    from gazepipe.io.capture import read_markers
    from gazepipe.stages.clean import standalone
    from gazepipe.stages.clean.spikes import find_spikes

    entries: list[dict] = []
    plain = standalone._gap_entry

    def entry(markers, g, at_edge):          # every gap's estimate, whatever the summary holds
        d = plain(markers, g, at_edge)
        entries.append({"filled": g.method != "unfilled", "estimate": float(g.error_mm), "frames": g.length})
        return d

    print("\n== gazepipe fill on every corpus C3D (defaults): gaps filled / total, filled gaps without an error "
          "estimate (samples), fastest filled step vs the file's fastest measured step (mm per frame; spikes left "
          "out, and all), unlabeled samples filled, unfilled gaps by reason")
    total = {"gaps": 0, "filled": 0, "noest": 0, "noest_samples": 0, "faster": 0, "unl": 0}
    standalone._gap_entry = entry
    try:
        for path in sorted(CORPUS.glob("*.c3d")):
            m = read_markers(path)
            entries.clear()
            t0 = time.perf_counter()
            filled, summary, _ = standalone.fill_capture(m)
            dt = time.perf_counter() - t0
            steps = np.linalg.norm(np.diff(filled.xyz, axis=0), axis=2)
            new = filled.valid & ~m.valid
            near = (new[1:] | new[:-1]) & filled.valid[1:] & filled.valid[:-1]
            measured = m.valid[1:] & m.valid[:-1]
            # the file's fastest measured step, spikes (as the filler finds them) left out
            clean = m.valid & ~find_spikes(m.xyz, m.valid, m.rate_hz, find_rigid_clusters(m.xyz, m.valid))
            both = clean[1:] & clean[:-1]
            raw = np.linalg.norm(np.diff(np.where(m.valid[..., None], m.xyz, 0.0), axis=0), axis=2)
            fast_all = float(raw[measured].max()) if measured.any() else 0.0
            fast = float(raw[both].max()) if both.any() else 0.0
            top = float(steps[near].max()) if near.any() else 0.0
            noest = [e for e in entries if e["filled"] and not np.isfinite(e["estimate"])]
            unl = _unlabeled(list(m.labels))
            n_unl = int(new[:, unl].sum()) if unl else 0
            g = summary["gaps"]
            faster = int((steps[near] > fast).sum())
            print(f"{path.stem:34s} gaps {g['filled']:4d}/{g['total']:4d} ({int(new.sum())} samples); no estimate "
                  f"{len(noest):3d} ({sum(e['frames'] for e in noest)}); fastest filled {top:6.1f} vs measured "
                  f"{fast:6.1f} / {fast_all:7.1f}, {faster} filled steps faster; unlabeled filled {n_unl} of "
                  f"{len(unl)} trajectories' gaps; {dt:.1f} s")
            for reason, n in sorted(summary["unfilled_reasons"].items()):
                print(f"{'':36s}left: {n:4d} {reason}")
            total["gaps"] += g["total"]
            total["filled"] += g["filled"]
            total["noest"] += len(noest)
            total["noest_samples"] += sum(e["frames"] for e in noest)
            total["faster"] += faster
            total["unl"] += n_unl
    finally:
        standalone._gap_entry = plain
    print(f"all files: {total['filled']} of {total['gaps']} gaps filled; {total['noest']} filled without an error "
          f"estimate ({total['noest_samples']} samples); {total['faster']} filled steps faster than their file's "
          f"fastest measured step; {total['unl']} unlabeled samples filled")


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--trials", type=int, default=5, help="occlusion patterns per bin, take and seed")
    ap.add_argument("--seeds", type=int, default=3, help="seeds (the ratios' spread is their std over seeds)")
    ap.add_argument("--seed", type=int, default=0, help="first seed")
    ap.add_argument("--data", choices=("all", "session", "real", "corpus"), default="all")
    ap.add_argument("--takes", type=int, default=4, help="sample-session takes to use (0: all)")
    ap.add_argument("--pattern", choices=("random", "neighbours"), default="random",
                    help="which markers are hidden together with the first one of an occlusion")
    args = ap.parse_args(argv)
    try:
        import kineticstoolkit  # noqa: F401

        has_ktk = True
    except ImportError:
        has_ktk = False
        print("kineticstoolkit not installed: its column is skipped")
    if args.data in ("all", "corpus"):
        corpus_audit()
        if args.data == "corpus":
            return 0
    datasets = session_datasets(args.takes) if args.data in ("all", "session") else []
    for name in ("Walking_Hybrid_2", "ART-Human_2persons_integer") if args.data in ("all", "real") else ():
        ds = real_dataset(name)
        if ds is not None:
            datasets.append(ds)
    for i, ds in enumerate(datasets):
        t0 = time.perf_counter()
        out = merge([run(ds, args.trials, 1000 * k + args.seed + i, args.pattern) for k in range(args.seeds)])
        report(ds, out, has_ktk)
        print(f"({time.perf_counter() - t0:.0f} s)")
        sys.stdout.flush()
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
