"""Report figures as inline SVG strings (matplotlib, headless Agg backend).

Every figure function returns an SVG fragment ready to paste into an HTML5 page:
no XML declaration, no DOCTYPE, no namespace URLs (the HTML parser puts `<svg>` in
the SVG namespace by itself, and plain `href` replaces `xlink:href`), and every `id`
prefixed with the figure's own prefix so several figures can share one document.
Text stays text (`svg.fonttype = "none"`): small files, searchable, the browser's font.

Long signals are decimated to a min/max envelope (`envelope`) so a figure holds at
most a few thousand points per channel whatever the log length.
"""

from __future__ import annotations

import io
import itertools
import re
from typing import TYPE_CHECKING, Sequence

import matplotlib

matplotlib.use("Agg")  # before pyplot: no display, no GUI toolkit

import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

from bench.model.kinematics import FRAMES

if TYPE_CHECKING:   # for the type checker only: the rc keys matplotlib accepts
    from matplotlib.typing import RcKeyType

#: Points per channel a time-series figure keeps at most (min/max pairs).
MAX_POINTS = 2000
#: The largest magnitude a figure draws: matplotlib's axis arithmetic overflows near 1e308, so a figure
#: whose data reach beyond this is not drawn (`PlotError`; the report says so in its place).
MAX_MAGNITUDE = 1e100
AXIS_COLORS = ("#1f77b4", "#2ca02c", "#d62728")     # x / outer, y / middle, z / inner
OUTLIER_COLOR = "#d62728"
DWELL_SHADE, TURN_SHADE = "#cfe3f5", "#f8dfc4"

PLOT_RC: dict[RcKeyType, str | float | bool] = {
    "svg.fonttype": "none", "svg.hashsalt": "turntable-bench", "font.size": 8.0, "axes.titlesize": 9.0,
    "axes.grid": True, "grid.alpha": 0.3, "figure.dpi": 72.0}
NO_SVG_METADATA = {"Creator": None, "Date": None, "Format": None, "Type": None}
_counter = itertools.count(1)
_ID_REF = re.compile(r'(\bid="|href="#|url\(#)([^")]+)')


class PlotError(ValueError):
    """A figure cannot be drawn from these data; the message says why."""


def check_drawable(what: str, *arrays) -> None:
    """PlotError if a finite value in `arrays` is beyond +-`MAX_MAGNITUDE` (NaN and inf are left out of
    a plot anyway)."""
    for a in arrays:
        v = np.asarray(a, float)
        v = np.abs(v[np.isfinite(v)])
        if v.size and v.max() > MAX_MAGNITUDE:
            raise PlotError(f"{what} reach {v.max():.3g}, beyond the +-{MAX_MAGNITUDE:g} a figure can show")


def envelope(t: np.ndarray, y: np.ndarray, max_points: int = MAX_POINTS) -> tuple[np.ndarray, np.ndarray]:
    """(t, y) reduced to at most `max_points` points: each bucket's minimum and maximum, in time order.

    Unlike plain striding this keeps every spike visible. NaNs are skipped within a
    bucket (a bucket that is all NaN gives NaN, drawn as a gap).
    """
    t, y = np.asarray(t, float), np.asarray(y, float)
    n = len(y)
    if n <= max_points:
        return t, y
    buckets = max(1, max_points // 2)
    size = -(-n // buckets)
    pad = buckets * size - n
    yy = np.concatenate([y, np.full(pad, np.nan)]).reshape(buckets, size)
    lo = np.argmin(np.where(np.isnan(yy), np.inf, yy), axis=1)
    hi = np.argmax(np.where(np.isnan(yy), -np.inf, yy), axis=1)
    base = np.arange(buckets) * size
    idx = np.sort(np.stack([base + lo, base + hi], axis=1), axis=1).reshape(-1)
    idx = np.minimum(idx, n - 1)
    return t[idx], y[idx]


def to_svg(fig) -> str:
    """The figure as an inline SVG fragment (see the module docstring); closes the figure."""
    buf = io.StringIO()
    try:
        with plt.rc_context(PLOT_RC):  # the SVG options are read when saving
            fig.savefig(buf, format="svg", metadata=NO_SVG_METADATA)
    finally:
        plt.close(fig)
    return inline_svg(buf.getvalue(), f"fig{next(_counter)}-")


def inline_svg(text: str, prefix: str) -> str:
    """Standalone SVG text -> an HTML5 inline fragment with ids prefixed by `prefix`."""
    start = text.find("<svg")
    if start < 0:
        raise ValueError("not an SVG document")
    text = text[start:]
    ids = set(re.findall(r'\bid="([^"]+)"', text))
    text = _ID_REF.sub(lambda m: m.group(1) + (prefix + m.group(2) if m.group(2) in ids else m.group(2)), text)
    text = text.replace("xlink:href=", "href=")
    text = re.sub(r'\s+xmlns(:\w+)?="[^"]*"', "", text, count=0)
    # matplotlib's global `*{...}` rule would leak into the page: the properties inherit, so set them on the root.
    text = re.sub(r"\s*<defs>\s*<style[^>]*>\*\{([^}]*)\}</style>\s*</defs>", "", text, count=1)
    text = text.replace("<svg ", '<svg style="stroke-linejoin: round; stroke-linecap: butt" ', 1)
    return text


def new_figure(rows: int, cols: int, width_in: float, height_in: float, *, left_in: float = 0.8,
               right_in: float = 0.2, bottom_in: float = 0.5, top_in: float = 0.3, hgap_in: float = 0.3,
               wgap_in: float = 0.7, **kw):
    """Subplots with fixed margins in inches (no tight_layout: measuring every label costs a draw).

    Call inside `plt.rc_context(PLOT_RC)`: fonts and grids are taken when artists are made.
    """
    fig, axes = plt.subplots(rows, cols, figsize=(width_in, height_in), squeeze=False, **kw)
    axis_h = (height_in - bottom_in - top_in - hgap_in * (rows - 1)) / rows
    axis_w = (width_in - left_in - right_in - wgap_in * (cols - 1)) / cols
    fig.subplots_adjust(left=left_in / width_in, right=1 - right_in / width_in, bottom=bottom_in / height_in,
                        top=1 - top_in / height_in, hspace=hgap_in / axis_h, wspace=wgap_in / axis_w)
    return fig, axes


def _legend(ax) -> None:
    """Legend above the axes' top right corner, off the data."""
    ax.legend(loc="lower right", bbox_to_anchor=(1.0, 1.0), ncol=3, fontsize=7, borderaxespad=0.1, frameon=False)


#: A label's extent across its baseline, in font sizes, with the gap kept to its neighbour (DejaVu Sans'
#: ascent + descent is about 1.17 font sizes).
_LABEL_PITCH_EM = 1.3


def category_ticks(ax, labels: Sequence[str], fontsize: float = 8.0, min_fontsize: float = 5.5) -> None:
    """A tick at 0..n-1 per label, written upright; the font shrinks to the room each label has (down to
    `min_fontsize`), and past that every k-th label is written (every tick kept): 96 rotations at 8 pt overprinted.

    Call after the data are drawn (the room is the axis width over its x-range)."""
    fig = ax.figure
    x0, x1 = ax.get_xlim()
    width_pt = ax.get_position().width * fig.get_figwidth() * 72.0
    pitch_pt = width_pt / max(abs(x1 - x0), 1.0)       # one label's room, in points
    step = 1
    while pitch_pt * step / _LABEL_PITCH_EM < min_fontsize and step < len(labels):
        step += 1
    size = min(fontsize, pitch_pt * step / _LABEL_PITCH_EM)
    ax.set_xticks(np.arange(len(labels)), [label if i % step == 0 else "" for i, label in enumerate(labels)],
                  rotation=90, fontsize=size)
    ax.set_xlim(x0, x1)


def _shade(ax, spans: Sequence[tuple[float, float, str]]) -> None:
    for t0, t1, kind in spans:
        ax.axvspan(t0, t1, color=DWELL_SHADE if kind == "dwell" else TURN_SHADE, lw=0, zorder=0)


def residual_figure(positions: list[dict], rotations: list[dict], threshold: float) -> str | None:
    """Normalized residuals (residual / sigma) per position (acc, gyro) and per rotation, outliers in red."""
    panels = []
    if any(r.get("acc_normalized") for r in positions):
        panels.append(("positions: accelerometers", positions, "acc_normalized"))
    if any(r.get("gyro_normalized") for r in positions):
        panels.append(("positions: gyros (bias fit)", positions, "gyro_normalized"))
    if any(r.get("gyro_normalized") for r in rotations):
        panels.append(("rotations: gyros", rotations, "gyro_normalized"))
    if not panels:
        return None
    check_drawable("the normalized residuals",
                   *([np.nan if x is None else x for x in (r.get(key) or [])] for _, rows, key in panels for r in rows))
    with plt.rc_context(PLOT_RC):
        fig, axes = new_figure(len(panels), 1, 10.0, 2.6 * len(panels) + 0.3, hgap_in=0.95, bottom_in=0.65)
        for ax, (title, rows, key) in zip(axes[:, 0], panels):
            x = np.arange(len(rows))
            for k, (axis, color) in enumerate(zip("xyz", AXIS_COLORS)):
                v = np.array([np.nan if not r.get(key) or r[key][k] is None else r[key][k] for r in rows], float)
                ax.plot(x + (k - 1) * 0.2, v, "o", ms=3.5, color=color, label=axis)
                bad = np.abs(v) > threshold
                if bad.any():
                    ax.plot(x[bad] + (k - 1) * 0.2, v[bad], "o", ms=9, mfc="none", mec=OUTLIER_COLOR, mew=1.5)
            for s in (threshold, -threshold):
                ax.axhline(s, color=OUTLIER_COLOR, ls="--", lw=0.8)
            category_ticks(ax, [r.get("label", str(i)) for i, r in enumerate(rows)])
            ax.set_ylabel("residual / sigma")
            ax.set_title(f"{title} (dashed: outlier threshold +-{threshold:g} sigma)")
            _legend(ax)
    return to_svg(fig)


def step_means_figure(labels: list[str], acc_mean: np.ndarray, acc_std: np.ndarray,
                      gyro_mean: np.ndarray, gyro_std: np.ndarray) -> str:
    """Each dwell's mean output per axis (counts/s) with +-1 std of its samples: accelerometers, gyros."""
    check_drawable("the dwell means", acc_mean, acc_std, gyro_mean, gyro_std)
    with plt.rc_context(PLOT_RC):
        # One panel per sensor, the three axes side by side: every axis shares its sensor's range,
        # and ticks are what drawing costs.
        fig, axes = new_figure(2, 1, 10.0, 5.6, sharex=True, top_in=0.3, bottom_in=0.5, hgap_in=0.35)
        x = np.arange(len(labels))
        for ax, (name, mean, std) in zip(axes[:, 0], (("accelerometers", acc_mean, acc_std),
                                                     ("gyros", gyro_mean, gyro_std))):
            for k, axis in enumerate("xyz"):
                ax.errorbar(x + (k - 1) * 0.22, mean[:, k], yerr=std[:, k], fmt="o", ms=3, capsize=2,
                            color=AXIS_COLORS[k], label=axis)
            ax.set_ylabel(f"{name}, counts/s")
            _legend(ax)
        category_ticks(axes[1, 0], labels)
        axes[0, 0].set_title("Mean output per dwell (error bars: +-1 std of the samples in the dwell)")
    return to_svg(fig)


def timeseries_figure(t_s: np.ndarray, acc: np.ndarray, gyro: np.ndarray,
                      spans: Sequence[tuple[float, float, str]], max_points: int = MAX_POINTS) -> str:
    """Accelerometer and gyro outputs (counts/s per axis) over run time, dwells and turns shaded."""
    check_drawable("the IMU outputs", acc, gyro)
    check_drawable("the sample and step times", t_s, [x for t0, t1, _ in spans for x in (t0, t1)])
    with plt.rc_context(PLOT_RC):
        fig, axes = new_figure(2, 1, 10.0, 5.0, sharex=True, top_in=0.3, hgap_in=0.3)
        for ax, name, data in ((axes[0, 0], "accelerometers", acc), (axes[1, 0], "gyros", gyro)):
            _shade(ax, spans)
            for k, axis in enumerate("xyz"):
                tt, yy = envelope(t_s, data[:, k], max_points)
                ax.plot(tt, yy, lw=0.6, color=AXIS_COLORS[k], label=axis)
            ax.set_ylabel(f"{name}, counts/s")
            _legend(ax)
        axes[1, 0].set_xlabel("run time, s (blue: dwells, orange: turns)")
    return to_svg(fig)


def angles_figure(t_s: np.ndarray, angles_deg: np.ndarray, spans: Sequence[tuple[float, float, str]],
                  max_points: int = MAX_POINTS) -> str:
    """The controller's frame angles (outer, middle, inner) over run time."""
    check_drawable("the table angles", angles_deg)
    check_drawable("the table state and step times", t_s, [x for t0, t1, _ in spans for x in (t0, t1)])
    with plt.rc_context(PLOT_RC):
        fig, axes = new_figure(1, 1, 10.0, 3.0, top_in=0.3)
        ax = axes[0, 0]
        _shade(ax, spans)
        for k, frame in enumerate(FRAMES):
            tt, yy = envelope(t_s, angles_deg[:, k], max_points)
            ax.plot(tt, yy, lw=0.8, color=AXIS_COLORS[k], label=frame)
        ax.set_ylabel("controller angle, deg")
        ax.set_xlabel("run time, s (blue: dwells, orange: turns)")
        _legend(ax)
    return to_svg(fig)


def sigma_bars_figure(names: list[str], z: list[float | None], threshold: float, title: str) -> str:
    """One bar per coefficient: a difference in units of its sigma, bars beyond +-threshold in red."""
    check_drawable("the differences", [np.nan if x is None else x for x in z])
    with plt.rc_context(PLOT_RC):
        fig, axes = new_figure(1, 1, 10.0, 3.2, bottom_in=0.7)
        ax = axes[0, 0]
        v = np.array([np.nan if x is None else x for x in z], float)
        colors = [OUTLIER_COLOR if abs(x) > threshold else "#7f7f7f" for x in np.nan_to_num(v)]
        ax.bar(np.arange(len(names)), np.nan_to_num(v), color=colors)
        for s in (threshold, -threshold):
            ax.axhline(s, color=OUTLIER_COLOR, ls="--", lw=0.8)
        category_ticks(ax, names, fontsize=7.0)
        ax.set_ylabel("sigma")
        ax.set_title(title)
    return to_svg(fig)


#: Noise terms of an Allan figure: result key -> (slope label, colour).
ALLAN_TERMS = {"quantisation": ("-1: quantisation", "#9467bd"), "arw": ("-1/2: ARW", "#1f77b4"),
               "vrw": ("-1/2: VRW", "#1f77b4"), "bias_instability": ("0: bias instability (x0.664)", "#2ca02c"),
               "rrw": ("+1/2: RRW", "#d62728")}


def allan_figure(channels: Sequence[tuple[str, dict, dict[str, np.ndarray]]]) -> str:
    """Log-log Allan deviation of each channel (points with +-1 sigma bars), its fitted curve and term lines,
    as an inline SVG (`allan_axes_figure` draws it)."""
    return to_svg(allan_axes_figure(channels))


#: Label of the fitted total curve in the Allan plots (the sum of every fitted term, the result's `model`).
ALLAN_MODEL_LABEL = "fitted curve, +-1 sigma (dotted: not fitted there)"


def allan_axes_figure(channels: Sequence[tuple[str, dict, dict[str, np.ndarray]]]):
    """The matplotlib figure of `allan_figure` (the caller closes it).

    `channels`: (name, the result's channel dict, {term: line values at the channel's taus}); a line is
    drawn thin over all taus and thick over the region it was fitted on. The fitted total curve (the channel's
    `model`: all terms, the Gauss-Markov bias included, fitted together) is drawn solid with its 1-sigma band
    over the taus it was fitted on, dotted beyond them.
    """
    for name, ch, lines in channels:
        model = ch.get("model") or {}
        check_drawable(f"the Allan deviation of {name}", ch["tau_s"], ch["adev"], ch["adev_low"], ch["adev_high"],
                       *lines.values(), *(np.asarray(model[k], float) for k in ("adev", "adev_sigma") if k in model))
    rows = -(-len(channels) // 2)
    with plt.rc_context(PLOT_RC):
        fig, axes = new_figure(rows, 2, 10.0, 3.0 * rows + 0.75, hgap_in=0.75, wgap_in=0.8, bottom_in=0.55,
                               top_in=0.85)
        for ax in axes.reshape(-1)[len(channels):]:
            ax.set_visible(False)
        for ax, (name, ch, lines) in zip(axes.reshape(-1), channels):
            tau = np.asarray(ch["tau_s"], float)
            adev = np.asarray(ch["adev"], float)
            err = np.vstack([adev - np.asarray(ch["adev_low"], float), np.asarray(ch["adev_high"], float) - adev])
            ax.errorbar(tau, adev, yerr=err, fmt="o", ms=3, color="#333333", capsize=2, lw=0.8, label="ADEV")
            model = ch.get("model") or {}
            if len(model.get("adev", ())) == len(tau):
                fitted = np.asarray(model["adev"], float)
                sigma = np.asarray(model.get("adev_sigma", np.zeros(len(tau))), float)
                on = np.asarray(model.get("points", range(len(tau))), int)    # the taus it was fitted on
                ax.plot(tau, fitted, ls=":", lw=0.9, color="#ff7f0e")        # beyond them: an extrapolation
                ax.fill_between(tau[on], np.maximum(fitted[on] - sigma[on], fitted[on] * 1e-3),
                                fitted[on] + sigma[on], color="#ff7f0e", alpha=0.2, lw=0)
                ax.plot(tau[on], fitted[on], lw=1.4, color="#ff7f0e", label=ALLAN_MODEL_LABEL)
            for term, line in lines.items():
                label, color = ALLAN_TERMS[term]
                ax.plot(tau, line, ls="--", lw=0.8, color=color)
                points = ch["terms"][term]["points"]
                ax.plot(tau[points], line[points], lw=3.0, alpha=0.6, color=color, label=label)
            ax.set_xscale("log")
            ax.set_yscale("log")
            low = float(np.nanmin(np.asarray(ch["adev_low"], float)[np.asarray(ch["adev_low"], float) > 0],
                                  initial=float(adev.min())))
            ax.set_ylim(low / 2.0, float(np.max(ch["adev_high"])) * 2.0)
            ax.set_xlabel("tau, s")
            ax.set_ylabel(f"Allan deviation, {ch['unit']}")
            ax.set_title(name)
        _figure_legend(fig, axes.reshape(-1)[:len(channels)])
    return fig


def _figure_legend(fig, axes) -> None:
    """One legend for every panel, above them all: inside an axes it covered the curves where they cross it."""
    entries: dict[str, object] = {}
    for ax in axes:
        for handle, label in zip(*ax.get_legend_handles_labels()):
            entries.setdefault(label, handle)
    order = ["ADEV", ALLAN_MODEL_LABEL] + [label for label, _ in ALLAN_TERMS.values()]
    entries = dict(sorted(entries.items(), key=lambda e: order.index(e[0]) if e[0] in order else len(order)))
    fig.legend(list(entries.values()), list(entries), loc="upper center", bbox_to_anchor=(0.5, 1.0), ncol=4,
               fontsize=7, frameon=False, borderaxespad=0.2)
