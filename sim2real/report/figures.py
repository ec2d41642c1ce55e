"""The gap report's figures: deterministic PNGs (matplotlib's Agg canvas, fixed dpi, no version or time stamps).

:func:`plan` names the figures a report has, in order; :func:`render` draws them all. The same data give the same
bytes. matplotlib is imported only when a figure is drawn.

Example:
    >>> from matplotlib.figure import Figure
    >>> fig = Figure(figsize=(2, 2))
    >>> _ = fig.subplots().plot([0, 1], [1, 0])
    >>> png = png_bytes(fig)
    >>> png[:8] == b"\\x89PNG\\r\\n\\x1a\\n", b"matplotlib" in png.lower()
    (True, False)
"""

from __future__ import annotations

import io
import math
import re
from collections.abc import Mapping
from types import MappingProxyType
from typing import TYPE_CHECKING, Any

import numpy as np

if TYPE_CHECKING:
    from sim2real.report.gap_report import GapReport

__all__ = ["plan", "png_bytes", "render"]

_DPI = 100
_CHANNELS_PER_PAGE = 6
_PNG_METADATA = {"Software": None}  # no matplotlib version stamp: PNGs depend on the data only


def plan(report: GapReport) -> list[tuple[str, str, str]]:
    """``(figure name, kind, key)`` of each figure of ``report``, in order; names are file-safe and unique."""
    out: list[tuple[str, str, str]] = []
    if report.stats:
        out.append(("returns", "returns", ""))
    used: set[str] = set()

    def unique(base: str) -> str:
        name, k = base, 2
        while name in used:
            name, k = f"{base}-{k}", k + 1
        used.add(name)
        return name

    for sweep in dict.fromkeys(c.sweep for c in report.robustness):
        out.append((unique(f"robustness_{_slug(sweep)}"), "robustness", sweep))
    for grid in dict.fromkeys(g.grid for g in report.grids):
        out.append((unique(f"heatmap_{_slug(grid)}"), "heatmap", grid))
    if report.fit is not None and len(report.fit.channels):  # a fit read back from JSON has no traces
        pages = math.ceil(len(report.fit.channels) / _CHANNELS_PER_PAGE)
        for page in range(pages):  # every channel, paged
            out.append(("sysid_fit" if page == 0 else f"sysid_fit-{page + 1}", "sysid_fit", str(page)))
    if report.contact_sheet is not None:
        out.append(("contact_sheet", "contact_sheet", ""))
    return out


def render(report: GapReport) -> Mapping[str, bytes]:
    """Every figure of ``report`` as PNG bytes, by name, in :func:`plan` order (read-only)."""
    out: dict[str, bytes] = {}
    for name, kind, key in plan(report):
        if kind == "returns":
            out[name] = _png(_returns_figure(report))
        elif kind == "robustness":
            out[name] = _png(_robustness_figure(report, key))
        elif kind == "heatmap":
            out[name] = _png(_heatmap_figure(report, key))
        elif kind == "sysid_fit":
            assert report.fit is not None
            out[name] = _png(_sysid_figure(report.fit, int(key), report.linear))
        else:
            assert report.contact_sheet is not None
            out[name] = _image_png(report.contact_sheet)
    return MappingProxyType(out)


def _outside_legend(ax: Any, title: str) -> None:
    """A legend right of the axes (never over the data), one entry per label, with a title."""
    handles, labels = ax.get_legend_handles_labels()
    unique = dict(zip(labels, handles, strict=True))
    ax.legend(
        unique.values(), unique.keys(), title=title, fontsize=8, title_fontsize=8, loc="upper left",
        bbox_to_anchor=(1.01, 1.0), borderaxespad=0.0,
    )  # fmt: skip


def _returns_figure(report: GapReport) -> Any:
    from matplotlib.figure import Figure

    conditions = list(dict.fromkeys(s.condition for s in report.stats))
    policies = [p for p in report.policies if any(s.policy == p for s in report.stats)]
    fig = Figure(figsize=(max(5.0, 1.1 * len(policies) * max(1, len(conditions)) * 0.6 + 2.0) + 2.2, 4.0))
    fig.set_layout_engine("constrained")
    ax = fig.subplots()
    width = 0.8 / max(1, len(conditions))
    for k, condition in enumerate(conditions):
        xs, ys, lo, hi = [], [], [], []
        for i, policy in enumerate(policies):
            for s in report.stats:
                if s.policy == policy and s.condition == condition:
                    e = s.statistic(report.statistic)
                    xs.append(i - 0.4 + width * (k + 0.5))
                    ys.append(e.value)
                    lo.append(max(0.0, e.value - e.low) if math.isfinite(e.low) else 0.0)
                    hi.append(max(0.0, e.high - e.value) if math.isfinite(e.high) else 0.0)
        label = _tex(report.label(condition, "condition"))
        ax.errorbar(xs, ys, yerr=[lo, hi], fmt="o", capsize=3, color=f"C{k % 10}", label=label)
    ax.set_xticks(
        range(len(policies)),
        labels=[_tex(report.label(p, "policy")) for p in policies],
        rotation=20 if len(policies) > 3 else 0,
    )
    ax.set_xlabel("policy")
    ax.set_ylabel(f"{report.statistic} episode return ({report.confidence:.0%} interval)")
    ax.set_title(_tex(f"{report.task}: return per policy and condition"), fontsize=10)
    ax.grid(axis="y", alpha=0.3)
    _outside_legend(ax, "evaluated on")
    return fig


def _robustness_figure(report: GapReport, sweep: str) -> Any:
    from matplotlib.figure import Figure

    curves = [c for c in report.robustness if c.sweep == sweep]
    axis = report.axis_label(curves[0].axis)
    fig = Figure(figsize=(8.4, 4.0))
    fig.set_layout_engine("constrained")
    ax = fig.subplots()
    for k, c in enumerate(curves):
        color = f"C{k % 10}"
        x = np.asarray(c.values) * axis.factor
        values = np.array([p.value for p in c.points])
        low = np.array([p.low for p in c.points])
        high = np.array([p.high for p in c.points])
        ax.plot(x, values, "o-", color=color, ms=3, label=_tex(report.label(c.policy, "policy")))
        ax.fill_between(x, low, high, color=color, alpha=0.2, linewidth=0)
        if c.threshold is not None:
            ax.axhline(c.threshold, color=color, ls=":", lw=1)
    ax.axvline(curves[0].nominal * axis.factor, color="0.4", ls="--", lw=1, label="unperturbed value")
    ax.plot([], [], color="0.4", ls=":", lw=1, label=f"{report.fraction:g} × return in own training sim")
    ax.set_xlabel(_tex(axis.text))
    ax.set_ylabel(f"{report.statistic} episode return ({report.confidence:.0%} band)")
    ax.set_title(_tex(f"robustness to {axis.text}"), fontsize=10)
    ax.grid(alpha=0.3)
    _outside_legend(ax, "policy")
    return fig


def _heatmap_figure(report: GapReport, grid: str) -> Any:
    from matplotlib.figure import Figure
    from matplotlib.patches import Rectangle

    maps = [g for g in report.grids if g.grid == grid]
    cols = min(3, len(maps))
    rows = math.ceil(len(maps) / cols)
    fig = Figure(figsize=(4.2 * cols + 0.8, 3.6 * rows))
    fig.set_layout_engine("constrained")
    axes = fig.subplots(rows, cols, squeeze=False)
    every = np.concatenate([np.asarray(g.values, dtype=np.float64).ravel() for g in maps])
    every = every[np.isfinite(every)]
    vmin, vmax = (float(every.min()), float(every.max())) if every.size else (0.0, 1.0)
    image = None
    for ax, g in zip(axes.ravel(), maps, strict=False):
        ax_x, ax_y = report.axis_label(g.axes[0]), report.axis_label(g.axes[1])
        m = np.asarray(g.values, dtype=np.float64)
        # x across, y up (largest at the top): the layout of the report's grid tables
        image = ax.imshow(m.T, origin="lower", aspect="auto", vmin=vmin, vmax=vmax, cmap="viridis")
        ax.set_xticks(range(len(g.x)), labels=[f"{v * ax_x.factor:g}" for v in g.x])
        ax.set_yticks(range(len(g.y)), labels=[f"{v * ax_y.factor:g}" for v in g.y])
        ax.set_xlabel(_tex(ax_x.text))
        ax.set_ylabel(_tex(ax_y.text))
        ax.set_title(_tex(report.label(g.policy, "policy")), fontsize=10)
        if m.size <= 100:
            mid = (vmin + vmax) / 2.0
            for i in range(m.shape[0]):
                for j in range(m.shape[1]):
                    if math.isfinite(m[i, j]):
                        color = "black" if m[i, j] > mid else "white"
                        ax.text(i, j, f"{m[i, j]:.3g}", ha="center", va="center", fontsize=7, color=color)
        xi = [i for i, v in enumerate(g.x) if math.isclose(v, g.nominal[0], abs_tol=1e-12)]
        yi = [j for j, v in enumerate(g.y) if math.isclose(v, g.nominal[1], abs_tol=1e-12)]
        if xi and yi:
            box = Rectangle((xi[0] - 0.5, yi[0] - 0.5), 1.0, 1.0, fill=False, edgecolor="red", linewidth=2.0)
            ax.add_patch(box)
    for ax in axes.ravel()[len(maps) :]:
        ax.set_axis_off()
    if image is not None:
        fig.colorbar(image, ax=axes.ravel().tolist(), label=f"{report.statistic} episode return")
    names = f"{report.axis_label(maps[0].axes[0]).text} × "
    names += report.axis_label(maps[0].axes[1]).text
    fig.suptitle(_tex(f"{report.statistic} return over {names} (unperturbed point boxed in red)"), fontsize=10)
    return fig


def _sysid_figure(fit: Any, page: int, linear: tuple[str, ...] = ()) -> Any:
    """Page ``page`` of the fit's channels (in the fit's order): measured vs simulated, and the residual with its
    ±2σ noise band, each axis in the channel's unit; the legend sits above the plots, not on the data."""
    from matplotlib.figure import Figure

    from sim2real.report.labels import channel_unit

    count = len(fit.channels)
    pages = math.ceil(count / _CHANNELS_PER_PAGE)
    chosen = list(range(page * _CHANNELS_PER_PAGE, min(count, (page + 1) * _CHANNELS_PER_PAGE)))
    fig = Figure(figsize=(10, 2.1 * len(chosen) + 0.8))
    fig.set_layout_engine("constrained")
    axes = fig.subplots(len(chosen), 2, squeeze=False)
    t = np.asarray(fit.trace_time)
    for row, c in enumerate(chosen):
        name = fit.channels[c]
        unit = channel_unit(name, linear) or "channel units"
        measured, predicted = fit.trace_measured[:, c], fit.trace_predicted[:, c]
        ok = np.isfinite(measured)
        ax = axes[row, 0]
        ax.plot(t[ok], measured[ok], ".", ms=2, color="0.4", label="measured (twin log)")
        ax.plot(t[ok], predicted[ok], "-", lw=1, color="C0", label="simulated (fitted model)")
        ax.set_ylabel(_tex(f"{name} ({unit})"), fontsize=8)
        ax.set_title(_tex(f"{name}: fit {fit.fit_percent.get(name, math.nan):.1f}%"), fontsize=9)
        ax2 = axes[row, 1]
        ax2.plot(t[ok], measured[ok] - predicted[ok], ".", ms=2, color="C3", label="residual")
        sigma = fit.noise_std.get(name, math.nan)
        if math.isfinite(sigma):
            for sign in (-2, 2):
                ax2.axhline(sign * sigma, color="0.5", lw=0.8, ls="--", label="±2σ noise")
        ax2.set_ylabel(f"residual ({unit})", fontsize=8)
    axes[-1, 0].set_xlabel(f"time (s), {fit.trace_source} data")
    axes[-1, 1].set_xlabel("time (s)")
    handles, labels = [], []
    for ax in axes[0]:
        h, lab = ax.get_legend_handles_labels()
        for one, text in zip(h, lab, strict=True):
            if text not in labels:
                handles.append(one)
                labels.append(text)
    title = f"system identification: channels {chosen[0] + 1}-{chosen[-1] + 1} of {count} (page {page + 1} of {pages})"
    fig.legend(
        handles, labels, loc="outside upper center", ncols=len(labels), fontsize=8, title=title, title_fontsize=9
    )
    return fig


def _slug(name: str) -> str:
    slug = re.sub(r"[^A-Za-z0-9]+", "-", name).strip("-").lower()[:60].strip("-")
    return slug or "sweep"


def _tex(text: str) -> str:
    """A label matplotlib draws literally (a ``$`` would start mathtext)."""
    return text.replace("$", r"\$")


def png_bytes(figure: Any) -> bytes:
    """A matplotlib ``Figure`` as PNG bytes at a fixed dpi, without version or time stamps (deterministic for the
    same data); the figure is cleared afterwards to free its artists."""
    return _png(figure)


def _png(figure: Any) -> bytes:
    buffer = io.BytesIO()
    try:
        figure.savefig(buffer, format="png", dpi=_DPI, metadata=_PNG_METADATA)
    finally:
        figure.clear()
    return buffer.getvalue()


def _image_png(image: np.ndarray) -> bytes:
    from matplotlib import image as mimage

    buffer = io.BytesIO()
    # matplotlib drops None-valued keys (the version stamp); its annotation allows only str values
    mimage.imsave(buffer, image, format="png", metadata=_PNG_METADATA)  # type: ignore[arg-type]
    return buffer.getvalue()
