"""The tidy results table of ARCHITECTURE.md §Results and units of work, its crash-safe journal, and the run manifest.

Columns, in order (``COLUMNS``):

- key: ``scene``, ``estimator`` (the label, with parameter overrides, e.g.
  ``balanced_mis{shared_sequence=false}``), ``spp``, ``frame``, ``seed``, ``time_budget_ms``
  (NaN for an equal-spp cell; for an equal-time cell the budget, and ``spp`` is the spp chosen
  to fit it);
- configuration: ``width``, ``height``, ``env_res`` (the effective image and cube face sizes),
  ``estimator_params`` (every parameter as sorted JSON), ``estimator_version`` (hash of the
  estimator's sources), ``schema_version`` (``SCHEMA_VERSION``), ``metrics`` (the metrics
  computed, e.g. ``de76,de2000,relmse,flip``; ``run --metrics``);
- metrics: each registered metric's column, in the registry's order (``mean_delta_e76``,
  ``mean_delta_e2000``, ``rel_mse``, ``flip``, ...: :mod:`iblbench.harness.protocol.metric`; NaN
  for a metric the run left out), then ``flicker`` … ``nonfinite`` (``ROW_STATISTICS``); ``shadow_rays``
  is the visibility queries per covered pixel (0 in a scene without visibility); ``flicker``
  is the mean over covered pixels of |ΔE76(est_t, ref_t) − ΔE76(est_p, ref_p)|,
  p the frame before t in the run's frame list, for the same (scene, estimator, spp, seed,
  time_budget_ms); NaN on the first frame of the list (and so for a static scene);
- replicates: ``mean_delta_e76_renders``, ``mean_delta_e2000_renders``, ``rel_mse_renders`` (the
  ``_renders`` column of each metric the registry marks replicated): the metric of each of the cell's planned timed renders, render 0 (the scored one) first, as text
  (:func:`iblbench.harness.protocol.stats.renders_text`; empty for a metric left out): the
  replicates a cell's interval is made of (:mod:`iblbench.harness.protocol.stats`);
- times (:mod:`iblbench.harness.protocol.timing`, the one definition): ``time_ms`` (the cell's device
  time per frame, build + sample + shade, median of ``time_repeats`` timed renders),
  ``time_ms_min``, ``time_ms_iqr``, the per-stage medians ``time_ms_build``, ``time_ms_sample``,
  ``time_ms_shade``, the host wall time ``time_ms_host``, ``time_repeats`` (at least the
  repeats asked for; more where the renders spread too wide) and ``time_ms_renders`` (each timed
  render's device time, as text);
- ``device`` (the OpenCL device that rendered the cell, whose times they are), ``host`` (the
  machine it is on: a cluster's workers may be several), ``protocol``;
- then any *extra* columns: estimator-specific per-frame scalars from ``Estimate.extras``
  (e.g. ``smc``'s ``ess``, ``reinits``, ``resample_steps``), sorted by name, NaN in the rows of
  estimators that do not report them.  They are not part of the cell key or of ``COLUMNS``
  (which stays fixed), and a row without them is still a finished cell.

Schema versions: 1 had no schema_version, time_budget_ms, width, height, env_res or
estimator_params column; 2 had no flicker column; 3 timed one render per cell (host wall time
``time_ms_frame``, device stages of that one render) and had no metrics column; 4 had no
shadow_rays column; 5 had no per-render columns (``*_renders``, ``time_ms_renders``); 6 had no
host column; 7 is this one.  Rows of another schema never count as finished cells.  The readers
(:func:`load_table`) fill an older table's missing columns where a value is sound
(``OLDER_ROWS_HOLD``); a column that has none (the times before schema 4) makes a reader that
needs it say which schema the table holds and how to upgrade it: a run into the folder renders
its sweep's cells again, saying so first, and keeps the old table beside the new one
(``backup_name``).

Storage.  ``results.parquet`` and ``results.csv`` are replaced whole, each in one rename, so a
reader never sees half a table.  While a run is going, each finished cell is appended to
``results.journal.jsonl`` (one JSON line, written to the OS before the next cell starts); the
journal is folded into the table every ``FOLD_SECONDS``, at the end of a run, and when a run
starts on a folder a killed run left behind.  A ``kill -9`` can cut only the line being written,
which :func:`read_results` ignores: the cell in flight is lost, nothing else.  A line that a
full disk took only part of is truncated away (:meth:`Journal.append`).  Every reader
(a resume, ``report``, ``check``, ``compare``: :func:`read_results`, :func:`load_table`) takes a
cell's row from the journal where the table has one too, so a forced rerun killed before its
fold reads as its new rows, never the old ones it replaces.  The journal is
fsynced when it closes, not per line (an fsync per cell was 5-13 ms of a cell's ~30 ms of host
time): a power cut, unlike a killed process, can lose the cells since the last fold (at most
``FOLD_SECONDS``), which a resume renders again.
"""
from __future__ import annotations

import errno
import json
import math
import os
import pathlib
import shutil
import sys

import numpy as np
import pandas as pd

from iblbench.harness.protocol.metric import columns as metric_columns, replicated_columns
from iblbench.harness.protocol.stats import RENDERS, TIME_COLUMNS
from iblbench.harness.protocol.timing import TIME
from iblbench.foundation.atomic import atomic_path
from iblbench.foundation.errors import InputError, argument, keywords_named

SCHEMA_VERSION = 7
KEY_COLUMNS = ["scene", "estimator", "spp", "frame", "seed", "time_budget_ms"]
CONFIG_COLUMNS = ["width", "height", "env_res", "estimator_params", "estimator_version",
                  "schema_version", "metrics"]
REPLICATED = replicated_columns()   # scored on every planned render
REPLICATE_COLUMNS = [column + RENDERS for column in REPLICATED]
# What a row holds besides its metrics: flicker (from the ΔE76 maps of consecutive frames) and
# what the estimate reports of its samples.
ROW_STATISTICS = ["flicker", "used_samples", "effective_samples", "effective_ratio", "evaluations",
                  "shadow_rays", "nonfinite"]
METRIC_COLUMNS = [*metric_columns(), *ROW_STATISTICS, *REPLICATE_COLUMNS, *TIME_COLUMNS]
COLUMNS = KEY_COLUMNS + CONFIG_COLUMNS + METRIC_COLUMNS + ["device", "host", "protocol"]
# Columns that are the same on every rerun of a cell on one device (renders are deterministic
# per seed): everything but the time columns, the measured times and how many renders they took
# (timing module).
DETERMINISTIC_COLUMNS = [c for c in COLUMNS if c not in TIME_COLUMNS]
TABLE = "results.parquet"
CSV = "results.csv"
JOURNAL = "results.journal.jsonl"
FOLD_SECONDS = 10.0
_INTS = ("spp", "frame", "seed", "nonfinite", "width", "height", "env_res", "schema_version",
         "time_repeats")


def prepare_out(out: pathlib.Path) -> None:
    """Create ``out`` (InputError when it cannot be, or is not writable)."""
    try:
        out.mkdir(parents=True, exist_ok=True)
    except OSError as error:
        raise InputError(out, f"cannot create the output directory ({error.strerror})") from None
    if not os.access(out, os.W_OK):
        raise InputError(out, "the output directory is not writable")


def extra_columns(rows: list[dict]) -> list[str]:
    """Columns of ``rows`` beyond the fixed ``COLUMNS`` (estimator extras), sorted."""
    fixed = set(COLUMNS)
    return sorted({name for row in rows for name in row if name not in fixed})


def results_frame(rows: list[dict]) -> pd.DataFrame:
    frame = pd.DataFrame(rows, columns=COLUMNS + extra_columns(rows))
    frame["schema_version"] = frame["schema_version"].fillna(1)   # rows from before the column
    frame["time_budget_ms"] = frame["time_budget_ms"].astype("float64")
    ints = {c: "int64" for c in _INTS if not frame[c].isna().any()}
    return frame.astype(ints)


# What a row of an older schema holds in a column a later schema added, where that is sound
# (module docstring, "Schema versions"): schema 1 had no equal-time cells and no version; a
# figure the run did not record is unknown (NaN); no per-render values (empty text) make a cell's
# interval one over its seeds (stats.cell_values); the host was not recorded.  Schema 4's times
# have no value here: schema 3 timed one render on the host (time_ms_frame).
OLDER_ROWS_HOLD = {"schema_version": 1, "time_budget_ms": math.nan, "flicker": math.nan,
                   "shadow_rays": math.nan, **{column: "" for column in REPLICATE_COLUMNS},
                   TIME + RENDERS: "", "host": ""}


def schema_versions(values) -> list[int]:
    """The schema versions of rows whose ``schema_version`` are ``values``, oldest first (a
    missing one, None or NaN: a row from before the column, schema 1)."""
    return sorted({1 if value is None or pd.isna(value) else int(value) for value in values})


def backup_name(version: int) -> str:
    """Where a run keeps a table of schema ``version`` before it writes its own rows."""
    return f"results.schema{version}.parquet"


def _upgraded(table: pd.DataFrame, path: pathlib.Path, required_columns) -> pd.DataFrame:
    """``table`` with the columns later schemas added filled as ``OLDER_ROWS_HOLD`` says; an
    InputError naming the table's schema and how to upgrade it where a column the reader needs
    has no sound value, or "not an iblbench results table" where even schema 1's key is
    missing."""
    table = table.assign(**{column: value for column, value in OLDER_ROWS_HOLD.items()
                            if column not in table.columns})
    missing = [column for column in required_columns if column not in table.columns]
    if not missing:
        return table
    versions = schema_versions(table["schema_version"])
    if not set(KEY_COLUMNS) <= set(table.columns) or versions[0] >= SCHEMA_VERSION:
        raise InputError(path, f"not an iblbench results table: missing columns {', '.join(missing)}")
    raise InputError(path, f"holds results of schema {versions[0]}, which lacks "
                           f"{', '.join(missing)} (this iblbench writes schema {SCHEMA_VERSION}); "
                           f"to upgrade it, run its sweep again with "
                           f"{argument('out', str(path.parent))}: the run "
                           f"re-renders the cells and keeps the old table as "
                           f"{backup_name(versions[0])}")


def budget_of(row: dict) -> float | None:
    """The row's time budget in ms, None for an equal-spp cell."""
    value = row.get("time_budget_ms")
    if value is None or (isinstance(value, float) and math.isnan(value)):
        return None
    return float(value)


def row_key(row: dict) -> tuple:
    """Identity of a cell: an equal-time cell is keyed by its budget, not the spp chosen for it."""
    budget = budget_of(row)
    spp = None if budget is not None else int(row["spp"])
    return (row["scene"], row["estimator"], spp, int(row["frame"]), int(row["seed"]), budget)


cell_key = row_key   # the name before issue 4


def image_stem(row: dict) -> str:
    """File stem of a cell's images under ``images/<scene>/f<frame>/``.

    ``{estimator}_spp{spp}_s{seed}``, the label made file-name safe (``{`` → ``-``, ``,`` →
    ``-``, ``}`` and quotes dropped) and ``_t{budget}ms`` before ``_spp`` for an equal-time cell.
    """
    label = str(row["estimator"])
    safe = label.replace("{", "-").replace(",", "-").replace("}", "").replace('"', "")
    budget = budget_of(row)
    timed = f"_t{budget:g}ms" if budget is not None else ""
    return f"{safe}{timed}_spp{int(row['spp'])}_s{int(row['seed'])}"


def _plain(value):
    if isinstance(value, np.generic):
        return value.item()
    return value


def load_table(run_dir: str | pathlib.Path, required_columns) -> pd.DataFrame:
    """The results of a run directory, for reading them (report, check, compare): its table with
    the journal's rows in place of the table's rows of the same cell, as :func:`read_results`
    (a run killed before its fold, a forced rerun's new rows among them); an
    :class:`InputError` naming the path if the table is missing, unreadable or lacks a column."""
    run_dir = pathlib.Path(run_dir)
    if not run_dir.is_dir():
        raise InputError(run_dir, "no such run directory")
    path = run_dir / TABLE
    if not path.is_file():
        make = "iblbench.run(out=...)" if keywords_named() else "'iblbench run --out DIR'"
        raise InputError(path, f"no results table; run {make} first")
    journal = read_journal(run_dir)   # before the table (read_results says why)
    try:
        table = pd.read_parquet(path)
    except Exception as error:   # pyarrow raises several types for damaged files
        raise InputError(path, f"cannot read the results table ({type(error).__name__})") from None
    table = _upgraded(table, path, required_columns)
    return results_frame(_newest_rows(table.to_dict("records"), journal)) if journal else table


def _read_table(out_dir: pathlib.Path) -> list[dict]:
    path = out_dir / TABLE
    if not path.exists():
        return []
    try:
        return pd.read_parquet(path).to_dict("records")
    except Exception as error:   # pyarrow raises several types for damaged files
        raise InputError(path, f"cannot read the existing results table ({error}); "
                               f"use a new {argument('out')}") from None


_TEXT_COLUMNS = ("scene", "estimator", "estimator_params", "estimator_version", "metrics",
                 "device", "host", "protocol", *REPLICATE_COLUMNS, TIME + RENDERS)


def _is_number(value) -> bool:
    return isinstance(value, (int, float)) and not isinstance(value, bool)


def journal_row_is_sound(row) -> bool:
    """A journal line's JSON is a row :func:`results_frame` can hold: an object with every key
    column, text where the table has text, numbers (or null) everywhere else."""
    if not isinstance(row, dict) or not all(column in row for column in KEY_COLUMNS):
        return False
    if not all(isinstance(row[c], int) and not isinstance(row[c], bool)
               for c in ("spp", "frame", "seed")):
        return False
    for column, value in row.items():
        if column in _TEXT_COLUMNS:
            if not isinstance(value, str):
                return False
        elif value is not None and not _is_number(value):
            return False
    return True


def read_journal(out_dir: pathlib.Path) -> list[dict]:
    """Rows appended by a run that has not folded them yet; a torn last line is dropped, and a
    line that is JSON but not a sound row (:func:`journal_row_is_sound`) is skipped and counted
    in a warning on stderr (its cell is run again).  A reader outside the run's lock may find the
    journal gone between a look and a read (a fold dropped it): that is no journal."""
    path = out_dir / JOURNAL
    try:
        lines = path.read_bytes().split(b"\n")
    except FileNotFoundError:
        return []
    rows, unsound = [], 0
    for number, line in enumerate(lines):
        if not line.strip():
            continue
        try:
            row = json.loads(line)
        except ValueError:
            if number == len(lines) - 1:   # the line being written when the run was killed
                break
            raise InputError(path, f"line {number + 1} is damaged; move the journal away to "
                                   "resume without its cells") from None
        if journal_row_is_sound(row):
            rows.append(row)
        else:
            unsound += 1
    if unsound:
        print(f"iblbench: warning: skipped {unsound} damaged line{'s' * (unsound > 1)} of {path} "
              "(their cells will be run again)", file=sys.stderr)
    return rows


def cell_files(out_dir: pathlib.Path, row: dict) -> list[pathlib.Path]:
    """The image files a finished cell leaves under ``images/<scene>/f<frame>/`` (its EXR; the
    PNG previews are ``iblbench report``'s)."""
    folder = out_dir / "images" / str(row["scene"]) / f"f{int(row['frame'])}"
    return [folder / f"{image_stem(row)}.exr"]


def cell_files_intact(out_dir: pathlib.Path, row: dict) -> bool:
    """Whether every image a finished cell left is there and reads whole: a damaged EXR makes
    the cell unfinished (a resume renders it again), where before it counted as done and the
    report then failed on it (issue 23)."""
    from iblbench.scenes.imageio import read_exr

    try:
        for path in cell_files(out_dir, row):
            read_exr(path)
    except InputError:
        return False
    return True


def remove_cells(out_dir: pathlib.Path, dropped: list[dict], kept: list[dict]) -> None:
    """The files of the ``dropped`` rows' cells: their images, each frame's reference that no
    ``kept`` row needs, and their scenes' saved inputs (``force`` with another image
    configuration: issue 23, they stayed behind their rows)."""
    for row in dropped:
        for path in cell_files(out_dir, row):
            path.unlink(missing_ok=True)
    frames = {(str(row["scene"]), int(row["frame"])) for row in dropped}
    for scene, frame in frames - {(str(row["scene"]), int(row["frame"])) for row in kept}:
        (out_dir / "images" / scene / f"f{frame}" / "reference.exr").unlink(missing_ok=True)
    for scene in {scene for scene, _ in frames}:
        shutil.rmtree(out_dir / "inputs" / scene, ignore_errors=True)


def image_configuration(row: dict) -> tuple[int, int, int] | None:
    """A row's (width, height, env_res); None for a row from before those columns."""
    values = tuple(row.get(column) for column in ("width", "height", "env_res"))
    return tuple(int(v) for v in values) if all(pd.notna(v) for v in values) else None


def configuration_differences(rows: list[dict], expected: dict[str, tuple[int, int, int]]) -> list[str]:
    """What differs between the rows' image configuration and ``expected`` (scene → (width,
    height, env_res)), one phrase per (scene, configuration) found, for scenes in ``expected``."""
    found = sorted({(row["scene"], image_configuration(row)) for row in rows
                    if row["scene"] in expected and image_configuration(row) is not None})
    differences = []
    for scene, (width, height, env_res) in found:
        new_width, new_height, new_env_res = expected[scene]
        parts = []
        if (width, height) != (new_width, new_height):
            parts.append(f"{argument('resolution', f'{width}x{height}')} "
                         f"(now {new_width}x{new_height})")
        if env_res != new_env_res:
            parts.append(f"{argument('env_res', env_res)} (now {new_env_res})")
        if parts:
            differences.append(f"{scene} was run with {' and '.join(parts)}")
    return differences


def read_results(out_dir: pathlib.Path) -> list[dict]:
    """Every row in ``out_dir``: the table, then the journal's rows (a journal row replaces the
    table's row of the same cell).  The journal is read first: a reader outside a run's lock
    that a fold overtakes between the two reads then gets the new table, which holds the rows
    the journal had, instead of the old table without the journal (the old rows of a forced
    rerun's cells)."""
    journal = read_journal(out_dir)
    return _newest_rows(_read_table(out_dir), journal)


def _newest_rows(table_rows: list[dict], journal_rows: list[dict]) -> list[dict]:
    """One row per cell: the journal's where it has one (it is newer than the last fold)."""
    rows = {row_key(row): row for row in table_rows}
    rows.update((row_key(row), row) for row in journal_rows)
    return list(rows.values())


def write_table(frame: pd.DataFrame, *paths: pathlib.Path) -> None:
    """Write ``frame`` to each path, as Parquet or CSV by its suffix, each replaced in one
    fsynced step (a reader never sees half a table)."""
    for path in paths:
        with atomic_path(path) as tmp:
            if path.suffix == ".parquet":
                frame.to_parquet(tmp, index=False)
            else:
                frame.to_csv(tmp, index=False)
            _fsync(tmp)


def write_results(out_dir: pathlib.Path, rows: list[dict]) -> pd.DataFrame:
    """(Re)write ``results.parquet`` and ``results.csv``, then drop the journal, whose rows
    ``rows`` must include."""
    frame = results_frame(rows)
    write_table(frame, out_dir / TABLE, out_dir / CSV)
    journal = out_dir / JOURNAL
    if journal.exists():
        journal.unlink()
    _fsync_dir(out_dir)
    return frame


class Journal:
    """Append-only record of finished cells (``results.journal.jsonl``), fsynced on close
    (module docstring, "Storage")."""

    def __init__(self, out_dir: pathlib.Path):
        self.path = out_dir / JOURNAL
        self._fd: int | None = None

    def append(self, row: dict) -> None:
        """One line, whole or not at all: a full disk can take part of a line without an error,
        and the next line, glued to that part once space is freed, would be a damaged line
        mid-journal, which stops every reader."""
        if self._fd is None:
            self._fd = os.open(self.path, os.O_WRONLY | os.O_APPEND | os.O_CREAT, 0o666)
        line = (json.dumps({k: _plain(v) for k, v in row.items()}, allow_nan=True)
                + "\n").encode()
        end = os.lseek(self._fd, 0, os.SEEK_END)   # the run is the journal's one writer
        if os.write(self._fd, line) < len(line):
            os.ftruncate(self._fd, end)
            raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC), str(self.path))

    def close(self) -> None:
        # Forgotten before it is closed: a Ctrl-C right after close(2) must not leave a closed
        # descriptor for the fold that the Ctrl-C makes to close again.
        fd, self._fd = self._fd, None
        if fd is not None:
            try:
                os.fsync(fd)
            finally:
                os.close(fd)


def _fsync(path: pathlib.Path) -> None:
    fd = os.open(path, os.O_RDONLY)
    try:
        os.fsync(fd)
    finally:
        os.close(fd)


def _fsync_dir(path: pathlib.Path) -> None:
    try:
        _fsync(path)
    except OSError:   # some file systems cannot fsync a directory
        pass


def _json_safe(value):
    if isinstance(value, np.generic):
        value = value.item()
    if isinstance(value, float) and not math.isfinite(value):
        return None
    if isinstance(value, dict):
        return {str(k): _json_safe(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [_json_safe(v) for v in value]
    return value


def json_text(value) -> str:
    """The one way iblbench writes JSON (manifests, ``--json`` summaries): indented, NumPy
    scalars as Python numbers, NaN and infinities as null (strict JSON has no NaN)."""
    return json.dumps(_json_safe(value), indent=2, default=str, allow_nan=False)


def read_manifest(out_dir: pathlib.Path) -> dict:
    """The manifest of an earlier run in ``out_dir`` ({} if there is none).  One that cannot be
    read, is not JSON (truncated) or is not a JSON object is an InputError naming it: a run
    would otherwise replace it and lose the run history, and a check would pass on it (issue 23).
    Manifests are written atomically, so only damage from outside makes one."""
    path = pathlib.Path(out_dir) / "manifest.json"
    try:
        manifest = json.loads(path.read_text())
    except FileNotFoundError:
        return {}
    except OSError as error:
        raise InputError(path, f"cannot read the manifest ({error.strerror})") from None
    except ValueError as error:
        raise InputError(path, f"the manifest is not valid JSON ({error}); move it aside to start "
                               "a new run history here") from None
    if not isinstance(manifest, dict):
        raise InputError(path, f"the manifest is not a JSON object (it holds a "
                               f"{type(manifest).__name__}); move it aside to start a new run "
                               "history here")
    return manifest


def write_manifest(out_dir: pathlib.Path, manifest: dict) -> None:
    with atomic_path(out_dir / "manifest.json") as tmp:
        tmp.write_text(json_text(manifest))
