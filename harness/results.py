"""The tidy results table of DESIGN §6 and the run manifest, written atomically."""
from __future__ import annotations

import json
import math
import pathlib

import pandas as pd

from iblbench.scenes.atomic import atomic_path
from iblbench.scenes.errors import InputError

KEY_COLUMNS = ["scene", "estimator", "spp", "frame", "seed"]
METRIC_COLUMNS = [
    "mean_delta_e76", "mean_delta_e2000", "rel_mse", "flip",
    "used_samples", "effective_samples", "effective_ratio", "evaluations", "nonfinite",
    "time_ms_build", "time_ms_sample", "time_ms_shade", "time_ms_frame",
]
COLUMNS = KEY_COLUMNS + ["estimator_version"] + METRIC_COLUMNS + ["device", "protocol"]


def results_frame(rows: list[dict]) -> pd.DataFrame:
    frame = pd.DataFrame(rows, columns=COLUMNS)
    return frame.astype({"spp": "int64", "frame": "int64", "seed": "int64", "nonfinite": "int64"})


def read_results(out_dir: pathlib.Path) -> list[dict]:
    """The rows of an earlier run in ``out_dir`` (none if it has no results table)."""
    path = out_dir / "results.parquet"
    if not path.exists():
        return []
    try:
        return pd.read_parquet(path).to_dict("records")
    except Exception as error:   # pyarrow raises several types for damaged files
        raise InputError(path, f"cannot read the existing results table ({error}); "
                               "use a new --out") from None


def cell_key(row: dict) -> tuple:
    return tuple(row[column] for column in KEY_COLUMNS)


def write_results(out_dir: pathlib.Path, rows: list[dict]) -> pd.DataFrame:
    """(Re)write ``results.parquet`` and ``results.csv``; each file is replaced in one step."""
    frame = results_frame(rows)
    with atomic_path(out_dir / "results.parquet") as tmp:
        frame.to_parquet(tmp, index=False)
    with atomic_path(out_dir / "results.csv") as tmp:
        frame.to_csv(tmp, index=False)
    return frame


def _json_safe(value):
    if isinstance(value, float) and not math.isfinite(value):
        return None
    if isinstance(value, dict):
        return {str(k): _json_safe(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [_json_safe(v) for v in value]
    return value


def write_manifest(out_dir: pathlib.Path, manifest: dict) -> None:
    with atomic_path(out_dir / "manifest.json") as tmp:
        tmp.write_text(json.dumps(_json_safe(manifest), indent=2, default=str))
