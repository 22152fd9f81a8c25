"""The parts the camera and depth gap reports (``vgr.camera_gap_report/1``, ``vgr.depth_gap_report/1``)
have in common: the document's head (format, verdict, exit code, reason, notes), a round's decision,
an added term's names, the decision rule, the JSON Schema loader and the terminal's verdict lines.
The workflow-specific fields (pixels or millimetres, views or captures) stay in each report."""

from __future__ import annotations

import json
import sys
from collections.abc import Callable
from pathlib import Path
from typing import Any

from engine.files import replace_text
from plugins.model_gap.verdicts import VERDICT_EXIT_CODES

__all__ = [
    "decision_dict", "decision_rule", "load_schema", "print_rounds", "print_verdict", "report_head", "say",
    "show_report", "term_names", "write_report_file",
]  # fmt: skip


def load_schema(path: Path) -> dict[str, Any]:
    """The JSON Schema in *path*."""
    return json.loads(path.read_text())


def report_head(report_format: str, result: Any) -> dict[str, Any]:
    """The first fields of a report document: format, verdict, its exit code, reason, notes."""
    return {
        "format": report_format,
        "verdict": result.verdict,
        "exit_code": int(VERDICT_EXIT_CODES[result.verdict]),
        "reason": result.reason,
        "notes": list(result.notes),
    }


def decision_dict(d: Any, reason: str) -> dict[str, Any]:
    """A round's decision (:class:`plugins.model_gap.camera.selection.Decision`) with *reason* as its reason."""
    return {
        "named": None if d.named is None else d.named.name,
        "tied": [e.name for e in d.tie],
        "representative": None if d.representative is None else d.representative.name,
        "parsimony_over": [e.name for e in d.parsimony_over],
        "pair_p_values": d.pair_p_values,
        "reason": reason,
    }


def term_names(a: Any) -> dict[str, Any]:
    """The first fields of an added term: its label, effect, whether a tie term, members, parsimony over."""
    return {
        "name": a.label,
        "effect": a.effect.name,
        "tied": bool(a.tied_with),
        "members": [e.name for e in (a.effect, *a.tied_with)],
        "parsimony_over": [e.name for e in a.parsimony_over],
    }


def decision_rule(cfg: Any, over: str, **extra: Any) -> dict[str, Any]:
    """The ``decision_rule`` field: the paired test over held-out *over* (views, captures), the config's
    selection options, *extra* options, the catalog."""
    return {
        "test": f"one-sided Wilcoxon signed-rank over held-out {over} of MSE_current - MSE_candidate",
        "alpha": cfg.alpha,
        "correction": "bonferroni over the round's candidates",
        "alpha_tie": cfg.alpha_tie,
        "folds": cfg.folds,
        "seed": cfg.seed,
        "max_effects": cfg.max_effects,
        **extra,
        "catalog": [e.name for e in cfg.catalog],
    }


def say(console: Any, text: str) -> None:
    """Print *text* as it is (no rich markup, no highlighting)."""
    console.print(text, markup=False, highlight=False)


def print_rounds(doc: dict[str, Any], console: Any, unit: str, over: str) -> None:
    """The terminal's table of each round's candidates and its decision; *unit* the lengths' (``px``,
    ``mm``: the fields ``heldout_rms_<unit>``, ``gain_<unit>``), *over* what the test pairs (``views``,
    ``captures``: the fields ``n_<over>_better``, ``n_<over>``)."""
    from rich.table import Table

    for r in doc["iterations"]:
        t = Table(title=f"round {r['iteration']}: current held-out RMS {r[f'current_heldout_rms_{unit}']:.4f} {unit}")
        for col in ("effect", f"held-out {unit}", f"gain {unit}", f"{over} better", "p (corrected)", "eligible"):
            t.add_column(col)
        for c in r["candidates"]:
            better = f"{c[f'n_{over}_better']}/{c[f'n_{over}']}"
            t.add_row(
                c["effect"], f"{c[f'heldout_rms_{unit}']:.4f}", f"{c[f'gain_{unit}']:+.4f}", better,
                f"{c['p_corrected']:.2g}", "yes" if c["eligible"] else "no",
            )  # fmt: skip
        console.print(t)
        say(console, f"  {r['decision']['reason']}")


def print_verdict(doc: dict[str, Any], console: Any) -> None:
    """The terminal's last lines of a report: the verdict with its reason, then the notes."""
    say(console, f"verdict: {doc['verdict']}: {doc['reason']}")
    for note in doc["notes"]:
        say(console, f"note: {note}")


def write_report_file(path: Path, doc: dict[str, Any]) -> None:
    """Write *doc* to *path* as strict, indented JSON."""
    replace_text(path, json.dumps(doc, indent=2, allow_nan=False) + "\n")


def show_report(doc: dict[str, Any], as_json: bool, print_report: Callable[[dict[str, Any], Any], None]) -> None:
    """``--json``: *doc* on stdout as strict JSON; otherwise *print_report*'s tables on the terminal."""
    if as_json:
        print(json.dumps(doc, indent=2, allow_nan=False))
    else:
        from rich.console import Console

        print_report(doc, Console(width=None if sys.stdout.isatty() else 160))
