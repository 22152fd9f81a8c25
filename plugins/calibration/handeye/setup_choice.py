"""Finding the set-up (eye in hand or eye to hand) from the data: both fitted, the likelier one taken.

The two set-ups are two models of the same measurements with the same number of parameters
(X, Y and the true robot poses; ``problem``). Both are fitted by maximum likelihood (``ml``),
each with its own noise (declared, or estimated from its residuals), and compared by
**Vuong's likelihood-ratio test for non-nested models** (Vuong 1989, Econometrica 57(2)): with
``d_i`` the difference of the two models' log-likelihoods of sample i,

    z = sum(d_i) / (sqrt(n) * sd(d_i))

is standard normal for many samples when both models are equally close to the truth; vgr refers it
to Student's t with ``n - 1`` degrees of freedom (the paired t test of the ``d_i``), which is the
same for many samples and honest for few. ``|z|`` beyond the two-sided ``level`` quantile (default
0.1 %: 3.29 for many samples, 6.87 for 6) takes the likelier set-up; otherwise the data cannot
tell them apart (degenerate or too noisy motions) and no set-up is guessed. The models have equal
dimensions, so no complexity correction (AIC / BIC) enters.

Per-sample log-likelihood. Each sample's 12 measured numbers (robot and camera pose) carry 6
nuisance coordinates (the true robot pose), so the likelihood of a sample is that of its 6-dim
*chain misfit* ``c_i = e_camera - G_i e_robot`` (the part no robot pose can explain;
``G_i`` maps a robot pose change into the model camera pose), Gaussian with covariance
``C_i = S_camera + G_i S_robot G_i^T``:

    l_i = -1/2 (min(s_i^2, cap) + log det(2 pi C_i))

where ``s_i^2 = c_i^T C_i^-1 c_i`` is the sample's minimised ML cost (chi-square(6)) and ``cap``
the ML's outlier threshold (a sample flagged as an outlier counts as much as one at the threshold,
the truncated quadratic the robust fit minimises). ``log det C_i`` is what makes fits with
different estimated noise comparable: a set-up that needs 3 deg of camera noise to fit is less
likely than one that needs 0.1 deg, even though both whiten to chi-square(6). (The profile
likelihood of all 12 residuals would be unbounded as the robot noise goes to zero; the chain
misfit's is not.) ``log det C_i`` comes from the nuisance Jacobian ``N_i`` of the whitened
residuals: ``det C = det S_c det S_r det(N^T N) / det(A_r)^2`` with ``A_r`` its unwhitened robot
rows (``det S_c`` each sample's own with per-sample camera covariances).
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray
from scipy import stats

from plugins.calibration.handeye.ml import CHI2_MEDIAN, DOF_PER_SAMPLE, MLFit, MLOptions
from plugins.calibration.handeye.ml_model import EivModel
from plugins.calibration.handeye.problem import SETUPS, Setup
from plugins.calibration.result import CalibrationResult

F64 = NDArray[np.float64]

#: two-sided level of the set-up test: a wrong set-up gives a wrong calibration, refusing costs a flag
SETUP_TEST_LEVEL = 0.001

__all__ = [
    "SETUP_TEST_LEVEL",
    "SetupCandidate",
    "SetupLikelihood",
    "SetupTest",
    "choose_setup",
    "compare_setups",
    "sample_log_likelihood",
]

_MM, _DEG = 1e3, float(np.rad2deg(1.0))
_CAP = float(stats.chi2.ppf(MLOptions().outlier_quantile, DOF_PER_SAMPLE))  # the ML's outlier threshold


@dataclass
class SetupCandidate:
    """One set-up's calibration of the data: its result and, when it was solved, its ML fit."""

    setup: Setup
    result: CalibrationResult
    fit: MLFit | None


@dataclass(frozen=True)
class SetupTest:
    """Vuong's test between the two set-ups; ``chosen`` is None when the data cannot tell them apart."""

    chosen: Setup | None
    likelier: Setup
    z: float  # >= 0: for the likelier set-up
    p_value: float  # two-sided
    log_likelihood_ratio: float  # sum of d_i, likelier minus other
    level: float


@dataclass(frozen=True)
class SetupLikelihood:
    """Per-sample log-likelihoods of one set-up's fit and the noise scale ``k`` they were taken at
    (the fit's variances times ``k``)."""

    loglik: F64
    scale: float
    camera_noise: tuple[float, float]  # (rot rad, trans m), largest sigma per axis, at that scale
    declared: bool


def sample_log_likelihood(
    setup: Setup, T_base_tcp: F64, T_cam_target: F64, fit: MLFit, *, declared: bool = False
) -> SetupLikelihood:
    """Per-sample log-likelihood of the chain misfit at the ML fit (module docstring).

    The fit's noise (declared or estimated) gives the *shape* of the noise; its overall scale ``k``
    is profiled out robustly (``k`` = median s^2 / median of chi-square(6)), so each set-up is judged
    at the noise its own residuals show: a noise level declared a little too optimistic, or an
    estimation that stopped early (a far-off fit), does not decide the comparison. Scaling every
    sigma by ``sqrt(k)`` leaves the fit itself unchanged.
    """
    model = EivModel(setup, T_base_tcp, T_cam_target, fit.noise, fit.X, fit.Y, fit.M)
    st = model.state(np.zeros(model.n_params), jacobian=True)
    s2 = np.sum(model.whitened(st) ** 2, axis=1)
    k = max(float(np.median(s2)) / CHI2_MEDIAN, 1e-12)
    logdet = model.camera_logdet()
    if model.robot_free:
        assert st.J_nuis is not None
        N = st.J_nuis
        A_r = N[:, :6, :] / model.w_robot[None, :, None]
        logdet += 2.0 * float(np.sum(np.log(fit.noise.robot.sigmas6())))
        logdet += np.linalg.slogdet(np.transpose(N, (0, 2, 1)) @ N)[1]
        logdet -= 2.0 * np.linalg.slogdet(A_r)[1]
    dof = DOF_PER_SAMPLE
    loglik = -0.5 * (np.minimum(s2 / k, _CAP) + logdet + dof * np.log(k) + dof * np.log(2.0 * np.pi))
    cam = fit.noise.camera
    camera_noise = (float(np.max(cam.rot_sigma)) * np.sqrt(k), float(np.max(cam.trans_sigma)) * np.sqrt(k))
    return SetupLikelihood(loglik, k, camera_noise, declared)


def compare_setups(loglik: Mapping[Setup, F64], *, level: float = SETUP_TEST_LEVEL) -> SetupTest:
    """Vuong's test on the per-sample log-likelihoods of the two set-ups.

    The statistic is referred to Student's t with ``n - 1`` degrees of freedom (it is the paired t
    statistic of the ``d_i``, with the sample standard deviation): Vuong's normal limit for many
    samples, and not overconfident for the few samples a hand-eye data set may have (with 6 samples
    the normal reference took the wrong set-up in 1 of 100 noisy simulations, this one in none).
    """
    a, b = SETUPS
    d = np.asarray(loglik[a], dtype=float) - np.asarray(loglik[b], dtype=float)
    n = d.size
    total = float(np.sum(d))
    sd = float(np.std(d, ddof=1)) if n > 1 else 0.0
    if sd <= 1e-12 * max(1.0, float(np.max(np.abs(d)))):  # identical fits: nothing to tell them apart
        z = 0.0 if abs(total) <= 1e-9 * n or n < 2 else float(np.sign(total)) * np.inf
    else:
        z = total / (np.sqrt(n) * sd)
    likelier: Setup = a if z >= 0 else b
    p = float(2.0 * stats.t.sf(abs(z), max(n - 1, 1)))
    chosen = likelier if p < level else None
    return SetupTest(chosen, likelier, abs(z), p, abs(total), level)


def chain_spread_all(result: CalibrationResult) -> tuple[float, float]:
    """RMS pose-chain spread (m, rad) over *every* sample of a result, outliers included: a wrong
    set-up fits a few samples and calls the rest outliers, so its inliers' spread says nothing."""
    names = result.residual_names
    if result.residuals is None or "chain_tx" not in names:
        m = result.metrics
        return m["chain_spread_trans_rms_m"], m["chain_spread_rot_rms_rad"]
    k = names.index("chain_tx")
    d = np.asarray(result.residuals, dtype=float)[:, k : k + 6]
    return (
        float(np.sqrt(np.mean(np.sum(d[:, :3] ** 2, axis=1)))),
        float(np.sqrt(np.mean(np.sum(d[:, 3:] ** 2, axis=1)))),
    )


def _misfit_text(c: SetupCandidate, lik: SetupLikelihood, *, taken: bool = False) -> str:
    """How well one set-up fits: its pose-chain spread over all samples and the noise it needs (for
    the set-up taken, the noise its result reports; for the other, its noise at the profiled scale)."""
    m = c.result.metrics
    t_rms, r_rms = chain_spread_all(c.result)
    text = f"the pose chains spread by {t_rms * _MM:.2f} mm / {r_rms * _DEG:.3f} deg RMS"
    if lik.declared:
        factor = np.sqrt(m["variance_factor"]) if taken else np.sqrt(lik.scale)
        return text + f" ({factor:.2g}x the declared noise)"
    rot, trans = (m["noise_camera_rot_rad"], m["noise_camera_trans_m"]) if taken else lik.camera_noise
    return text + f" (camera noise {rot * _DEG:.3g} deg / {trans * _MM:.3g} mm)"


def _test_text(t: SetupTest, n: int) -> str:
    p = f"p = {t.p_value:.2g}" if t.p_value >= 1e-12 else "p < 1e-12"
    return (
        f"log-likelihood ratio {t.log_likelihood_ratio:.1f} over {n} samples, Vuong's z = {t.z:.2f}, {p}; "
        f"a set-up is taken at p < {t.level:g}"
    )


def _test_metrics(t: SetupTest) -> dict[str, float]:
    return {
        "setup_vuong_z": t.z,
        "setup_p_value": t.p_value,
        "setup_log_likelihood_ratio": t.log_likelihood_ratio,
    }


def _other_metrics(other: SetupCandidate, lik: SetupLikelihood) -> dict[str, float]:
    """The misfit of the set-up that was not taken, ``other_setup_*``."""
    t_rms, r_rms = chain_spread_all(other.result)
    return {
        "other_setup_chain_spread_trans_rms_m": t_rms,
        "other_setup_chain_spread_rot_rms_rad": r_rms,
        "other_setup_noise_camera_rot_rad": lik.camera_noise[0],
        "other_setup_noise_camera_trans_m": lik.camera_noise[1],
        "other_setup_noise_scale": lik.scale,
    }


def _unsolved(
    kind: str, reasons: list[str], advice: list[str], metrics: dict[str, float], method: str
) -> CalibrationResult:
    return CalibrationResult(
        kind=kind, verdict="degenerate", reasons=reasons, advice=advice, metrics=metrics, method=method
    )


_STATE_IT = (
    "state the set-up (eye_in_hand: camera on the flange, target fixed; eye_to_hand: camera fixed, target "
    "on the flange; vgr calibrate: --setup)"
)


def choose_setup(
    kind: str,
    T_base_tcp: F64,
    T_cam_target: F64,
    candidates: Mapping[Setup, SetupCandidate],
    *,
    declared: bool = False,
    level: float = SETUP_TEST_LEVEL,
) -> tuple[CalibrationResult, Setup | None]:
    """The result of the set-up the data choose, with the choice and the other's misfit in its
    reasons and metrics; or a ``degenerate`` result (no estimate) when they cannot choose.

    ``declared``: the noise was stated (the text then gives misfits as multiples of it).
    Returns the result and the chosen set-up (None when refused).
    """
    unsolved = [c for c in candidates.values() if c.fit is None]
    if unsolved:  # degenerate motion for one reading at least: it cannot be compared
        reasons: list[str] = []
        advice: list[str] = []
        for c in unsolved:
            reasons += [f"as {c.setup}: {r}" for r in c.result.reasons if f"as {c.setup}: {r}" not in reasons]
            advice += [a for a in c.result.advice if a not in advice]
        reasons.append(
            "the set-up cannot be found from these data: "
            + " and ".join(f"as {c.setup} they are {c.result.verdict}" for c in unsolved)
        )
        metrics = dict(unsolved[0].result.metrics)
        return _unsolved(kind, reasons, [*advice, _STATE_IT], metrics, "set-up test (not solved)"), None
    lik = {
        s: sample_log_likelihood(s, T_base_tcp, T_cam_target, c.fit, declared=declared)  # type: ignore[arg-type]
        for s, c in candidates.items()
    }
    t = compare_setups({s: v.loglik for s, v in lik.items()}, level=level)
    n = T_base_tcp.shape[0]
    a, b = SETUPS
    if t.chosen is None:
        reasons = [
            f"the set-up cannot be found from these data: {a} and {b} fit them about equally well "
            f"({_test_text(t, n)}): as {a} {_misfit_text(candidates[a], lik[a])}, as {b} "
            f"{_misfit_text(candidates[b], lik[b])}"
        ]
        advice = [_STATE_IT, "or add poses with larger rotations about different axes"]
        return _unsolved(kind, reasons, advice, _test_metrics(t), "set-up test (not solved)"), None
    other = b if t.chosen == a else a
    res = candidates[t.chosen].result
    res.reasons.insert(
        0,
        f"set-up {t.chosen} found from the data, the likelier of the two ({_test_text(t, n)}): as {other} "
        f"{_misfit_text(candidates[other], lik[other])}, as {t.chosen} "
        f"{_misfit_text(candidates[t.chosen], lik[t.chosen], taken=True)}",
    )
    res.metrics["setup_found_from_data"] = 1.0
    res.metrics.update({**_test_metrics(t), **_other_metrics(candidates[other], lik[other])})
    res.method += f"; set-up {t.chosen} found from the data (Vuong's test, z = {t.z:.1f})"
    return res, t.chosen
