"""Gross errors in a kinematic campaign: the robust baseline refit, and the screen's passes over the workflow.

The statistics (robust scale, flag rule) are :mod:`plugins.model_gap.core.robust`'s; this module runs
them on the robot problem:

1. **Robust baseline** (:func:`robust_baseline`): after the baseline calibration (plain least squares
   as :mod:`.problem` does it), the calibration is refitted with scipy ``least_squares(loss="soft_l1",
   f_scale=2 s)``, ``s`` the robust residual scale, re-estimated and refitted three times; then every
   sample beyond the cut is flagged.
2. The workflow runs on the samples kept (the baseline calibrated again on them, the noise estimated
   on them when it is not given).
3. **Final screen** (:func:`final_screen`): every sample of the campaign -- those left out too -- is
   predicted by the final model (the same prediction as ``vgr gap check``: nothing refitted) and
   flagged at the scale of the samples the model was fitted on. A sample the baseline flagged only
   because of an effect the baseline lacked is taken back; one the baseline missed is left out.
   When the set changes the workflow runs again on the new set (at most :data:`MAX_PASSES` passes;
   the result says whether the last pass was stable).

So a few gross errors neither hide an effect (they no longer inflate the residual scale) nor create
one (they no longer pull the fit towards a pattern), and an effect's own large residuals are not
mistaken for gross errors.
"""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np

from plugins.model_gap.core.robust import OutlierScreen, robust_scale, screen
from plugins.model_gap.core.share import structure_union
from plugins.model_gap.core.structure import StructureTest
from plugins.model_gap.core.workflow import GapResult
from plugins.model_gap.data import GapData
from plugins.model_gap.problem import KinematicGapProblem

MAX_PASSES = 3
ROBUST_ROUNDS = 3
F_SCALE = 2.0  # soft_l1's scale in robust sigmas: least squares inside, absolute value far outside


def robust_baseline(problem: KinematicGapProblem, alpha: float) -> tuple[np.ndarray, OutlierScreen]:
    """Refit the baseline with a robust loss and flag the gross errors (step 1 of the module docstring)."""
    for _ in range(ROBUST_ROUNDS):
        lin = problem.linearise()
        s = robust_scale(lin.residual, lin.jacobian.shape[2], alpha=alpha)
        if not s > 0:
            break
        problem.refit(loss="soft_l1", f_scale=F_SCALE * s)
    lin = problem.linearise()
    return screen(lin.residual, lin.sigma, lin.jacobian.shape[2], alpha)


def final_screen(
    problem: KinematicGapProblem,
    data: GapData,
    families: list[Any],
    alpha: float,
    kept: np.ndarray,
    structure: StructureTest | None = None,
) -> tuple[np.ndarray, OutlierScreen, np.ndarray]:
    """Flag every sample of ``data`` with the final model of ``problem`` (fitted on rows ``kept``) at the
    robust scale of its own residuals (step 3 of the module docstring); also every sample's 3-D residual
    norm (SI). When the end test found ``structure`` left, the structure's designs (fitted on the kept
    rows) are taken out of the residuals first: an out-of-catalog error's large residuals are structure,
    not gross errors."""
    from plugins.model_gap.check import stored_problem
    from plugins.model_gap.stored_model import StoredModel, gap_model_dict

    own = problem.linearise()
    s = robust_scale(own.residual, own.jacobian.shape[2], alpha=alpha)
    doc = gap_model_dict(problem)
    stored = StoredModel(problem.model, doc["effects"], "gap model", "the final model", doc["noise_sigma_m"],
                         doc["tool_points"])  # fmt: skip
    noise_mm = None if data.sigma_m is not None else float(np.median(problem.sigma)) * 1e3
    full, _ = stored_problem(stored, data, noise_mm=noise_mm, families=families)
    lin = full.linearise()
    w = lin.residual
    if structure is not None and structure.found:
        U = structure_union(lin, structure, full.features(), full.error_directions())
        if U is not None:
            m = w.shape[1]
            rows = (kept[:, None] * m + np.arange(m)).reshape(-1)
            coef, *_ = np.linalg.lstsq(U[rows], w.reshape(-1)[rows], rcond=1e-10)
            w = w - (U @ coef).reshape(w.shape)
            s = robust_scale(w[kept], own.jacobian.shape[2] + U.shape[1], alpha=alpha)
    mask, sc = screen(w, lin.sigma, own.jacobian.shape[2], alpha, scale=s)
    return mask, sc, np.linalg.norm(w * lin.sigma[:, None], axis=1)


def run_screened(
    data: GapData,
    build: Callable[[GapData], KinematicGapProblem],
    run: Callable[[KinematicGapProblem, Path | None], GapResult],
    families: list[Any],
    alpha: float,
    model_dir: Path | None,
) -> tuple[GapResult, KinematicGapProblem]:
    """The passes of the module docstring: ``build(data)`` makes a problem (baseline calibrated, noise set),
    ``run(problem, model_dir)`` runs the workflow on it. ``alpha`` 0: no screen (one plain pass)."""
    problem = build(data)
    if alpha <= 0:
        return run(problem, model_dir), problem
    mask, first = robust_baseline(problem, alpha)
    history: list[np.ndarray] = []
    for passes in range(1, MAX_PASSES + 1):
        if mask.any():
            problem = build(data.subset(np.flatnonzero(~mask)))
        elif passes == 1:
            problem.refit()  # back from the robust loss to least squares on every sample
        else:
            problem = build(data)
        if passes > 1:
            _clean(model_dir)
        result = run(problem, model_dir)
        kept = np.flatnonzero(~mask)
        new_mask, last, norms = final_screen(problem, data, families, alpha, kept, result.iterations[-1].structure)
        stable = bool(np.array_equal(new_mask, mask))
        if stable or passes == MAX_PASSES or any(np.array_equal(new_mask, h) for h in history):
            break
        history.append(mask)
        mask = new_mask
    ids = np.flatnonzero(mask)
    scale3 = last.scale * np.sqrt(3.0) * float(np.median(problem.sigma))
    sc = OutlierScreen(alpha, last.cut, last.scale, data.n_samples, ids.tolist(), norms[ids].tolist(),
                       (norms[ids] / scale3).tolist(), passes, stable)  # fmt: skip
    sc.notes.append(
        f"baseline screen (least squares refitted with a soft_l1 loss): {first.n_flagged} flagged at a robust "
        f"scale of {first.scale:.3g}x the noise; final screen with the final model at {last.scale:.3g}x"
    )
    if not stable:
        moved = sorted(set(np.flatnonzero(new_mask).tolist()) ^ set(ids.tolist()))
        sc.notes.append(
            f"after {passes} passes the final model still flags rows {moved} differently: the last pass is reported"
        )
    result.outliers = sc
    if sc.ids:
        result.reason += "; " + sc.describe(problem.report_unit, problem.report_scale)
    return result, problem


def _clean(model_dir: Path | None) -> None:
    """Remove the per-round model files of an earlier pass (the last pass writes its own)."""
    if model_dir is None or not Path(model_dir).is_dir():
        return
    for f in Path(model_dir).glob("model_*.yaml"):
        f.unlink()
