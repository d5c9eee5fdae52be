"""The dataset card of a built dataset: the YAML Hugging Face ``datasets`` reads, and a plain description.

``.huggingface.yaml`` holds the YAML alone: ``configs`` maps each split folder to a Hugging Face split
(``val`` loads as ``validation``; a split with no file is left out, as Hugging Face refuses an empty one) and
``dataset_info`` gives each split's row count and bytes plus a fingerprint of the files' contents. Hugging Face
caches a local folder by that YAML, so a rebuild with other contents must change it. ``_README.md`` is the card:
the same YAML as front matter, then the features with their units and frames, the counts per split and pose,
the inputs' hashes and the gazepipe version. (It is not named ``README.md``: pandas and pyarrow try to read
every file of a folder whose name starts with neither "_" nor "."; rename it when publishing the folder.)
"""

from __future__ import annotations

import json
import re
from typing import Any

#: the Hugging Face split each ``split`` value loads as
HF_SPLITS = {"train": "train", "val": "validation", "test": "test"}


def _q(text: str) -> str:
    """A YAML double-quoted scalar (JSON's string syntax is YAML's)."""
    return json.dumps(text, ensure_ascii=False)


def hf_yaml(name: str, splits: dict[str, tuple[int, int]], fingerprint: str) -> str:
    """The YAML of the card: ``configs`` (split folder → Hugging Face split) and ``dataset_info``.

    Parameters
    ----------
    name : the dataset's name.
    splits : per split value (train, val, test): (rows, bytes of its files); splits with no rows are left out.
    fingerprint : a hash of the take files' contents (Hugging Face's cache key follows the YAML).
    """
    present = [(s, rows, size) for s, (rows, size) in splits.items() if rows > 0]
    lines = ["configs:", "- config_name: default", "  data_files:"]
    for split, _, _ in present:
        lines += [f"  - split: {HF_SPLITS[split]}", f"    path: {_q(f'{split}/**/*.parquet')}"]
    lines += ["dataset_info:", f"  dataset_name: {_q(name)}",
              f"  description: {_q(f'gazepipe dataset {name}, contents {fingerprint[:16]}')}", "  splits:"]
    for split, rows, size in present:
        lines += [f"  - name: {HF_SPLITS[split]}", f"    num_examples: {rows}", f"    num_bytes: {size}"]
    lines.append(f"  download_size: {sum(size for _, _, size in present)}")
    return "\n".join(lines) + "\n"


_DERIVATIVE = re.compile(r"^(?P<base>.+)_d(?P<k>\d+)$")


def column_units(units: dict[str, Any], col: str) -> str:
    """The units of ``col``: its own entry, else for a derivative ``<base>_d<N>`` the ``<base>_dK`` entry with
    K = N (for blendshape values: per second of the value, ``1/s`` for the first derivative)."""
    if col in units:
        return str(units[col])
    m = _DERIVATIVE.match(col)
    if m is None or f"{m['base']}_dK" not in units:
        return ""
    k = int(m["k"])
    per = "1/s" if k == 1 else f"1/s^{k}"
    of = units.get(m["base"])
    return f"{per} ({'per second' if k == 1 else f'per second^{k}'} of the {of or m['base']} value)"


def _rate_line(info: dict[str, Any]) -> str:
    fps = info.get("fps")
    if fps:
        return f"Frame rate: {float(fps):.6g} Hz."
    rates = sorted({float(r) for r in info.get("rates_hz") or []})
    if not rates:
        return ""
    if len(rates) == 1:
        return f"Frame rate: {rates[0]:.6g} Hz."
    return (f"Frame rates: {', '.join(f'{r:.6g}' for r in rates)} Hz (per take; `dt_s`, where present, is each "
            "frame's step).")


def _mirror_line(info: dict[str, Any]) -> str:
    if not (info.get("params") or {}).get("mirror") or "mirrored" not in (info.get("identifiers") or []):
        return ""
    return ("Every row has a left-right mirrored copy: column `mirrored` is false for the captured row and true "
            "for its copy (filter on it for captured rows only).")


def card_text(info: dict[str, Any], yaml: str) -> str:
    """``_README.md``: ``yaml`` as front matter, then what the dataset holds, from its ``_dataset.json``."""
    name = info.get("name", "?")
    out = ["---", yaml.rstrip("\n"), "---", "", f"# {name}", "", str(info.get("description", "")).strip(), ""]
    out += ["## Loading", "", "```python",
            "import pandas as pd; df = pd.read_parquet(\"<this folder>\")          # every row; column `split`",
            "import datasets; dd = datasets.load_dataset(\"<this folder>\")       # train / validation / test",
            "import gazepipe.datasets as gd; ds = gd.open_dataset(\"<this folder>\")  # windows, statistics",
            "```", "",
            "Files: `<split>/<session>/<take>.parquet`, one per take; `_dataset.json` holds the feature names, "
            "the training statistics and everything below.", ""]
    units = info.get("units", {}) or {}
    feats = info.get("features", {}) or {}
    out += ["## Features", "", "| column | values | units and frame | first elements |", "|---|---|---|---|"]
    for col, names in (feats.items() if isinstance(feats, dict) else []):
        first = ", ".join(names[:4]) + (", …" if len(names) > 4 else "")
        out.append(f"| `{col}` | {len(names)} | {column_units(units, col)} | {first} |")
    masks = info.get("masks", {}) or {}
    for col, names in (masks.items() if isinstance(masks, dict) else []):
        first = ", ".join(names[:4]) + (", …" if len(names) > 4 else "")
        out.append(f"| `{col}` (bool) | {len(names)} | {column_units(units, col)} | {first} |")
    ids = info.get("identifiers", [])
    if ids:
        out += ["", "Identifier columns: " + ", ".join(f"`{c}`" for c in ids)
                + (f"; `time_s` in {units['time_s']}" if "time_s" in units else "") + "."]
    notes = [line for line in (_rate_line(info), _mirror_line(info)) if line]
    for line in notes:
        out += ["", line]
    counts = info.get("counts", {}) or {}
    out += ["", "## Counts", "", "| split | takes | rows |", "|---|---|---|"]
    for split, c in sorted((counts.get("by_split") or {}).items(), key=lambda kv: list(HF_SPLITS).index(kv[0])
                           if kv[0] in HF_SPLITS else 9):
        out.append(f"| {split} | {c.get('takes', 0)} | {c.get('rows', 0)} |")
    out += ["", "| pose | takes | rows |", "|---|---|---|"]
    for pose, c in sorted((counts.get("by_pose") or {}).items()):
        out.append(f"| {pose} | {c.get('takes', 0)} | {c.get('rows', 0)} |")
    for w in info.get("warnings", []) or []:
        out.append(f"\nWarning: {w}")
    out += ["", "## Inputs", "", "Content hashes (SHA-256) of each take's inputs, by the stage that wrote them:",
            "", "| take | inputs |", "|---|---|"]
    for take, hashes in sorted((info.get("inputs") or {}).items()):
        out.append(f"| {take} | " + ", ".join(f"{k} `{str(v)[:16]}`" for k, v in sorted(hashes.items())) + " |")
    out += ["", f"Built by gazepipe {info.get('version', '?')}, dataset schema version "
                f"{info.get('schema_version', '?')}.", ""]
    return "\n".join(out)
