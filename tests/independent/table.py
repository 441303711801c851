"""How ``leadthrough analyze`` fares on independent data: one table per case.

Usage::

    python -m tests.independent.table [--out DIR] [--cases null hose_spring ...] [--seed N]

For each case: write ``DIR/CASE/{train.csv, test.csv, robot.urdf, truth.json}``
(:func:`.generator.write_case`), run the product's CLI as a user would::

    python -m gateway.cli analyze --urdf robot.urdf --train train.csv --test test.csv --out analyze

(log in ``DIR/CASE/analyze.log``), read ``DIR/CASE/analyze/summary.json``, fit the plain
least-squares baseline (:mod:`.baseline`) on the same files, and print per joint: noise std,
plain-LS held-out RMS, analyze's held-out RMS before/after its effects [N·m], then the effects
analyze reports against the truth. The whole table goes to ``DIR/table.json`` (rewritten after
every case). Whatever analyze does (crash, timeout, missing keys, unknown effects) is reported,
never raised.

Note: analyze computes its RMS against its own low-passed torque (``--torque-cutoff-hz``), so
its figures can fall below the white-noise std of the files; plain LS uses the raw files.
"""

from __future__ import annotations

import argparse
import json
import math
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

import numpy as np

from .arm import ARM
from .baseline import plain_ls
from .generator import CASES, read_csv, write_case

#: The parameter shown for each effect name of the product's vocabulary.
MAIN_PARAMETER = {
    "payload": "mass_kg",
    "spring": "k_nm_per_rad",
    "position_ripple": "cycles_per_rev",
    "time_delay": "delay_s",
    "thermal_drift": "rate_nm_per_s",
    "wrist_coupling": "coefficient",
    "stribeck": "amplitude_nm",
    "load_dependent_friction": "coefficient",
}
#: Further parameters shown when present.
SECONDARY = ("amplitude_nm", "from_joint", "q0_rad", "velocity_rad_s", "com_m")
DEFAULT_TIMEOUT_S = 1800.0


def _num(v: Any) -> str:
    if isinstance(v, bool):
        return str(v)
    if isinstance(v, int):
        return str(v)
    if isinstance(v, float):
        return f"{v:.4g}" if math.isfinite(v) else str(v)
    if isinstance(v, list) and len(v) <= 6:
        return "[" + ", ".join(_num(x) for x in v) + "]"
    return str(v)[:60]


def describe_effect(effect: Any) -> str:
    """One line for an effect dict (truth or analyze's); tolerant of any shape."""
    if not isinstance(effect, dict):
        return f"<unreadable effect {effect!r:.60}>"
    name = effect.get("name", "<no name>")
    params = effect.get("parameters")
    params = params if isinstance(params, dict) else {}
    key = effect.get("main_parameter") or MAIN_PARAMETER.get(str(name))
    if key not in params:
        key = next((k for k, v in params.items() if isinstance(v, int | float)), None)
    parts = [f"{name:<16} joints {_num(effect.get('joints'))}"]
    if key is not None:
        parts.append(f"{key}={_num(params[key])}")
    parts += [f"{k}={_num(params[k])}" for k in SECONDARY if k in params and k != key]
    if "appeared" in effect:
        parts.append(f"appeared={effect['appeared']}")
    return "  ".join(parts)


def _joints(effect: Any) -> frozenset[int]:
    try:
        return frozenset(int(j) for j in effect.get("joints", []))
    except (TypeError, ValueError, AttributeError):
        return frozenset()


def compare(truth_effects: list[dict[str, Any]], found: list[Any]) -> dict[str, Any]:
    """Verdicts: per truth effect ``found`` (same name and joints; for a coupling the same
    source joint too), ``wrong_joints`` (same name, other joints) or ``missed``; analyze's
    effects matching no truth effect are ``extra``."""
    used: set[int] = set()
    verdicts = []
    for te in truth_effects:
        verdict, hit = "missed", None
        for i, fe in enumerate(found):
            if not isinstance(fe, dict) or fe.get("name") != te["name"] or i in used:
                continue
            same = _joints(fe) == frozenset(te["joints"])
            if te["name"] == "wrist_coupling":
                src = (fe.get("parameters") or {}).get("from_joint")
                same = same and src == te["parameters"]["from_joint"]
            if same:
                verdict, hit = "found", i
                break
            if hit is None:
                verdict, hit = "wrong_joints", i
        if hit is not None:
            used.add(hit)
        verdicts.append(
            {"truth": te["name"], "joints": te["joints"], "verdict": verdict, "analyze_index": hit}
        )
    extra = [i for i in range(len(found)) if i not in used]
    return {"truth": verdicts, "extra": extra}


def run_analyze(case_dir: Path, paths: dict[str, Path], timeout_s: float) -> dict[str, Any]:
    """Run the CLI on one case; returns exit code, seconds, the summary (or None) and errors."""
    out = case_dir / "analyze"
    cmd = [
        sys.executable,
        "-m",
        "gateway.cli",
        "analyze",
        "--urdf",
        str(paths["urdf"]),
        "--train",
        str(paths["train"]),
        "--test",
        str(paths["test"]),
        "--out",
        str(out),
    ]
    log = case_dir / "analyze.log"
    start = time.perf_counter()
    result: dict[str, Any] = {"command": cmd, "log": str(log), "summary": None, "error": None}
    try:
        proc = subprocess.run(cmd, capture_output=True, text=True, timeout=timeout_s, check=False)
        result["exit_code"] = proc.returncode
        log.write_text(f"$ {' '.join(cmd)}\n--- stdout\n{proc.stdout}\n--- stderr\n{proc.stderr}")
        if proc.returncode != 0:
            tail = (proc.stderr or proc.stdout).strip().splitlines()[-3:]
            result["error"] = f"exit {proc.returncode}: " + " | ".join(tail)
    except subprocess.TimeoutExpired:
        result["exit_code"] = None
        result["error"] = f"timeout after {timeout_s:.0f} s"
    except OSError as exc:
        result["exit_code"] = None
        result["error"] = f"could not start: {exc}"
    result["seconds"] = round(time.perf_counter() - start, 1)
    summary_path = out / "summary.json"
    if summary_path.exists():
        try:
            result["summary"] = json.loads(summary_path.read_text())
        except (OSError, ValueError) as exc:
            result["error"] = (result["error"] or "") + f" unreadable summary.json: {exc}"
    elif result["error"] is None:
        result["error"] = "no summary.json written"
    return result


def _per_joint(summary: Any, key: str, n: int) -> tuple[list[float | None], str | None]:
    if not isinstance(summary, dict):
        return [None] * n, None
    v = summary.get(key)
    try:
        vals = [float(x) for x in v]
    except (TypeError, ValueError):
        return [None] * n, f"summary key {key!r} missing or not numbers: {v!r:.80}"
    if len(vals) != n:
        return (vals + [None] * n)[:n], f"summary {key!r} has {len(vals)} values, expected {n}"
    return vals, None


def table_case(name: str, root: Path, seed: int, timeout_s: float) -> dict[str, Any]:
    """Generate, analyze and baseline one case; the JSON-able record of its table."""
    case_dir = root / name
    paths = write_case(case_dir, name, seed)
    truth = json.loads(paths["truth"].read_text())
    n = ARM.n
    record: dict[str, Any] = {
        "case": name,
        "dir": str(case_dir),
        "truth": truth["effects"],
        "noise_std_nm": truth["noise_std_nm"],
        "problems": [],
    }
    t0 = time.perf_counter()
    base = plain_ls(paths["urdf"].read_text(), read_csv(paths["train"]), read_csv(paths["test"]))
    record["plain_ls"] = {
        "rms_test": base.rms_test.tolist(),
        "rms_train": base.rms_train.tolist(),
        "n_base": base.n_base.tolist(),
        "seconds": round(time.perf_counter() - t0, 1),
    }
    ana = run_analyze(case_dir, paths, timeout_s)
    summary = ana.pop("summary")
    record["analyze"] = ana
    if ana["error"]:
        record["problems"].append(ana["error"])
    before, p1 = _per_joint(summary, "rms_before", n)
    after, p2 = _per_joint(summary, "rms_after", n)
    record["problems"] += [p for p in (p1, p2) if p and summary is not None]
    found = summary.get("effects") if isinstance(summary, dict) else None
    if summary is not None and not isinstance(found, list):
        record["problems"].append(f"summary 'effects' is not a list: {found!r:.80}")
    found = found if isinstance(found, list) else []
    for e in found:
        if isinstance(e, dict) and e.get("name") not in MAIN_PARAMETER:
            record["problems"].append(f"unknown effect name {e.get('name')!r}")
    record["analyze_rms_before"] = before
    record["analyze_rms_after"] = after
    record["analyze_effects"] = found
    record["comparison"] = compare(truth["effects"], found)
    return record


def _cell(v: float | None) -> str:
    return f"{v:12.4g}" if v is not None else f"{'-':>12}"


def format_case(rec: dict[str, Any]) -> str:
    """The printed table of one case."""
    truth = rec["truth"]
    head = "; ".join(describe_effect(e) for e in truth) if truth else "no effect"
    lines = [
        f"=== case {rec['case']}  (truth: {head})",
        f"{'joint':<6}{'noise_std':>12}{'plainLS_test':>14}{'ana_before':>12}"
        f"{'ana_after':>12}   [N·m, held-out test run]",
    ]
    for j in range(len(rec["noise_std_nm"])):
        lines.append(
            f"{ARM.joints[j].name:<6}{_cell(rec['noise_std_nm'][j])}  "
            f"{_cell(rec['plain_ls']['rms_test'][j])}{_cell(rec['analyze_rms_before'][j])}"
            f"{_cell(rec['analyze_rms_after'][j])}"
        )
    cmp_ = rec["comparison"]
    found = rec["analyze_effects"]
    lines.append("effects  truth:")
    if not truth:
        lines.append("    (none)")
    for te, v in zip(truth, cmp_["truth"], strict=True):
        lines.append(f"    {describe_effect(te)}")
        idx = v["analyze_index"]
        got = f" -> analyze: {describe_effect(found[idx])}" if idx is not None else ""
        note = ""
        if te.get("separable_from_rigid_model") is False:
            note = " (expected: inside the rigid-body model's span, absorbed by its parameters)"
        lines.append(f"    verdict: {v['verdict'].upper()}{got}{note}")
    lines.append("effects  analyze reported:" + ("" if found else " (none)"))
    for i, fe in enumerate(found):
        tag = "EXTRA" if i in cmp_["extra"] else "match"
        lines.append(f"    [{tag}] {describe_effect(fe)}")
    ana = rec["analyze"]
    lines.append(
        f"analyze: exit {ana.get('exit_code')} in {ana.get('seconds')} s; "
        f"plain LS {rec['plain_ls']['seconds']} s"
    )
    lines += [f"PROBLEM: {p}" for p in rec["problems"]]
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(
        prog="python -m tests.independent.table",
        description=__doc__,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    parser.add_argument(
        "--out",
        type=Path,
        default=Path(tempfile.gettempdir()) / "indep_table",
        help="output folder (default: %(default)s)",
    )
    parser.add_argument("--cases", nargs="+", choices=list(CASES), default=list(CASES))
    parser.add_argument("--seed", type=int, default=0, help="generator seed (default 0)")
    parser.add_argument(
        "--timeout",
        type=float,
        default=DEFAULT_TIMEOUT_S,
        help="seconds allowed per analyze run (default %(default)s)",
    )
    args = parser.parse_args(argv)
    args.out.mkdir(parents=True, exist_ok=True)
    table: dict[str, Any] = {"seed": args.seed, "arm": ARM.name, "cases": []}
    for name in args.cases:
        try:
            rec = table_case(name, args.out, args.seed, args.timeout)
        except Exception as exc:  # a broken case must not hide the others
            rec = {"case": name, "problems": [f"table failed: {type(exc).__name__}: {exc}"]}
            print(f"=== case {name}\nPROBLEM: {rec['problems'][0]}\n", flush=True)
        else:
            print(format_case(rec) + "\n", flush=True)
        table["cases"].append(rec)
        (args.out / "table.json").write_text(json.dumps(table, indent=2, default=_jsonable) + "\n")
    print(f"table: {args.out / 'table.json'}")
    return 0


def _jsonable(v: Any) -> Any:
    if isinstance(v, np.ndarray | np.generic):
        return v.tolist()
    return str(v)


if __name__ == "__main__":
    sys.exit(main())
