"""The analysis outputs a person reads (``report.md``) and a program reads (``summary.json``).

``summary.json`` keys (torques [N·m], per joint in URDF order, on the *test* files unless the
key says train): ``joints``, ``friction_model``, ``rms_before`` / ``rms_after`` (held-out RMS
without / with the accepted effects), ``relative_before`` / ``relative_after``
(RMS / RMS of the measured torque), ``rms_train`` (final model, training files, in-sample),
``rms_train_before``, ``effects`` (list of ``{"name", "joints" (1-based), "parameters" (units in
the keys), "appeared": "all_along" | "between_train_and_test", "improved_joints",
"heldout_rms_before", "heldout_rms_after"}``), ``friction_comparison`` (per family: train and
test RMS and q_e), ``friction_measured_over`` (per joint: the speeds the friction was fitted
over, :mod:`.speed_regimes`), ``raw`` (the raw-torque figures; ``raw.by_speed`` split at rest,
teaching speeds and faster, ``raw.per_file`` per test file), ``validation`` (commissioning's
slow motion never fitted, :mod:`.validation_runs`), ``timing_s`` (seconds per stage
and ``total``), plus file names and counts.
A figure with no samples behind it (a joint that never slid in the test files) is ``null``.
"""

from __future__ import annotations

import json
import math
from pathlib import Path
from typing import Any

from control.identification.effects import ALL_ALONG, BETWEEN

_CASES = {
    ALL_ALONG: "present all along (training and test files)",
    BETWEEN: "appeared between training and test (absent from the training files)",
}
_FITTED = {
    "train": "refitted with the model on the training files, judged on the test files",
    "test": "chosen and estimated on the first part of the test run (residual of the fixed "
    "training model), scored on the rest of the test run",
}


#: what a table shows for a figure with no samples behind it (a joint that never slid in the
#: test files has no held-out error on sliding samples: null in summary.json)
NO_SAMPLES = "—"


def _fmt(v: float | None) -> str:
    if v is None or not math.isfinite(v):
        return NO_SAMPLES
    return f"{v:.3g}" if abs(v) < 1000 else f"{v:.0f}"


def _pct(v: float | None) -> str:
    return NO_SAMPLES if v is None or not math.isfinite(v) else f"{100 * v:.1f} %"


def finite_or_none(obj: Any) -> Any:
    """``obj`` with every NaN or infinity (a figure with no samples behind it) as None: JSON
    has no NaN, and a reader of summary.json must not get one."""
    if isinstance(obj, float):
        return obj if math.isfinite(obj) else None
    if isinstance(obj, dict):
        return {k: finite_or_none(v) for k, v in obj.items()}
    if isinstance(obj, list | tuple):
        return [finite_or_none(v) for v in obj]
    return obj


def _param_text(params: dict[str, Any]) -> str:
    parts = []
    for k, v in params.items():
        if isinstance(v, list):
            parts.append(f"{k} = [{', '.join(_fmt(x) for x in v)}]")
        elif isinstance(v, float):
            parts.append(f"{k} = {_fmt(v)}")
        else:
            parts.append(f"{k} = {v}")
    return ", ".join(parts)


def _range(r: list[float] | None) -> str:
    return NO_SAMPLES if not r else f"{_fmt(r[0])}–{_fmt(r[1])}"


def _per_file_lines(summary: dict[str, Any], joints: list[str]) -> list[str]:
    """The raw error per test file, when there are several (a multi-sine and a slow,
    reversing motion are judged apart)."""
    files = (summary.get("raw") or {}).get("per_file") or []
    if len(files) < 2:
        return []
    lines = [
        "",
        "Per test file, raw, after / plain LS [N·m]:",
        "",
        "| file | rows | " + " | ".join(joints) + " |",
        "|---|---|" + "---|" * len(joints),
    ]
    for f in files:
        after, plain = f.get("rms_after"), f.get("rms_plain_ls")
        cells = [
            NO_SAMPLES if after is None else f"{_fmt(after[j])} / {_fmt(plain[j])}"
            for j in range(len(joints))
        ]
        lines.append(
            f"| `{Path(str(f['file'])).name}` | {f['rows_scored']} | " + " | ".join(cells) + " |"
        )
    return lines


def _validation_lines(summary: dict[str, Any], joints: list[str]) -> list[str]:
    """The model on recordings never given to the fit (:mod:`.validation_runs`)."""
    v = summary.get("validation")
    if not v or not v.get("files"):
        return []
    lines = ["", "### On a slow, reversing motion never fitted", "", f"{v['what']}.", ""]
    for f in v["files"]:
        by = f["by_speed"]
        lines += [
            f"`{Path(str(f['file'])).name}`: {f['rows_scored']} of {f['rows']} rows scored.",
            "",
            "| joint | measured RMS [N·m] | error [N·m] | at rest | at teaching speeds | faster |",
            "|---|---|---|---|---|---|",
        ]
        for j, name in enumerate(joints):
            cells = [
                f"{_fmt(by[r]['rms_after'][j])} ({_pct(by[r]['share'][j])})"
                for r in ("rest", "teaching", "faster")
            ]
            lines.append(
                f"| {name} | {_fmt(f['rms_measured'][j])} | {_fmt(f['rms_after'][j])} | "
                + " | ".join(cells)
                + " |"
            )
        lines.append("")
    return lines


def _speed_lines(summary: dict[str, Any], joints: list[str]) -> list[str]:
    """Where in speed the friction was measured, and the raw error at rest, at teaching speeds
    and faster (:mod:`.speed_regimes`)."""
    cover = summary.get("friction_measured_over")
    by = (summary.get("raw") or {}).get("by_speed")
    if not cover or not by:
        return []
    teach = by["teaching_below_rad_s"]
    lines = [
        "",
        "### Speeds: where the friction was measured, and the raw error by speed",
        "",
        f"Friction fitted on the training rows where each joint slides: 1st–99th percentile of "
        f"their speed, the share of them below {_fmt(teach)} rad/s (teaching speeds), the "
        "reversals and the share of training rows at rest. The raw test error (as above) "
        f"split by each row's measured speed: at rest (below {_fmt(by['rest_below_rad_s'])} "
        f"rad/s), teaching (below {_fmt(teach)} rad/s), faster; after / plain LS [N·m], the "
        "share of rows in brackets.",
        "",
        "| joint | slid at [rad/s] | at teaching speeds | reversals | at rest | "
        "error at rest | error teaching | error faster |",
        "|---|---|---|---|---|---|---|---|",
    ]

    def cell(regime: str, j: int) -> str:
        e = by[regime]
        return f"{_fmt(e['rms_after'][j])} / {_fmt(e['rms_plain_ls'][j])} ({_pct(e['share'][j])})"

    for j, name in enumerate(joints):
        c = cover[j]
        lines.append(
            f"| {name} | {_range(c['speed_range_rad_s'])} | {_pct(c['teaching_share'])} | "
            f"{c['reversals']} | {_pct(c['rest_share'])} | {cell('rest', j)} | "
            f"{cell('teaching', j)} | {cell('faster', j)} |"
        )
    return lines


def render_markdown(summary: dict[str, Any]) -> str:
    """``report.md`` text from a summary dict."""
    joints = summary["joints"]
    lines = [
        "# Identification report",
        "",
        f"URDF `{summary['files']['urdf']}`; {len(joints)} joints, "
        f"{summary['base_parameters']} base parameters; "
        f"friction model `{summary['friction_model']}`.",
        f"Training files: {', '.join(f'`{p}`' for p in summary['files']['train'])} "
        f"({summary['n_samples']['train']} samples at {summary['rate_hz']:.0f} Hz). "
        f"Held-out test files: {', '.join(f'`{p}`' for p in summary['files']['test'])} "
        f"({summary['n_samples']['test']} samples).",
    ]
    for why in summary.get("files_left_out", []):
        lines.append(f"Left out: {why}.")
    if summary.get("cylinders_removed"):
        lines.append(
            "Assist-cylinder torque (eqs. 10/12, from the measured pressures) was taken out of "
            "the measured torque before fitting."
        )
    for c in (summary.get("cylinders") or {}).get("cylinders", []):
        lines.append(
            f"Cylinder on J{c['joint_index'] + 1}: force {c['torque_scale']:.4g} × described "
            f"(piston Ø {1000 * c['described_piston_diameter_m']:.4g} → "
            f"{1000 * c['piston_diameter_m']:.4g} mm), {'kept' if c['kept'] else 'not kept'}: "
            f"{c['reason']}."
        )
    mc = summary.get("measurement_chain")
    if mc:
        free = mc.get("gain_estimated", [])
        lines.append(
            "Measurement chain (the torque channel reads gain · τ + offset; gain estimated "
            "where it lowered the joint's own held-out error beyond noise, also fitted on "
            "the first half of the training rows and scored on the second, else 1): "
            + ", ".join(
                f"J{j + 1} gain {g:.4g}{'' if j < len(free) and free[j] else ' (held)'} "
                f"offset {_fmt(b)} N·m"
                for j, (g, b) in enumerate(zip(mc["gain"], mc["offset_nm"], strict=True))
            )
            + "."
        )
    lines += [
        "",
        "## Held-out torque error per joint (test files)",
        "",
        "| joint | RMS measured [N·m] | RMS before [N·m] | rel. before | RMS after [N·m] "
        "| rel. after | change | train RMS [N·m] |",
        "|---|---|---|---|---|---|---|---|",
    ]
    unjudged = []
    for j, name in enumerate(joints):
        before, after = summary["rms_before"][j], summary["rms_after"][j]
        judged = all(v is not None and math.isfinite(v) for v in (before, after))
        change = f"{100 * (after - before) / before:+.1f} %" if judged and before > 0 else "-"
        if not judged:
            unjudged.append(name)
        lines.append(
            f"| {name} | {_fmt(summary['rms_measured_test'][j])} | {_fmt(before)} | "
            f"{_pct(summary['relative_before'][j])} | {_fmt(after)} | "
            f"{_pct(summary['relative_after'][j])} | {change} | "
            f"{_fmt(summary['rms_train'][j])} |"
        )
    if unjudged:
        lines += ["", f"{NO_SAMPLES}: {', '.join(unjudged)} did not slide in the test files (no "
                  "sample above the stick velocity to judge the model on)."]  # fmt: skip
    raw = summary.get("raw")
    if raw:
        lines += [
            "",
            "### On the raw torque, every row",
            "",
            f"The same models scored as `leadthrough predict` scores them: {raw['scored']}.",
            "",
            "| joint | raw noise [N·m] | RMS before [N·m] | RMS after [N·m] | plain LS [N·m] |",
            "|---|---|---|---|---|",
        ]
        noise = raw.get("noise_std_nm") or [None] * len(joints)
        for j, name in enumerate(joints):
            lines.append(
                f"| {name} | {_fmt(noise[j])} | {_fmt(raw['rms_before'][j])} | "
                f"{_fmt(raw['rms_after'][j])} | {_fmt(raw['rms_plain_ls'][j])} |"
            )
    lines += _per_file_lines(summary, joints)
    lines += _validation_lines(summary, joints)
    lines += _speed_lines(summary, joints)
    lines += ["", "## Effects found in the residual", ""]
    if not summary.get("effects_searched", True):
        lines.append("The effect search was switched off (`--no-effects`).")
    elif not summary["effects"] and not summary.get("refused_effects"):
        lines.append(
            "No further effect found: no candidate of the effect vocabulary cut a joint's "
            f"held-out RMS by {100 * summary['margin']:.0f} % with a held-out gain significant "
            f"against the measured noise floor (family-wise level {summary['alpha']:g})."
        )
    elif not summary["effects"]:
        lines.append("No effect accepted; the candidates below passed the held-out tests but "
                     "were refused for the reason given.")  # fmt: skip
    if summary.get("refused_effects"):
        lines += ["", "### Refused candidates", "", "| effect | joints | case | held-out gain "
                  "| reason |", "|---|---|---|---|---|"]  # fmt: skip
        for r in summary["refused_effects"]:
            lines.append(
                f"| `{r['name']}` | {', '.join(joints[j - 1] for j in r['joints'])} | "
                f"{r['case'].replace('_', ' ')} | {100 * r['heldout_gain']:.0f} % | "
                f"{r['reason']} |"
            )
        lines.append("")
    for e in summary["effects"]:
        case = _CASES[e["appeared"]] + "; " + _FITTED[e["estimated_on"]]
        improved = ", ".join(joints[j - 1] for j in e["improved_joints"]) or "-"
        lines += [
            f"### `{e['name']}` on joint(s) {', '.join(joints[j - 1] for j in e['joints'])}",
            "",
            f"- {case}",
            f"- parameters: {_param_text(e['parameters'])}",
            f"- held-out RMS improved on: {improved}",
            "",
        ]
    if summary["effects"]:
        lines.append("No further effect found after these.")
    comp = summary.get("friction_comparison", {})
    if comp:
        lines += [
            "",
            "## Friction models compared (before effects)",
            "",
            "Eq. (14) is the Fourier model of ref. [37], eq. (15) the paper's model (our reading, "
            "`control/model/friction.py`), simple = Coulomb + viscous + offset.",
            "",
            "| joint | " + " | ".join(f"{k} train / test RMS [N·m]" for k in comp) + " |",
            "|---|" + "---|" * len(comp),
        ]
        for j, name in enumerate(joints):
            cells = [f"{_fmt(c['rms_train'][j])} / {_fmt(c['rms_test'][j])}" for c in comp.values()]
            lines.append(f"| {name} | " + " | ".join(cells) + " |")
        lines.append("")
        lines.append(
            "q_e per joint [rad/s]: " + "; ".join(f"{k}: {c['q_e_rad_s']}" for k, c in comp.items())
        )
    if summary.get("plots"):
        lines += ["", "## Plots", ""]
        lines += [f"- [{p}]({p})" for p in summary["plots"]]
    timing = summary.get("timing_s", {})
    if timing:
        lines += ["", "## Timing", "", ", ".join(f"{k} {v:.2f} s" for k, v in timing.items())]
    lines += ["", f"Model file: [{summary['model_file']}]({summary['model_file']})", ""]
    return "\n".join(lines)


def write_report(out_dir: str | Path, summary: dict[str, Any]) -> None:
    """Write ``summary.json`` and ``report.md`` into ``out_dir``."""
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    clean = finite_or_none(summary)
    (out / "summary.json").write_text(json.dumps(clean, indent=1, allow_nan=False) + "\n")
    (out / "report.md").write_text(render_markdown(summary))
