"""Recorded values of a run: `Result` holds the rows of a run, one row per communication point, one column per
full variable name. By default every row stays in memory (the Python API: `simulate` returns them). With a
`sink` (an outputs.ResultFile), each row goes to the file as it is produced and the Result keeps only the
last row in memory, so a run of any length needs a bounded amount of memory; read the rows back with
`read_csv`. How files reach the disk without ever losing or faking a result: outputs.py.
"""
from __future__ import annotations

import csv
import math
from pathlib import Path
from typing import Any

import numpy as np

from . import stopping
from .errors import ScenarioError
from .outputs import PARTIAL_MARK, ResultFile, read_sidecar, write_csv


class Result:
    """Rows of (time, values...) with column names "component.variable".

    Without a sink every row is kept in memory (`rows`). With a sink (`ResultFile`), every row is
    written to it and only the last row is kept (`last`); `time` and `result[name]` then refuse,
    naming the file to read instead."""

    def __init__(self, columns: list[str], sink: "ResultFile | None" = None, notes: list[str] | None = None):
        self.columns = list(columns)
        self.rows: list[list[float]] = []
        # what the results must say beside their rows (binding.model_differences): comment lines at the top of
        # the results file, and warnings
        self.notes: list[str] = list(notes or [])
        self.warnings: list[str] = list(self.notes)   # and the FMUs' warnings at initialization ("component: message")
        self.sink = sink
        self.last: list[float] | None = None   # the last row recorded
        self.n_rows = 0
        # what a run reports beside its rows (master.py, model_exchange.py): None where it does not apply
        self.coupling_orders: dict[str, int] = {}
        self.step_control: Any = None          # stepcontrol.StepReport of an error-controlled run
        self.implicit: Any = None              # implicit.Statistics of an implicitly coupled run
        self.model_exchange: Any = None        # model_exchange.Statistics of a Model Exchange run
        self.units: dict[str, str] = {}        # unit of each column ('' for none), where the caller knows them
        self.coupling_error: Any = None        # doubling.ErrorEstimate of a fixed-step Co-Simulation run
        self.nonfinite: tuple[float, str] | None = None   # the first value recorded that is not finite: (t, column)
        self.verdict: Any = None               # verdict.Verdict: whether the result is accepted (emcosim.run sets it)
        self.partial: str | None = None        # why the rows are partial (a result read back from a partial file)
        self.info: dict = {}                   # what the run's sidecar says beside the rows (scenario, options, ...)
        if sink is not None:
            sink.start(self.columns, self.notes)

    def append(self, t: float, values: list) -> None:
        stopping.check()                       # Ctrl-C / SIGTERM: stop here, between FMU calls
        row = [t, *values]
        if self.nonfinite is None and not math.isfinite(sum(row)):     # a NaN or inf makes the sum one
            self._note_nonfinite(row)
        if self.sink is not None:
            self.sink.write(row)
        else:
            self.rows.append(row)
        self.last = row
        self.n_rows += 1

    def _note_nonfinite(self, row: list) -> None:
        for name, v in zip(["time", *self.columns], row):
            if not math.isfinite(v):
                self.nonfinite = (row[0], name)
                return

    @property
    def accepted(self) -> bool | None:
        """Whether the result is accepted (engine/verdict.py), None where no verdict was made."""
        return None if self.verdict is None else self.verdict.accepted

    def __len__(self) -> int:
        return self.n_rows if self.sink is not None else len(self.rows)

    def _in_memory(self) -> list[list[float]]:
        if self.sink is not None:
            raise ScenarioError(f"the rows of this run were streamed to {self.sink.path}, not kept in memory; "
                                "read them with emcosim.engine.results.read_csv")
        return self.rows

    @property
    def time(self) -> np.ndarray:
        return np.array([r[0] for r in self._in_memory()])

    def __getitem__(self, name: str) -> np.ndarray:
        if name == "time":
            return self.time
        try:
            i = self.columns.index(name) + 1
        except ValueError:
            raise KeyError(f"no recorded variable '{name}' (recorded: {', '.join(self.columns)})") from None
        return np.array([r[i] for r in self._in_memory()], dtype=float)

    def to_pandas(self):
        """The rows as a pandas DataFrame: one column per recorded variable, indexed by time [s] (named
        "time"); the units by column name in `df.attrs["units"]` (as far as known: `emcosim.run` fills them in
        from the FMUs' modelDescriptions)."""
        import pandas as pd

        rows = np.array(self._in_memory(), dtype=float).reshape(-1, len(self.columns) + 1)
        frame = pd.DataFrame(rows[:, 1:], columns=self.columns, index=pd.Index(rows[:, 0], name="time"))
        frame.attrs["units"] = {"time": "s", **{n: self.units.get(n, "") for n in self.columns}}
        return frame

    def metadata(self) -> dict:
        """What the result says beside its rows (its sidecar's part of it: outputs.sidecar): units, notes,
        warnings, the estimate, the verdict and the run's statistics, as JSON values."""
        out: dict = {"units": {"time": "s", **{n: self.units.get(n, "") for n in self.columns}} if self.units else {},
                     "notes": list(self.notes), "warnings": list(self.warnings)}
        estimate = self.coupling_error
        if estimate is not None:
            out["coupling_error"] = {"summary": estimate.summary(), "available": estimate.available,
                                     "order": estimate.order, "steps": estimate.steps, "samples": estimate.samples,
                                     "relative": estimate.relative() if estimate.available else {},
                                     "absolute": dict(zip(estimate.columns, estimate.absolute))}
        if self.verdict is not None:
            out["verdict"] = self.verdict.to_json()
        for key in ("step_control", "implicit", "model_exchange"):
            stats = getattr(self, key)
            if stats is not None and hasattr(stats, "summary"):
                out[key] = stats.summary()
        return out

    @classmethod
    def from_csv(cls, path: str | Path) -> "Result":
        """The rows of a results file (see `read_csv`) back in memory, with what its sidecar says (`info`; the
        units, and `partial`: why the rows are partial, None for a complete file)."""
        data = read_csv(path)
        result = cls([name for name in data if name != "time"])
        result.info = read_sidecar(path) or {}
        result.units = dict(result.info.get("units") or {})
        result.partial = partial_note(path)
        columns = [data["time"]] + [data[name] for name in result.columns]
        for row in zip(*columns):
            result.append(float(row[0]), [float(v) for v in row[1:]])
        return result

    def write_csv(self, path: str | Path, why: str | None = None, meta: dict | None = None) -> None:
        """Write the rows in memory to `path` (atomically), header first, and its sidecar NAME.json: what the
        result says (`metadata`), `meta` and `why` the rows are partial (None: a complete result)."""
        write_csv(path, ["time", *self.columns], self._in_memory(), why, {**self.metadata(), **(meta or {})})


def read_csv(path: str | Path) -> dict[str, np.ndarray]:
    """Columns of a results file by name (the master's, fmpy's or libcosim's CSV); comment lines are skipped
    (the marker line of a killed run's file, or of a partial file that a full disk kept in place)."""
    with open(path, newline="") as f:
        reader = csv.reader(line for line in f if not line.startswith("#"))
        header = [h.strip().strip('"') for h in next(reader)]
        data = np.array([[float(v) for v in row] for row in reader if row], dtype=float)
    data = data.reshape(-1, len(header))
    return {name: data[:, i] for i, name in enumerate(header)}


def partial_note(path: str | Path) -> str | None:
    """Why a results file is partial (its sidecar's `why`, or the marker line of a file kept in place: a killed
    run's, or one a full disk left), or None for a complete one."""
    info = read_sidecar(path)
    if info is not None and info.get("partial"):
        of = f" of {info['of']}" if info.get("of") else ""
        rows, t = info.get("rows"), info.get("last_time")
        upto = f"; {rows} rows up to t = {t:.9g} s" if rows and isinstance(t, (int, float)) else ""
        return f"emcosim: PARTIAL result{of}: {info.get('why') or 'why not recorded'}{upto}"
    with open(path, newline="") as f:
        first = f.readline()
    return first[2:].strip() if first.startswith(PARTIAL_MARK) else None


__all__ = ["Result", "partial_note", "read_csv"]
