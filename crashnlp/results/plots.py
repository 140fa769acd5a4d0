"""Figures: responses over data, force against crush, residuals."""

from __future__ import annotations

import io
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

from crashnlp.base.outputs import OUTPUT, PANELS  # noqa: E402
from crashnlp.results.files import note_output  # noqa: E402

DPI = 110
Job = tuple[str, tuple]  # a figure: the name of a figure function of this module, its arguments


def draw(jobs: list[Job]) -> None:
    """Draw figure jobs, in plain data so that another process can draw them (crashnlp.results.drawing);
    each file is noted in the output folder it is drawn into (crashnlp.results.files.note_output)."""
    for name, args in jobs:
        note_output(args[0])
        FIGURES[name](*args)


def response_figure(
    path: Path,
    title: str,
    model: dict[str, tuple],
    data: dict[str, tuple] | None = None,
    bands: dict[str, tuple] | None = None,
    notes: dict[str, str] | None = None,
    limits: dict[str, tuple] | None = None,
    accel_filter: str | None = None,
) -> None:
    """A panel per output of PANELS, two a row: model curves (t, y SI) with the measured ones
    behind them, where given the model's 95 % band (t, low, high SI) shaded, a panel's note (its
    fit's RMSE and rating) above it, and the problem's bounds on it (low, high SI; None: open);
    the acceleration's axis names the CFC class it was read through, as the tables do. One
    legend names what every panel draws."""
    rows = -(-len(PANELS) // 2)
    fig, axes = plt.subplots(rows, 2, figsize=(10, 3.25 * rows), sharex=True)
    for ax in axes.flat[len(PANELS) :]:
        ax.set_visible(False)
    for ax, name in zip(axes.flat, PANELS):
        label, f = OUTPUT[name].label_through(accel_filter), OUTPUT[name].plot_factor
        if data and name in data:
            t, y = data[name]
            ax.plot(np.asarray(t) * 1e3, np.asarray(y) * f, color="0.6", lw=1.2, label="data")
        if bands and name in bands:
            t, low, high = bands[name]
            ax.fill_between(
                np.asarray(t) * 1e3, np.asarray(low) * f, np.asarray(high) * f, color="C0", alpha=0.2, lw=0, label="95 %"
            )
        if name in model:
            t, y = model[name]
            ax.plot(np.asarray(t) * 1e3, np.asarray(y) * f, color="C0", lw=1.6, label="model")
        for end in (limits or {}).get(name, ()):
            if end is not None:
                ax.axhline(end * f, color="C3", ls="--", lw=1.0, label="bound")
        ax.set_ylabel(label)
        ax.grid(alpha=0.3)
        if notes and name in notes:
            ax.set_title(notes[name], loc="right", fontsize=8, pad=2)
    for ax in axes.flat[len(PANELS) - 2 :]:
        ax.set_xlabel("time (ms)")
        ax.xaxis.set_tick_params(labelbottom=True)
    drawn = {label: handle for ax in axes.flat for handle, label in zip(*ax.get_legend_handles_labels())}
    axes[0, 0].legend(drawn.values(), drawn.keys(), loc="lower right")
    fig.suptitle(title)
    _layout(fig, wspace=0.28)
    _save(fig, path)


def force_crush_figure(
    path: Path,
    curves: dict[str, tuple],
    points: tuple | None = None,
    title: str = "",
    measured: dict[str, tuple] | None = None,
    band: tuple | None = None,
) -> None:
    """Force against crush: named curves (x m, F N), optional breakpoint markers, the first curve's
    95 % band (x, low, high) shaded, and behind them measured curves in grey."""
    fig, ax = plt.subplots(figsize=(6.5, 4.5))
    crush, force = OUTPUT["crush"].plot_factor, OUTPUT["contact_force"].plot_factor  # the front end's
    for i, (label, (x, f)) in enumerate((measured or {}).items()):
        ax.plot(np.asarray(x) * crush, np.asarray(f) * force, lw=1.0, color=f"{0.55 + 0.1 * i:.2f}", label=label)
    if band is not None:
        x, low, high = (np.asarray(v) for v in band)
        ax.fill_between(x * crush, low * force, high * force, color="C0", alpha=0.2, lw=0, label="95 %")
    for i, (label, (x, f)) in enumerate(curves.items()):
        style = "--" if label.startswith("unloading") else "-"
        ax.plot(np.asarray(x) * crush, np.asarray(f) * force, style, lw=1.6, color=f"C{i}", label=label)
    if points is not None:
        ax.plot(np.asarray(points[0]) * crush, np.asarray(points[1]) * force, "o", color="C0", ms=4)
    ax.set_xlabel(OUTPUT["crush"].label)
    ax.set_ylabel(f"force ({OUTPUT['contact_force'].plot_unit})")
    ax.grid(alpha=0.3)
    ax.legend(fontsize=8)
    ax.set_title(title)
    _layout(fig)
    _save(fig, path)


def residual_figure(path: Path, title: str, residuals: dict[str, tuple]) -> None:
    """Residual (model - data) per fitted channel, in report units."""
    names = [p for p in PANELS if p in residuals]
    fig, axes = plt.subplots(len(names), 1, figsize=(8, 1.9 * len(names) + 0.6), sharex=True, squeeze=False)
    for ax, name in zip(axes[:, 0], names):
        label, f = OUTPUT[name].label, OUTPUT[name].plot_factor
        t, r = residuals[name]
        ax.plot(np.asarray(t) * 1e3, np.asarray(r) * f, color="C3", lw=1.0)
        ax.axhline(0, color="0.5", lw=0.8)
        ax.set_ylabel(label.replace(" (", "\nresidual ("))
        ax.grid(alpha=0.3)
    axes[-1, 0].set_xlabel("time (ms)")
    fig.suptitle(title)
    _layout(fig)
    _save(fig, path)


def overlay_figure(path: Path, title: str, xlabel: str, ylabel: str, series: list[tuple], note: str = "") -> None:
    """Curves of several fits or predictions on one axis (crashnlp compare-results), each in its
    own colour with its band shaded in it and a legend naming it (and its band); every value
    already in the axes' units; `note` under the axes, where it says what the bands are. series:
    (label, x, y, the band's outline as a polygon (x, y) or None)."""
    fig, ax = plt.subplots(figsize=(8, 4.8))
    for i, (label, x, y, band) in enumerate(series):
        colour = f"C{i % 10}"
        if band is not None:
            ax.fill(*band, color=colour, alpha=0.18, lw=0)
        ax.plot(x, y, color=colour, lw=1.6, label=label)
    ax.set_xlabel(xlabel)
    ax.set_ylabel(ylabel)
    ax.ticklabel_format(useOffset=False)
    ax.grid(alpha=0.3)
    ax.legend(fontsize=8)
    ax.set_title(title)
    _layout(fig)
    if note:  # two lines of small type under the axis' label
        fig.text(0.01, 0.01, note, fontsize=7, color="0.35", va="bottom", wrap=True)
        fig.subplots_adjust(bottom=(MARGINS_IN["bottom"] + NOTE_IN) / fig.get_size_inches()[1])
    _save(fig, path)


FIGURES = {f.__name__: f for f in (response_figure, force_crush_figure, residual_figure)}


def xy_png(x: np.ndarray, series: dict[str, np.ndarray], xlabel: str, title: str = "", failed: np.ndarray | None = None) -> bytes:
    """One panel per series against a swept value, as PNG bytes: a study draws its figures in its
    workers, which may be on other machines, and writes them where its table is. `failed`: the
    swept values of the cases that failed, each a red x on every panel's x axis (the axis reaches
    them), counted in a legend on the first."""
    fig, axes = plt.subplots(len(series), 1, figsize=(6.5, 2.2 * len(series) + 0.5), sharex=True, squeeze=False)
    for ax, (label, y) in zip(axes[:, 0], series.items()):
        ax.plot(x, y, "o-", color="C0")
        if failed is not None and failed.size:
            _mark_failed(ax, failed)
        ax.set_ylabel(label, fontsize=8)
        ax.ticklabel_format(useOffset=False)  # no "1e-5+5.908e-1": the values as they are
        ax.grid(alpha=0.3)
    if failed is not None and failed.size:
        axes[0, 0].legend(loc="best", fontsize=8)
    axes[-1, 0].set_xlabel(xlabel)
    fig.suptitle(title)
    _layout(fig)
    return _png(fig)


def _mark_failed(ax, failed: np.ndarray) -> None:
    """A red x at each failed case's swept value, on the panel's x axis line (x in data, y in the
    axes' fraction: the x limits take it in, the y limits stay the solved cases', and it reads as
    no value)."""
    ax.plot(
        failed,
        np.zeros(failed.size),
        "x",
        color="red",
        markersize=10,
        markeredgewidth=2,
        transform=ax.get_xaxis_transform(),
        clip_on=False,
        label=f"failed: {failed.size}",
    )


def correlation_png(labels: list[str], matrix: np.ndarray, title: str) -> bytes:
    """The estimates' correlation matrix as a heatmap, -1 to 1 (a report's map), as PNG bytes."""
    n = len(labels)
    side = max(4.5, 0.42 * n + 3.0)
    fig, ax = plt.subplots(figsize=(side + 1.0, side))
    image = ax.imshow(np.asarray(matrix, dtype=float), cmap="RdBu_r", vmin=-1.0, vmax=1.0)
    ax.set_xticks(range(n), labels, rotation=90, fontsize=8)
    ax.set_yticks(range(n), labels, fontsize=8)
    for i, j in np.ndindex(n, n):
        value = matrix[i][j]
        if value is not None and np.isfinite(value) and n <= 16:
            ax.text(j, i, f"{value:.2f}", ha="center", va="center", fontsize=7, color="white" if abs(value) > 0.6 else "black")
    fig.colorbar(image, ax=ax, fraction=0.046, pad=0.04, label="correlation")
    ax.set_title(title)
    fig.tight_layout()
    return _png(fig)


def map_png(x: list[str], y: list[str], values: np.ndarray, labels: tuple[str, str, str], title: str) -> bytes:
    """A study's two-entry grid as a heatmap: `values` (len(y) x len(x), NaN where a case failed)
    over the swept values as written; labels: x axis, y axis, colour bar. PNG bytes."""
    fig, ax = plt.subplots(figsize=(6.5, 4.8))
    grid = np.ma.masked_invalid(np.asarray(values, dtype=float))
    image = ax.imshow(grid, cmap="viridis", origin="lower", aspect="auto")
    ax.set_xticks(range(len(x)), x)
    ax.set_yticks(range(len(y)), y)
    failed = np.ma.getmaskarray(grid)
    shade = (np.asarray(values, dtype=float) - np.nanmin(values)) / max(float(np.nanmax(values) - np.nanmin(values)), 1e-300)
    for i, j in np.ndindex(grid.shape):
        light = not failed[i, j] and shade[i, j] > 0.6  # viridis' yellow end: dark text reads
        text = "failed" if failed[i, j] else f"{grid[i, j]:.4g}"
        ax.text(j, i, text, ha="center", va="center", fontsize=8, color="black" if light else "white")
    ax.set_xlabel(labels[0])
    ax.set_ylabel(labels[1])
    fig.colorbar(image, ax=ax, label=labels[2])
    ax.set_title(title)
    fig.tight_layout()
    return _png(fig)


def _png(fig) -> bytes:
    """The figure as PNG bytes, closed."""
    buffer = io.BytesIO()
    fig.savefig(buffer, format="png", dpi=DPI)
    plt.close(fig)
    return buffer.getvalue()


NOTE_IN = 0.3  # a figure's note below its axes: two lines of 7 pt
MARGINS_IN = {"left": 0.95, "right": 0.2, "bottom": 0.6, "top": 0.5}  # room for tick and axis labels and a title


def _layout(fig, wspace: float = 0.2, hspace: float = 0.12) -> None:
    """Fixed margins in inches: tight_layout draws every figure twice to measure its labels,
    which doubles the time of writing it."""
    width, height = fig.get_size_inches()
    m = MARGINS_IN
    fig.subplots_adjust(
        left=m["left"] / width,
        right=1 - m["right"] / width,
        bottom=m["bottom"] / height,
        top=1 - m["top"] / height,
        wspace=wspace,
        hspace=hspace,
    )


def _save(fig, path: Path) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=DPI)
    plt.close(fig)
