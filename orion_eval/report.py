"""The evaluation report: ``results.json`` -> ``report.html`` with the paper's Table I/II layout and Fig. 4.

- Table I: rows = methods, column groups = feedback settings, each with SR / SPL / SIT (percent,
  mean over seeds, best per column in bold).
- Table II: the same per goal type (big / small / ambiguous) for the setting with all feedback
  ("mixed" when evaluated, else the last setting).
- Fig. 4: success rate within i Talk turns, one line per method, one panel per feedback setting
  (``success_by_turn.png``); plus SR per setting as bars (``sr_by_feedback.png``). matplotlib, Agg.
- Wilcoxon signed-rank tests (SR) between methods, and the run's figures.
"""

from __future__ import annotations

import html
import json
from pathlib import Path

from orion_eval.metrics import METRICS

NAMES = {"human": "Human (GT route)", "cow": "CoW", "vlmap": "VLMap", "cf": "CF", "orion": "ORION"}
FB_NAMES = {"none": "No interaction", "yesno": "Yes/No", "corrective": "Corrective", "descriptive": "Descriptive",
            "landmark": "Landmark", "procedural": "Procedural", "mixed": "Mixed"}
CSS = """body{font-family:Helvetica,Arial,sans-serif;margin:24px;color:#222}table{border-collapse:collapse;margin:12px 0}
td,th{border:1px solid #bbb;padding:3px 7px;text-align:right;font-size:13px}th{background:#eee}
td.l,th.l{text-align:left}b{color:#000}.note{color:#555;font-size:13px}img{max-width:100%;border:1px solid #ddd}"""


def _fmt(v) -> str:
    return "–" if v is None else f"{v:.1f}"


def _p(p) -> str:
    return "–" if p is None else f"{p:.3g}"


def _table(cells: dict, methods: list[str], columns: list[str], column_names: dict) -> str:
    """cells[method][column] -> {SR, SPL, SIT}; bold = best per column and metric."""
    head1 = "".join(f'<th colspan="{len(METRICS)}">{html.escape(column_names.get(c, c))}</th>' for c in columns)
    head2 = "".join(f"<th>{m}</th>" for _ in columns for m in METRICS)
    best = {(c, m): max((cells.get(me, {}).get(c, {}).get(m) or -1) for me in methods) for c in columns
            for m in METRICS}
    rows = []
    for me in methods:
        tds = []
        for c in columns:
            for m in METRICS:
                v = cells.get(me, {}).get(c, {}).get(m)
                s = _fmt(v)
                tds.append(f"<td>{'<b>' + s + '</b>' if v is not None and v == best[(c, m)] and v > 0 else s}</td>")
        rows.append(f'<tr><td class="l">{html.escape(NAMES.get(me, me))}</td>{"".join(tds)}</tr>')
    return (f'<table><tr><th class="l" rowspan="2">Method</th>{head1}</tr><tr>{head2}</tr>'
            f'{"".join(rows)}</table>')


def plot_success_by_turn(results: dict, path: Path) -> Path:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    sbt = results["success_by_turn"]
    fbs = results["run"]["feedback"]
    n = len(fbs)
    cols = min(4, n)
    rows = -(-n // cols)
    fig, axes = plt.subplots(rows, cols, figsize=(3.2 * cols, 2.8 * rows), squeeze=False, sharey=True)
    for k, fb in enumerate(fbs):
        ax = axes[k // cols][k % cols]
        for me in results["run"]["methods"]:
            ys = sbt.get(me, {}).get(fb)
            if ys:
                ax.plot(range(1, len(ys) + 1), ys, marker="o", label=NAMES.get(me, me))
        ax.set_title(FB_NAMES.get(fb, fb), fontsize=10)
        ax.set_xlabel("interaction turns")
        ax.set_ylim(0, 100)
        ax.grid(alpha=0.3)
    for k in range(n, rows * cols):
        axes[k // cols][k % cols].axis("off")
    axes[0][0].set_ylabel("success rate (%)")
    axes[0][0].legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path


def plot_sr_by_feedback(results: dict, path: Path) -> Path:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    import numpy as np

    methods, fbs = results["run"]["methods"], results["run"]["feedback"]
    fig, ax = plt.subplots(figsize=(max(6, 1.2 * len(fbs)), 3.2))
    w = 0.8 / max(1, len(methods))
    for i, me in enumerate(methods):
        ys = [results["overall"].get(me, {}).get(fb, {}).get("SR") or 0 for fb in fbs]
        ax.bar(np.arange(len(fbs)) + i * w, ys, w, label=NAMES.get(me, me))
    ax.set_xticks(np.arange(len(fbs)) + w * (len(methods) - 1) / 2)
    ax.set_xticklabels([FB_NAMES.get(f, f) for f in fbs], fontsize=8)
    ax.set_ylabel("SR (%)")
    ax.set_ylim(0, 100)
    ax.legend(fontsize=8, ncol=len(methods))
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path


def write_report(results: dict, out_dir: Path) -> Path:
    """Write ``report.html`` and its PNG figures into ``out_dir``; returns the HTML path."""
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    run = results["run"]
    methods, fbs = run["methods"], run["feedback"]
    plot_success_by_turn(results, out_dir / "success_by_turn.png")
    plot_sr_by_feedback(results, out_dir / "sr_by_feedback.png")
    table1 = _table(results["overall"], methods, fbs, FB_NAMES)
    setting = "mixed" if "mixed" in fbs else fbs[-1]
    types = [t for t in ("big", "small", "ambiguous") if t in results["by_goal_type"]]
    by_type = {me: {t: results["by_goal_type"][t].get(me, {}).get(setting, {}) for t in types} for me in methods}
    table2 = _table(by_type, methods, types, {t: t.capitalize() for t in types})
    scenes = "".join(f"<h3>{html.escape(s)}</h3>" + _table(results["by_scene"][s], methods, fbs, FB_NAMES)
                     for s in run["scenes"] if s in results["by_scene"])
    tests = "".join(
        f'<tr><td class="l">{NAMES.get(t["a"], t["a"])} vs {NAMES.get(t["b"], t["b"])}</td><td>{t["pairs"]}</td>'
        f'<td>{_fmt(t["mean_a"])}</td><td>{_fmt(t["mean_b"])}</td>'
        f'<td>{_p(t["p"])}</td></tr>'
        for t in results["wilcoxon"]["SR"])
    diag = any(v.get("diagnostic") for enc in run.get("encoders", {}).values() for v in enc.values())
    page = f"""<!doctype html><html><head><meta charset="utf-8"><title>zipon eval</title><style>{CSS}</style></head><body>
<h1>ZIPON evaluation</h1>
<p class="note">{run['episodes']} episodes; scenes {', '.join(map(html.escape, run['scenes']))}; seeds {run['seeds']};
success rule '{run['success_rule']}', I<sub>max</sub> = {run['max_talk_turns']}; {run['seconds']} s
({run['episodes_per_s']} episodes/s). Values are percentages, mean over seeds.
{'<b>Maps built with the diagnostic oracle encoder (ground truth), not a perception model.</b>' if diag else ''}</p>
<h2>Table I — SR / SPL / SIT per method and feedback setting</h2>{table1}
<h2>Table II — per goal type ({html.escape(FB_NAMES.get(setting, setting))})</h2>{table2}
<h2>Fig. 4 — success by interaction turn</h2><img src="success_by_turn.png" alt="success by turn">
<h2>SR per feedback setting</h2><img src="sr_by_feedback.png" alt="SR by feedback">
<h2>Wilcoxon signed-rank tests (SR, paired episodes)</h2>
<table><tr><th class="l">pair</th><th>pairs</th><th>SR a</th><th>SR b</th><th>p</th></tr>{tests}</table>
<h2>Per scene</h2>{scenes}
<p class="note">Per-episode logs (actions, dialogue, poses): episodes/&lt;scene&gt;.episodes.jsonl.gz;
all numbers: results.json.</p>
</body></html>"""
    path = out_dir / "report.html"
    path.write_text(page)
    return path


def load_results(out_dir: Path) -> dict:
    return json.loads((Path(out_dir) / "results.json").read_text())
