"""What a person reads of a sweep (`agents.sweep`): its rows as `sweep.csv`, a markdown summary
`sweep.md`, and plots — each headline outcome against each swept number (`sweep_<key>.png`)
and, when two or more numbers take several values, heat maps of the first two headline
outcomes over the first two of them, averaged over the others (`sweep_heatmap.png`). The plots
need matplotlib (the `render` extra); without it the CSV and the summary are still written."""

import csv
import io
import json
import math

import numpy as np

from jaxsim.atomic import write_text_atomic

# Outcomes shown first where a sweep has them: a jump's success and apex, then the return.
HEADLINE = ("success", "peak_com", "clearance", "return", "episode_length",
            "curriculum/difficulty")
SHOWN_ROWS = 10          # best and worst members listed in the summary of a large sweep


def write(out, keys, rows) -> list[str]:
    """Write the report of `rows` (dicts: member, the swept `keys`, outcomes) into `out`;
    returns the names of the files written."""
    rows = sorted(rows, key=lambda row: row["member"])
    if not rows:
        return []
    outcomes = [k for k in dict.fromkeys(k for row in rows for k in row)
                if k != "member" and k not in keys]
    headline = [k for k in HEADLINE if k in outcomes] or outcomes[:3]
    written = ["sweep.csv", "sweep.md"]
    write_text_atomic(out / "sweep.csv", _csv(rows, ["member", *keys, *outcomes]))
    write_text_atomic(out / "sweep.md", _summary(rows, keys, outcomes, headline))
    try:
        from jaxsim import render
        plt = render.pyplot()
    except ImportError:
        return written
    numeric = [k for k in keys if all(_is_number(row.get(k)) for row in rows)]
    headline = [name for name in headline                  # (nothing to draw of the others)
                if any(np.isfinite(_number(row.get(name))) for row in rows)]
    for key in numeric if headline else ():
        name = f"sweep_{key.replace('.', '_')}.png"
        _plot_against(plt, render, rows, key, headline, out / name)
        written.append(name)
    varying = [k for k in numeric if len({row[k] for row in rows}) > 1]
    if len(varying) >= 2 and headline:
        _heat_map(plt, render, rows, varying[:2], headline[:2], out / "sweep_heatmap.png",
                  averaged=varying[2:])
        written.append("sweep_heatmap.png")
    return written


def _csv(rows, columns) -> str:
    text = io.StringIO()
    writer = csv.writer(text)
    writer.writerow(columns)
    for row in rows:
        writer.writerow([_cell(row.get(c)) for c in columns])
    return text.getvalue()


def _cell(value):
    if value is None:
        return ""
    return json.dumps(value) if isinstance(value, (list, dict)) else value


def _summary(rows, keys, outcomes, headline) -> str:
    lines = [f"# Sweep: {len(rows)} members", "",
             "Swept: " + ", ".join(f"`{k}` ({_span([row.get(k) for row in rows])})"
                                   for k in keys), "",
             "| outcome | min | median | max | members with a value |", "|---|---:|---:|---:|---:|"]
    for name in outcomes:
        values = np.array([_number(row.get(name)) for row in rows], float)
        finite = values[np.isfinite(values)]
        if finite.size:
            lines.append(f"| {name} | {finite.min():.4g} | {np.median(finite):.4g} | "
                         f"{finite.max():.4g} | {finite.size} of {len(rows)} |")
        else:
            lines.append(f"| {name} | — | — | — | 0 of {len(rows)} |")
    if headline:
        first = headline[0]
        ranked = sorted(rows, key=lambda row: -_number(row.get(first), -math.inf))
        shown = ranked if len(rows) <= 2 * SHOWN_ROWS else (ranked[:SHOWN_ROWS]
                                                           + ranked[-SHOWN_ROWS:])
        columns = ["member", *keys, *headline]
        title = (f"Members by {first}" if len(shown) == len(rows) else
                 f"The {SHOWN_ROWS} highest and {SHOWN_ROWS} lowest members by {first}")
        lines += ["", f"## {title}", "", "| " + " | ".join(columns) + " |",
                  "|" + "---:|" * len(columns)]
        lines += ["| " + " | ".join(_shown(row.get(c)) for c in columns) + " |" for row in shown]
    return "\n".join(lines) + "\n"


def _span(values) -> str:
    if all(_is_number(v) for v in values):
        distinct = sorted(set(values))
        return (f"{len(distinct)} values, {distinct[0]:.4g} to {distinct[-1]:.4g}"
                if len(distinct) > 1 else f"{distinct[0]:.4g}")
    return f"{len({json.dumps(v) for v in values})} values"


def _shown(value) -> str:
    if value is None:
        return "—"
    if _is_number(value):
        return f"{value:.4g}"
    return json.dumps(value)


def _number(value, missing=math.nan) -> float:
    return float(value) if _is_number(value) else missing


def _is_number(value) -> bool:
    return isinstance(value, (int, float)) and not isinstance(value, bool)


def _plot_against(plt, render, rows, key, headline, path):
    """Each headline outcome against `key`: every member a dot, the mean at each value a line."""
    x = np.array([row[key] for row in rows], float)
    fig, axes = plt.subplots(1, len(headline), figsize=(4.2 * len(headline), 3.4),
                             squeeze=False)
    for ax, name in zip(axes[0], headline):
        y = np.array([_number(row.get(name)) for row in rows], float)
        ax.plot(x, y, ".", alpha=0.5, ms=5)
        values = np.unique(x)
        if len(values) < len(x):
            with np.errstate(invalid="ignore"):
                means = [np.nanmean(np.where(x == v, y, np.nan)) for v in values]
            ax.plot(values, means, "-", lw=1.5, label="mean over the other keys")
            ax.legend(fontsize=7)
        ax.set_xlabel(key)
        ax.set_ylabel(name)
        ax.grid(alpha=0.3)
    render.save_figure(fig, path, title=f"sweep: outcomes against {key}", dpi=110)


def _heat_map(plt, render, rows, keys, names, path, averaged=()):
    """For each outcome of `names`, its mean over the members at each pair of values of the
    two `keys` (over the `averaged` keys' values too)."""
    a, b = (np.array([row[k] for row in rows], float) for k in keys)
    rows_a, cols_b = np.unique(a), np.unique(b)
    fig, axes = plt.subplots(1, len(names), figsize=(5.5 * len(names), 4.2), squeeze=False)
    for ax, name in zip(axes[0], names):
        y = np.array([_number(row.get(name)) for row in rows], float)
        grid = np.full((len(rows_a), len(cols_b)), np.nan)
        for i, va in enumerate(rows_a):
            for j, vb in enumerate(cols_b):
                cell = y[(a == va) & (b == vb)]
                if np.isfinite(cell).any():
                    grid[i, j] = np.nanmean(cell)
        image = ax.imshow(grid, origin="lower", aspect="auto", interpolation="nearest",
                          extent=(-0.5, len(cols_b) - 0.5, -0.5, len(rows_a) - 0.5))
        ax.set_xticks(range(len(cols_b)), [f"{v:.3g}" for v in cols_b], rotation=45,
                      fontsize=7)
        step = max(1, len(rows_a) // 12)
        ax.set_yticks(range(0, len(rows_a), step), [f"{v:.3g}" for v in rows_a[::step]],
                      fontsize=7)
        ax.set_xlabel(keys[1])
        ax.set_ylabel(keys[0])
        fig.colorbar(image, ax=ax, label=name)
    render.save_figure(fig, path, title="sweep: " + ", ".join(names) + (
        f" (mean over {', '.join(averaged)})" if averaged else ""), dpi=110)
