"""Shards of a batch: which cases shard ``I/N`` runs, and the per-shard summary files.

Shard ``I/N`` (1-based ``I``) runs the cases whose position in the case list sorted by folder
name (code-point order) is congruent to ``I-1`` modulo ``N``: the split depends only on the
folder names, never on the machine, the paths or the order the shell lists them. Each shard
writes ``OUT/summary.shard-I-of-N.json`` (``I`` zero-padded to the width of ``N``): the
document of ``summary.json`` for its cases, plus ``shard`` and ``study_cases`` (the folder names
of the whole study, sorted), from which ``batch --merge`` builds the study summary.
"""

from __future__ import annotations

import json
import math
import re
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from ..io.names import is_path_component

__all__: list[str] = []

#: ``format`` of summary.json and of the shard summaries.
SUMMARY_FORMAT = "biplanar-reg/batch-summary@1"
#: Largest shard count accepted.
MAX_SHARDS = 1_000_000
SHARD_GLOB = "summary.shard-*-of-*.json"
_SHARD_FILE = re.compile(r"^summary\.shard-(\d+)-of-(\d+)\.json$")


def parse_shard(value: str | Sequence[int] | None) -> tuple[int, int] | None:
    """``"I/N"`` or ``(I, N)`` as ``(I, N)`` with ``1 <= I <= N``; ``None`` stays ``None``."""
    if value is None:
        return None
    if isinstance(value, str):
        m = re.fullmatch(r"\s*(\d{1,7})\s*/\s*(\d{1,7})\s*", value)
        parts = (int(m.group(1)), int(m.group(2))) if m else None
    else:
        parts = tuple(value) if len(value) == 2 else None
    if (
        parts is None
        or not all(isinstance(p, int) and not isinstance(p, bool) for p in parts)
        or not 1 <= parts[0] <= parts[1] <= MAX_SHARDS
    ):
        raise ValueError(
            f"--shard: expected I/N with 1 <= I <= N <= {MAX_SHARDS} (e.g. 3/100), got {value!r}"
        )
    return parts[0], parts[1]


def shard_names(names: Sequence[str], shard: tuple[int, int] | None) -> list[str]:
    """The names shard ``(I, N)`` runs: positions ``I-1, I-1+N, ...`` of ``sorted(names)``."""
    ordered = sorted(names)
    if shard is None:
        return ordered
    i, n = shard
    return ordered[i - 1 :: n]


def shard_file(out: Path, shard: tuple[int, int]) -> Path:
    """``OUT/summary.shard-I-of-N.json``."""
    i, n = shard
    return out / f"summary.shard-{i:0{len(str(n))}d}-of-{n}.json"


def check_split(out: Path, shard: tuple[int, int]) -> None:
    """Refuse to run shard ``I/N`` into ``out`` when ``out`` holds the summaries of a split into
    another number of shards: the two splits would share cases and never merge (a job array
    resubmitted with ``--shard $SLURM_ARRAY_TASK_ID/$SLURM_ARRAY_TASK_COUNT``, whose count is
    the size of the new array).

    Raises
    ------
    ValueError
        One line naming the other split and what to do.
    """
    i, n = shard
    counts = sorted(
        {int(m.group(2)) for p in out.glob(SHARD_GLOB) if (m := _SHARD_FILE.match(p.name))} - {n}
    )
    if counts:
        k = counts[0]
        raise ValueError(
            f"--shard {i}/{n}: {out} holds the summaries of a split into {k} shards "
            f"(summary.shard-*-of-{k}.json); give the same count as the other shards (e.g. "
            f"--shard {i}/{k}), or delete those summaries to split the study anew"
        )


def _number(x: object) -> bool:
    return isinstance(x, int | float) and not isinstance(x, bool) and math.isfinite(x)


def _load(path: Path) -> dict[str, Any]:
    try:
        doc = json.loads(path.read_text(encoding="utf-8"))
    except (OSError, UnicodeDecodeError, ValueError, RecursionError) as exc:
        raise ValueError(f"{path}: not a readable shard summary ({exc})") from None
    ok = (
        isinstance(doc, dict)
        and doc.get("format") == SUMMARY_FORMAT
        and isinstance(doc.get("shard"), dict)
        and isinstance(doc.get("study_cases"), list)
        and isinstance(doc.get("rows"), list)
        and all(_number(doc.get(k)) for k in ("started", "finished"))
        and all(isinstance(r, dict) and is_path_component(r.get("case")) for r in doc["rows"])
        and all(is_path_component(c) for c in doc["study_cases"])
    )
    m = _SHARD_FILE.match(path.name)
    if (
        not ok
        or not m
        or (doc["shard"].get("index"), doc["shard"].get("count"))
        != (
            int(m.group(1)),
            int(m.group(2)),
        )
    ):
        raise ValueError(
            f"{path}: not a shard summary of biplanar-reg batch (format {SUMMARY_FORMAT}, "
            "keys shard, study_cases, rows, matching the file name)"
        )
    return doc


def read_shard_summaries(out: Path) -> list[dict[str, Any]]:
    """The shard summaries in ``out``, checked to describe one study split one way.

    Raises
    ------
    ValueError
        None found, an unreadable one, or shards of different splits or case lists.
    """
    paths = sorted(p for p in out.glob(SHARD_GLOB) if _SHARD_FILE.match(p.name))
    if not paths:
        raise ValueError(
            f"--merge {out}: no shard summaries (summary.shard-I-of-N.json); run "
            "'biplanar-reg batch CASES... --out OUT --shard I/N' for each shard first"
        )
    docs = [_load(p) for p in paths]
    first = docs[0]
    for path, doc in zip(paths[1:], docs[1:], strict=True):
        if doc["shard"]["count"] != first["shard"]["count"]:
            raise ValueError(
                f"--merge {out}: shards of different splits ({paths[0].name}, {path.name}); "
                "delete the summaries of the old split"
            )
        if doc["study_cases"] != first["study_cases"]:
            raise ValueError(
                f"--merge {out}: {paths[0].name} and {path.name} were run on different case "
                "lists; rerun the shards with the same CASES"
            )
    return docs
