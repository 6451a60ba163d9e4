"""Recorded values of a run: one row per communication point, one column per full variable name."""
from __future__ import annotations

import csv
from pathlib import Path

import numpy as np


class Result:
    """Rows of (time, values...) with column names "component.variable"."""

    def __init__(self, columns: list[str]):
        self.columns = list(columns)
        self.rows: list[list[float]] = []
        self.warnings: list[str] = []          # the FMUs' warnings at initialization ("component: message")

    def append(self, t: float, values: list) -> None:
        self.rows.append([t, *values])

    def __len__(self) -> int:
        return len(self.rows)

    @property
    def time(self) -> np.ndarray:
        return np.array([r[0] for r in self.rows])

    def __getitem__(self, name: str) -> np.ndarray:
        if name == "time":
            return self.time
        try:
            i = self.columns.index(name) + 1
        except ValueError:
            raise KeyError(f"no recorded variable '{name}' (recorded: {', '.join(self.columns)})") from None
        return np.array([r[i] for r in self.rows], dtype=float)

    def write_csv(self, path: str | Path) -> None:
        write_csv(path, ["time", *self.columns], self.rows)


def write_csv(path: str | Path, header: list[str], rows) -> None:
    with open(path, "w", newline="") as f:
        w = csv.writer(f)
        w.writerow(header)
        w.writerows([[repr(float(v)) for v in row] for row in rows])


def read_csv(path: str | Path) -> dict[str, np.ndarray]:
    """Columns of a results file by name (the master's, fmpy's or libcosim's CSV)."""
    with open(path, newline="") as f:
        reader = csv.reader(f)
        header = [h.strip().strip('"') for h in next(reader)]
        data = np.array([[float(v) for v in row] for row in reader if row], dtype=float)
    data = data.reshape(-1, len(header))
    return {name: data[:, i] for i, name in enumerate(header)}

