"""``vgr gap check``: a stored robot model scored on new measurements, refitting nothing.

The model is any model vgr writes (:func:`.stored_model.load_stored_model`): an augmented model of
``vgr gap`` (its calibrated geometry, frames and effects), the result of ``vgr calibrate kinematics``,
or a robot model file whose base is the measurement frame. Its prediction of the new data is the
workflow's own (:class:`.problem.KinematicGapProblem` with the stored effects put in as they are:
nothing is calibrated, no effect refitted), so on the data it was fitted to it reproduces the
workflow's final residuals exactly. ``refit=("tool",)`` refits the measured point on the flange
alone (a new tool or reflector on the same robot and cell), the effects and the geometry held.

The noise: ``noise_mm``, else the data's ``sigma_mm`` column, else the one the model was fitted with
(stored in the file). The statistics, the verdict (``ok`` / ``gap``, not dependent on the stated
noise) and the report are :mod:`plugins.model_gap.core.check`'s.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
from rich.console import Console

from plugins.model_gap.core.check import ModelCheck, check_residuals, render_check, write_check_json
from plugins.model_gap.core.interfaces import GapInputError, Linearisation
from plugins.model_gap.core.workflow import collect_candidates
from plugins.model_gap.data import GapData
from plugins.model_gap.families import families_from_registry
from plugins.model_gap.inputs import load_gap_data
from plugins.model_gap.problem import KinematicGapProblem, ProblemConfig
from plugins.model_gap.stored_model import StoredModel, load_stored_model

REFIT_LEVELS = ("tool",)
TOOL = ("tool.tx", "tool.ty", "tool.tz")


def stored_problem(
    stored: StoredModel, data: GapData, *, noise_mm: float | None = None, families: list[Any] | None = None
) -> tuple[KinematicGapProblem, str]:
    """The gap problem of ``stored`` on ``data`` with its effects as stored (no refit), and the noise source."""
    if noise_mm is not None:
        noise_m, source = float(noise_mm) / 1e3, "given"
    elif data.sigma_m is not None:
        noise_m, source = None, "data column sigma_mm"
    elif stored.noise_sigma_m is not None:
        noise_m, source = stored.noise_sigma_m, "the model file's"
    else:
        raise GapInputError(
            f"{stored.source} does not say the noise it was fitted with: give --noise-mm SIGMA (per axis) or a "
            "sigma_mm column"
        )
    cfg = ProblemConfig((), noise_m=noise_m, noise_source=source, tool_points=stored.tool_points)
    problem = KinematicGapProblem(stored.robot, data, cfg)
    fams = families if families is not None else families_from_registry()
    by_label = {(c.name, c.where): c for c in collect_candidates(problem, fams) if not c.unavailable}
    for e in stored.effects:
        cand = by_label.get((e.get("name"), e.get("where")))
        if cand is None:
            raise GapInputError(
                f"the model's effect {e.get('name')}@{e.get('where')} cannot be applied to these data (a column it "
                "needs is missing)"
            )
        vec = e.get("values") or [float(e["params"][p]) for p in cand.param_names]
        problem.accepted.append((cand, np.array([float(x) for x in vec])))  # as stored: nothing refitted
        if e.get("tied_with"):
            problem.tied_with[f"{cand.name}@{cand.where}"] = tuple(e["tied_with"])
    return problem, source


def _tool_state(problem: KinematicGapProblem) -> np.ndarray:
    """The tool translation (the first point's) and every other point's offset, flattened."""
    tool = problem.model.param_values[[problem.model.chain.index(n) for n in TOOL]]
    return np.concatenate([tool, np.zeros(0) if problem.points is None else problem.points.flat()])


def check_model(
    model: str | Path,
    data: str | Path | GapData,
    *,
    noise_mm: float | None = None,
    refit: tuple[str, ...] = (),
    alpha: float = 1e-3,
    families: list[Any] | None = None,
    report_dir: str | Path | None = None,
    console: Console | None = None,
    data_options: dict[str, Any] | None = None,
) -> ModelCheck:
    """Score the stored ``model`` on ``data`` (see the module docstring); write ``report_dir`` if given
    (``check_report.json``, ``check_plots.png``)."""
    bad = [r for r in refit if r not in REFIT_LEVELS]
    if bad:
        raise GapInputError(f"--refit {','.join(bad)}: only the tool point can be refitted on new data (--refit tool)")
    stored = load_stored_model(model)
    gap_data = data if isinstance(data, GapData) else load_gap_data(data, **(data_options or {}))
    problem, source = stored_problem(stored, gap_data, noise_mm=noise_mm, families=families)
    refitted: dict[str, dict[str, float]] = {}
    before = _tool_state(problem)
    if "tool" in refit:  # every measured point's position on the flange, geometry and effects held
        problem.base_names = list(TOOL) + ([] if problem.points is None else problem.points.param_names())
        problem.refit(effects=False)
    lin = problem.linearise()
    nb = len(problem.base_names)
    lin = Linearisation(lin.residual, lin.jacobian[:, :, :nb], lin.names[:nb], lin.sigma)
    if nb:
        Jw = lin.jacobian.reshape(lin.residual.size, nb)
        s2 = float(np.sum(lin.residual**2)) / max(1, lin.residual.size - nb)
        std = np.sqrt(np.diag(s2 * np.linalg.inv(Jw.T @ Jw)))
        for n, b, a, sd in zip(problem.base_names, before, _tool_state(problem), std, strict=True):
            refitted[n] = {"stored": float(b), "value": float(a), "std": float(sd)}
    info = {
        "kind": stored.kind,
        "source": stored.source,
        "robot": stored.robot.name,
        "effects": [f"{e.get('name')}@{e.get('where')}" for e in stored.effects],
        "refit": list(refit),
        "n_parameters_of_its_fit": stored.n_parameters,
        "n_residuals_of_its_fit": stored.n_residuals,
        "data": gap_data.source,
    }
    feats = problem.features()
    result = check_residuals(
        lin,
        feats,
        expected_factor=stored.expected_factor,
        alpha=alpha,
        noise_source=source,
        refitted=refitted,
        model=info,
        unit=problem.report_unit,
        scale=problem.report_scale,
    )
    if report_dir is not None:
        from plugins.model_gap.core.plots import plot_check

        out = Path(report_dir)
        out.mkdir(parents=True, exist_ok=True)
        result.files["plots"] = str(plot_check(result, feats, out / "check_plots.png"))
        result.files["report"] = str(out / "check_report.json")
        write_check_json(result, out / "check_report.json")
    if console is not None:
        render_check(result, console)
    return result
