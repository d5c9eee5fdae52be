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
        out.append(f"| `{col}` | {len(names)} | {units.get(col, '')} | {first} |")
    masks = info.get("masks", {}) or {}
    for col, names in (masks.items() if isinstance(masks, dict) else []):
        first = ", ".join(names[:4]) + (", …" if len(names) > 4 else "")
        out.append(f"| `{col}` (bool) | {len(names)} | {units.get(col, '')} | {first} |")
    ids = info.get("identifiers", [])
    if ids:
        out += ["", "Identifier columns: " + ", ".join(f"`{c}`" for c in ids)
                + (f"; `time_s` in {units['time_s']}" if "time_s" in units else "") + "."]
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
