"""The second round of ``benchmarks/gap.py``: per-run records of the gross-error screen and the summary of
the robust suite (gross outliers, out-of-catalog effects, 40-pose campaigns; ``plugins/sim/model_gap/suite.py``
``robust_suite``), apart from the first round's figures.

Per run (:func:`screen_record`): the rows the workflow left out, how many of the injected gross errors it
found, how many good rows it lost. Summary (:func:`robust_summary`), per noise mode: per group (outliers
per fraction, out-of-catalog, 40 poses) the naming (exact set of in-catalog hidden effects), wrong names,
verdicts, refusals and held-out RMS over the noise floor; for outliers the injected ones found and the good
samples lost; for the out-of-catalog cases each case's verdict, what was added and what the share rule took
out; and over every campaign without injected outliers the screen's realised false-flag rate.
"""

from __future__ import annotations

import numpy as np


def screen_record(res, camp) -> dict:
    """The gross-error screen of one run against the injected rows."""
    flagged = set(res.outliers.ids) if res.outliers is not None else set()
    injected = set() if camp.outlier_rows is None else {int(i) for i in camp.outlier_rows}
    return {
        "flagged": sorted(flagged),
        "injected_found": len(flagged & injected),
        "injected_missed": len(injected - flagged),
        "good_flagged": len(flagged - injected),
        "screen_passes": None if res.outliers is None else res.outliers.passes,
        "screen_stable": None if res.outliers is None else res.outliers.stable,
    }


def _rate(xs) -> float | None:
    xs = list(xs)
    return float(np.mean(xs)) if xs else None


def _group(rows: list[dict], mode: str) -> dict:
    runs = [r["vgr"][mode] for r in rows]
    ok = [v for v in runs if v.get("verdict") != "refused"]
    eff = [(r, v) for r, v in zip(rows, runs, strict=True) if r["expected"]]
    noise = [(r, v) for r, v in zip(rows, runs, strict=True) if not r["expected"]]
    ratio = [v["after_over_floor"] for v in ok if "after_over_floor" in v]
    out = {
        "cases": len(rows),
        "refused": sum(v.get("verdict") == "refused" for v in runs),
        "exact": _rate(v["correct"] for _, v in eff),
        "effect_cases": len(eff),
        "wrong_name_cases": sum(bool(v["wrong_name"]) for v in runs),
        "named_on_effect_free": sum(bool(v["named"]) for _, v in noise),
        "effect_free_cases": len(noise),
        "verdicts": {x: sum(v.get("verdict") == x for v in runs) for x in sorted({v.get("verdict") for v in runs})},
        "heldout_after_over_floor_max": max(ratio) if ratio else None,
        "heldout_after_over_floor_median": float(np.median(ratio)) if ratio else None,
    }
    if any(r["outliers_injected"] for r in rows):
        out["outliers_injected"] = sum(r["outliers_injected"] for r in rows)
        out["outliers_found"] = sum(v.get("injected_found", 0) for v in ok)
        out["good_samples_lost"] = sum(v.get("good_flagged", 0) for v in ok)
    return out


def _off_catalog(rows: list[dict], mode: str) -> list[dict]:
    return [
        {
            "case": r["case"],
            "off_catalog": r["off_catalog"],
            "in_catalog_hidden": r["expected"],
            "verdict": r["vgr"][mode].get("verdict"),
            "named": r["vgr"][mode].get("named"),
            "share_rule_dropped": (r["vgr"][mode].get("share") or {}).get("dropped", []),
            "shares": (r["vgr"][mode].get("share") or {}).get("shares", {}),
            "where_left": r["vgr"][mode].get("where_left", []),
            "advice": r["vgr"][mode].get("advice", [])[:2],
        }
        for r in rows
    ]


def robust_summary(rows: list[dict], modes: tuple[str, ...]) -> dict:
    """The summary of the module docstring (``rows``: every case of the run)."""
    groups: dict[str, list[dict]] = {}
    for r in rows:
        if r["kind"].startswith("outlier_"):
            frac = r["case"].split("-", 1)[0].removeprefix("outliers")
            groups.setdefault(f"outliers_{frac}", []).append(r)
        elif r["kind"] == "off_catalog":
            groups.setdefault("off_catalog", []).append(r)
        elif r["kind"].startswith("small_"):
            groups.setdefault("poses_40", []).append(r)
    clean = [r for r in rows if not r["outliers_injected"]]
    out: dict = {}
    for mode in modes:
        runs = [r["vgr"][mode] for r in clean if r["vgr"][mode].get("verdict") != "refused"]
        samples = sum(r["n_samples"] for r in clean if r["vgr"][mode].get("verdict") != "refused")
        lost = sum(len(v.get("flagged", [])) for v in runs)
        out[mode] = {
            "groups": {k: _group(rs, mode) for k, rs in sorted(groups.items())},
            "off_catalog_cases": _off_catalog(groups.get("off_catalog", []), mode),
            "screen_on_clean_campaigns": {
                "campaigns": len(runs),
                "samples": samples,
                "good_samples_flagged": lost,
                "rate_per_sample": lost / samples if samples else None,
                "campaigns_with_a_flag": sum(bool(v.get("flagged")) for v in runs),
                "nominal": "P(any good sample flagged) <= 1 % per campaign (outlier_alpha 0.01), i.e. 0.01 / N per sample",
            },
        }
    return out
