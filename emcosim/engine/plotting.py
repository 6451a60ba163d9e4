"""Figures as data, then drawn: a `FigureSpec` lists its panels and, in each, the plotted series in
the units shown on the axis; `draw` renders a spec with matplotlib, `save` writes PNG/SVG.

Keeping the plotted numbers and labels in a spec lets tests open exactly what a figure shows. The
engine's own figure (`variables_figure`, used by the command line's plots of any scenario) knows no
physics: one axis per recorded variable, labelled with the unit and description of the FMU's
modelDescription, scaled to an SI prefix (m -> um, s -> ms) where that reads better.
Colours: the Okabe-Ito palette (distinguishable with the common colour-vision deficiencies), with
a different line style per series so that figures also read in grey print.
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np

OKABE_ITO = ["#0072B2", "#E69F00", "#009E73", "#CC79A7", "#56B4E9", "#D55E00", "#F0E442", "#000000"]
# the palette without its colours of low contrast on white (sky blue 1.9:1, yellow 1.2:1): for lines drawn alone
CONTRAST = ["#0072B2", "#D55E00", "#009E73", "#CC79A7", "#E69F00", "#000000"]
LINE_STYLES = ["-", "--", "-.", ":"]

PREFIXES = {-12: "p", -9: "n", -6: "µ", -3: "m", 0: "", 3: "k", 6: "M", 9: "G"}
PREFIXABLE = {"m", "s", "V", "A", "C", "Wb", "J", "N", "W", "Ohm", "N s", "H", "F"}
SAME_UNIT = {"kg m/s": "N s", "kg.m/s": "N s", "kg*m/s": "N s"}      # equal units, the second takes a prefix


@dataclass
class Series:
    """One line: y over x, both in the units of the panel's labels."""

    label: str
    x: np.ndarray
    y: np.ndarray
    color: str | None = None
    style: str | tuple = "-"                   # a matplotlib line style
    width: float = 1.3
    zorder: float = 2.0


@dataclass
class Panel:
    ylabel: str
    series: list[Series]
    title: str = ""
    xlabel: str = ""
    yscale: str = "linear"


@dataclass
class FigureSpec:
    """A figure: panels in `columns` columns (rows filled first), the x label of the bottom row,
    and where the legend goes: 'right' (beside each panel) or 'below' (one legend under all)."""

    title: str
    panels: list[Panel]
    xlabel: str
    columns: int = 1
    legend: str = "right"
    note: str = ""                              # a line under the title (e.g. how a norm is scaled)
    size: tuple[float, float] | None = None
    mark: str = ""                              # why the result shown is partial or not accepted: red, under the axes

    def panel(self, ylabel_start: str) -> Panel:
        """The panel whose y label starts with `ylabel_start` (for tests and readers)."""
        return next(p for p in self.panels if p.ylabel.startswith(ylabel_start))


def scale_unit(values, unit: str | None) -> tuple[float, str]:
    """(factor, unit label) that show `values` (in `unit`) with an SI prefix putting the largest
    magnitude in [1, 1000): e.g. 3e-5 m -> (1e6, 'µm'). Units that take no prefix keep factor 1."""
    unit = SAME_UNIT.get(unit or "", unit or "")
    finite = np.abs(np.asarray(values, dtype=float))
    finite = finite[np.isfinite(finite)]
    if unit not in PREFIXABLE or finite.size == 0 or finite.max() == 0:
        return 1.0, unit
    exponent = 3 * math.floor(math.log10(finite.max()) / 3)
    exponent = min(max(exponent, min(PREFIXES)), max(PREFIXES))
    if unit == "s" and exponent > 0:                                # no kiloseconds
        exponent = 0
    return 10.0 ** -exponent, f"{PREFIXES[exponent]}{unit}"


def label(name: str, unit: str) -> str:
    return f"{name} [{unit}]" if unit and unit != "1" else name


def draw(spec: FigureSpec):
    """A matplotlib Figure of the spec (constrained layout; legends outside the axes)."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    rows = math.ceil(len(spec.panels) / spec.columns)
    size = spec.size or (7.5 + (2.5 if spec.legend == "right" else 0.0) * (spec.columns == 1) + 3.5 * (spec.columns - 1),
                         1.9 * rows + 1.4)
    fig, axes = plt.subplots(rows, spec.columns, sharex=True, figsize=size, squeeze=False, layout="constrained")
    for ax in axes.ravel()[len(spec.panels):]:
        ax.set_visible(False)
    for k, (ax, panel) in enumerate(zip(axes.ravel(), spec.panels)):
        for s in panel.series:
            ax.plot(s.x, s.y, linestyle=s.style, color=s.color, lw=s.width, label=s.label, zorder=s.zorder)
        ax.set_yscale(panel.yscale)
        if panel.yscale == "linear":             # no "+1.03" offset text above the axis: the ticks say the values
            ax.ticklabel_format(axis="y", useOffset=False)
        ax.set_ylabel(panel.ylabel)
        if panel.title:
            ax.set_title(panel.title, fontsize=10)
        ax.grid(alpha=0.3, which="both" if panel.yscale == "log" else "major")
        if k + spec.columns >= len(spec.panels):
            ax.set_xlabel(panel.xlabel or spec.xlabel)
            ax.xaxis.set_tick_params(labelbottom=True)
        if spec.legend == "right" and panel.series:
            ax.legend(loc="upper left", bbox_to_anchor=(1.01, 1.0), fontsize=8, frameon=False)
    if spec.legend == "below":
        handles, labels = {}, []
        for ax in axes.ravel():
            for h, text in zip(*ax.get_legend_handles_labels()):
                if text not in handles:
                    handles[text] = h
                    labels.append(text)
        width_pt = fig.get_figwidth() * 72 - 40
        per_entry = 5.0 * max(len(t) for t in labels) + 45                # 9 pt text, line sample and gap
        ncol = max(1, min(len(labels), 4, int(width_pt // per_entry)))
        fig.legend([handles[t] for t in labels], labels, loc="outside lower center", ncol=ncol, fontsize=9,
                   frameon=False)
    title = spec.title + (f"\n{spec.note}" if spec.note else "")
    if title:
        fig.suptitle(title, fontsize=11)
    if spec.mark:
        mark(fig, spec.mark)
    return fig


def mark(fig, text: str) -> None:
    """A red line under the figure's axes (room made for it): how far the run got (where the text says), then
    the text (why the result is partial or not accepted), cut to one line."""
    import re

    height = fig.get_figheight()
    engine = fig.get_layout_engine()
    if engine is not None and hasattr(engine, "set"):
        engine.set(rect=(0, 0.3 / height, 1, 1 - 0.3 / height))       # 0.3 inch below the axes
    upto = re.search(r"\d+ rows up to t = \S+ s", text)
    line = (f"PARTIAL: {upto.group(0)}. " if upto else "") + " ".join(text.split())
    line = line if len(line) <= 160 else line[:157] + "..."
    fig.text(0.005, 0.08 / height, line, color="red", fontsize=7, ha="left", va="bottom")


def save(fig, path: str | Path, formats: tuple[str, ...] | None = None, dpi: int = 110) -> list[Path]:
    """Write `fig` to `path` (its suffix gives the format), or to path.<ext> for each of `formats`;
    close it and return the files written."""
    import matplotlib.pyplot as plt

    path = Path(path)
    paths = [path] if formats is None else [path.with_suffix(f".{ext}") for ext in formats]
    for p in paths:
        fig.savefig(p, dpi=dpi)
    plt.close(fig)
    return paths


# ---- the engine's figure of a run: recorded variables with their units -------------------------------

@dataclass
class VariableInfo:
    unit: str = ""
    description: str = ""


def variable_info(scenario) -> dict[str, VariableInfo]:
    """Unit and description of every variable of the scenario's FMUs, by full name, from each
    FMU's modelDescription."""
    from .binding import load

    info = {}
    for name, inst in load(scenario).items():
        for v in inst.model_description.modelVariables:
            unit = v.unit or (v.declaredType.unit if v.declaredType is not None else None) or ""
            info[f"{name}.{v.name}"] = VariableInfo(unit, v.description or "")
    return info


def variables_figure(result, info: dict[str, VariableInfo], title: str = "",
                     columns: list[str] | None = None) -> FigureSpec:
    """One panel per recorded variable (or per name in `columns`), in its unit with an SI prefix."""
    t = result.time
    t_factor, t_unit = scale_unit(t, "s")
    panels = []
    for i, name in enumerate(columns or result.columns):
        y = result[name]
        meta = info.get(name, VariableInfo())
        factor, unit = scale_unit(y, meta.unit)
        panels.append(Panel(label(name, unit), [Series(name, t * t_factor, y * factor, CONTRAST[i % len(CONTRAST)])],
                            title=meta.description))
    return FigureSpec(title, panels, label("time t", t_unit), legend="none")
