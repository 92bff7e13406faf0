"""Benchmark reports: JSON (everything) and a Markdown table (what goes into the README)."""

from __future__ import annotations

import json
from pathlib import Path

from ..output_safety.atomic import atomic_write_text

NAMES = {
    "cosemdepth": "Co-SemDepth",
    "m4depth": "M4Depth",
    "m4semantic": "M4Semantic",
    "m4depth+m4semantic": "M4Depth + M4Semantic",
}


def _fmt_params(n: int) -> str:
    return f"{n / 1e6:.2f} M"


def markdown(report: dict) -> str:
    """A Markdown rendering of a benchmark report (``meta``, ``results``, ``joint_vs_separate``)."""
    meta = report["meta"]
    hw = meta.get("gpu") or f"{meta['cpu_model']} ({meta['cpu_count']} cores, {meta['threads']} threads)"
    lines = [
        f"Measured {meta['date_utc']} on {hw}, PyTorch {meta['torch']}"
        + (f", CUDA {meta['cuda']}" if meta.get("cuda") else "")
        + f"; load average at start {meta.get('loadavg')}, at end {meta.get('loadavg_end')}.",
        "",
        f"Command: `{meta.get('command', '')}`",
        "",
        "Streaming (every step continues the trajectory; B independent streams per step), warm-up excluded. "
        "ms/frame = step time / B; FPS = frames per second; CPU ms = process CPU time per frame (all threads); "
        "peak memory = peak resident memory above the process before building the model "
        "(CPU) or peak CUDA allocation. Quiet median: over the timed steps during which all other processes together "
        "used at most 0.1 core (from /proc/stat); on a shared machine other users slow a multi-threaded step down far "
        "more than their share, so this is the figure of the machine itself.",
        "",
        "| model | device | precision | path | batch | resolution | median ms/frame | p90 ms/frame | min ms/frame "
        "| FPS | quiet median ms/frame (steps) | CPU ms/frame | params | peak memory |",
        "|---|---|---|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    for r in report["results"]:
        lines.append(
            f"| {NAMES.get(r['arch'], r['arch'])} | {r['device']} | {r['precision']} | {r['path']} | {r['batch']} "
            f"| {r['height']}x{r['width']} | {r['median_ms_per_frame']:.1f} | {r['p90_ms_per_frame']:.1f} "
            f"| {r['min_ms_per_frame']:.1f} | {r['fps']:.1f} | {_quiet(r)} | {_cpu(r)} | {_fmt_params(r['params'])} "
            f"| {r['peak_mem_mb']:.0f} MB |"
        )
    jvs = report.get("joint_vs_separate") or []
    if jvs:
        lines += [
            "",
            "Joint vs separate (Co-SemDepth vs M4Depth then M4Semantic on every frame, both loaded):",
            "",
            'Times: median (interquartile range) over the repeated steps; "joint faster" says "within noise" when '
            "the two interquartile ranges overlap.",
            "",
            "| precision | path | batch | resolution | joint ms/frame | separate ms/frame | time basis | joint params "
            "| separate params | joint peak memory | separate peak memory | joint faster | joint smaller |",
            "|---|---|---|---|---|---|---|---|---|---|---|---|---|",
        ]
        for j in jvs:
            lines.append(
                f"| {j['precision']} | {j['path']} | {j['batch']} | {j['height']}x{j['width']} "
                f"| {_with_iqr(j['joint_median_ms_per_frame'], j.get('joint_spread_ms_per_frame'))} "
                f"| {_with_iqr(j['separate_median_ms_per_frame'], j.get('separate_spread_ms_per_frame'))} "
                f"| {j.get('time_basis', 'all steps')} | {_fmt_params(j['joint_params'])} | {_fmt_params(j['separate_params'])} "
                f"| {j['joint_peak_mem_mb']:.0f} MB | {j['separate_peak_mem_mb']:.0f} MB "
                f"| {_verdict(j['joint_faster'])} | {'yes' if j['joint_smaller_memory'] else 'no'} |"
            )
    return "\n".join(lines) + "\n"


def _with_iqr(median: float, sp: dict | None) -> str:
    return f"{median:.1f}" if not sp else f"{median:.1f} ({sp['q25']:.1f}-{sp['q75']:.1f})"


def _verdict(v) -> str:
    """``joint_faster``: "yes" / "no" / "within noise" (older reports hold a bool)."""
    return ("yes" if v else "no") if isinstance(v, bool) else str(v)


def _quiet(r: dict) -> str:
    v = r.get("quiet_median_ms_per_frame")
    return f"- (0/{r['iters']})" if v is None else f"{v:.1f} ({r['quiet_steps']}/{r['iters']})"


def _cpu(r: dict) -> str:
    v = r.get("median_cpu_ms_per_frame")
    return "-" if v is None or r["device"] != "cpu" else f"{v:.0f}"


def write_report(report: dict, json_path: str | Path | None, md_path: str | Path | None) -> None:
    if json_path:
        atomic_write_text(json_path, json.dumps(report, indent=1) + "\n")
    if md_path:
        atomic_write_text(md_path, markdown(report))
