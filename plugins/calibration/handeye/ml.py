"""Maximum-likelihood refinement of hand-eye unknowns on SE(3), robust to outliers.

Runs :class:`ml_model.EivModel` through ``scipy.optimize.least_squares`` in four phases:

1. **Robust fit** - iteratively reweighted least squares on the per-sample Mahalanobis norm
   ``s_i`` (its square is chi-square with 6 degrees of freedom): Huber weight ``min(1, c / s_i)`` or
   Cauchy weight ``1 / (1 + s_i^2 / c^2)``, with ``c^2`` the ``robust_quantile`` of chi-square(6)
   times a robust variance factor (median of ``s_i^2`` over the chi-square median; never below 1
   when the noise is declared, so a correct noise model is not tightened by chance). Samples beyond
   the outlier threshold get weight 0 (Huber's bounded pull of gross outliers would bias the fit).
2. **Outliers** - samples with ``s_i^2`` above the ``outlier_quantile`` of chi-square(6) (same
   scaling) are flagged and left out of the final estimate.
3. **Noise estimation** (``estimate_noise=True``) - variance-component estimation (Förstner /
   Helmert): each of the groups robot-translation, robot-rotation, camera-translation,
   camera-rotation (or each camera axis, ``MLOptions.camera_axes``; or, when each sample has its
   own camera covariance, one common factor of them: their shape and per-sample scale are kept)
   gets the factor ``sum of squared whitened residuals / redundancy`` until the
   factors are within 1 % of 1 or the update moves the estimated translations by less than 1 % of
   their sigma. Groups whose redundancy is below 1 are not estimable and keep their prior. Robot
   and camera translation noise are hardly separable (both add isotropically to the pose chain);
   then only their sum is determined, which is also all the estimate depends on. The outliers are
   then flagged again on the estimated noise (Pope's tau test, ``6 F(6, nu)``), with the bound
   moved out when the studentized costs show a heavy tail (``tails``: a multivariate-t model,
   Lange, Little & Taylor 1989, chosen over Gaussian noise by a likelihood-ratio test, fitted on
   the costs up to 3x Pope's bound and never extrapolated beyond them), and the noise estimated
   again without the samples that changed.
4. **Final ML fit** on the inliers with the final noise; the covariance of (X, Y) is the inverse
   Fisher information at the optimum (Gauss-Newton, nuisance robot poses eliminated exactly by the
   Schur complement). It is *unscaled* here; ``solver`` decides on the a-posteriori scaling. With
   the noise estimated, the covariance rests on estimated variance components: it is the
   Kenward-Roger adjusted one (``variance``), and the F distribution's degrees of freedom and scale
   for X and for (X, Y) say how wide a confidence region must be (``F`` instead of chi-square).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any, Literal

import numpy as np
from numpy.typing import NDArray
from scipy import stats
from scipy.optimize import least_squares

from plugins.calibration.handeye.ml_model import EivModel, EivState
from plugins.calibration.handeye.noise import NoiseModel, PoseNoise
from plugins.calibration.handeye.problem import Setup
from plugins.calibration.handeye.tails import TailFit, fit_tail
from plugins.calibration.handeye.variance import group_rows, kenward_roger

F64 = NDArray[np.float64]
Loss = Literal["huber", "cauchy", "linear"]
DOF_PER_SAMPLE = 6
CHI2_MEDIAN = float(stats.chi2.median(DOF_PER_SAMPLE))

__all__ = ["DOF_PER_SAMPLE", "Loss", "MLFit", "MLOptions", "chi2_at", "refine_ml"]


@dataclass(frozen=True)
class MLOptions:
    """Options of :func:`refine_ml`."""

    loss: Loss = "huber"
    robust_quantile: float = 0.99
    outlier_quantile: float = 0.999
    estimate_noise: bool = False
    # estimated camera noise: one variance component per axis of the camera frame (a depth camera's
    # or PnP's noise is largest along the optical axis) instead of one for translation, one for
    # rotation; None: per axis when each component would rest on MIN_REDUNDANCY_PER_COMPONENT
    # redundant residuals or more (8 poses: 4.5 each, and per axis erred 7 % more than pooled on
    # isotropic noise; benchmarks/handeye_streams.py)
    camera_axes: bool | None = None
    # with the noise estimated: the outliers flagged again with it, and the noise estimated again
    # without the ones that changed, at most this many times
    max_reflag_rounds: int = 3
    # with the noise estimated: the outlier bound moved out when the costs show a heavy (t) tail
    # (``tails``); False: Pope's Gaussian bound always
    heavy_tails: bool = True
    max_robust_iterations: int = 15
    max_noise_iterations: int = 30
    dense_max_params: int = 200
    max_nfev: int = 200


@dataclass
class MLFit:
    """Result of :func:`refine_ml` (SI units; covariance unscaled, in decoupled perturbations)."""

    X: F64
    Y: F64
    M: F64  # (n, 4, 4) ML estimate of the true robot poses
    e_robot: F64  # (n, 6) measured (-) estimated robot pose
    e_camera: F64  # (n, 6) measured (-) model camera pose
    s2: F64  # (n,) per-sample whitened cost, ~ chi-square(6) for inliers
    weights: F64  # (n,) final robust weights of phase 1
    outliers: NDArray[np.bool_]
    covariance: F64  # (12, 12) for (X, Y), unscaled
    noise: NoiseModel  # noise model of the final fit (estimated when asked)
    chi2: float  # sum of s2 over inliers
    dof: int  # 6 * n_inliers - 12
    threshold_scale: float  # variance factor used for the robust / outlier thresholds
    nfev: int
    converged: bool
    noise_groups_estimated: int = 0  # variance components with redundancy >= 1 (0: noise not estimated)
    # per-sample camera covariances: the factor the given ones were multiplied by (estimated; 1 declared)
    camera_covariance_factor: float = 1.0
    # estimated noise (``variance``, Kenward-Roger): F(k, dof) denominator degrees of freedom and scale
    # lambda of the confidence regions of X (6) and of (X, Y) (12), and the factor by which the
    # adjustment widened X's covariance (mean over its 6 whitened directions); inf / 1 when declared
    dof_x: float = float("inf")
    dof_xy: float = float("inf")
    f_scale_x: float = 1.0
    f_scale_xy: float = 1.0
    kr_inflation_x: float = 1.0
    outlier_quantile: float = 0.999  # the quantile of the noise beyond which a sample is flagged
    # with the noise estimated: the last outlier test's tail fit (``tails``; heavy False: Gaussian)
    tail: TailFit | None = None
    notes: list[str] = field(default_factory=list)


def _robust_weights(s2: F64, loss: Loss, c2: float) -> F64:
    if loss == "linear":
        return np.ones_like(s2)
    if loss == "huber":
        s = np.sqrt(np.maximum(s2, 1e-300))
        return np.minimum(1.0, np.sqrt(c2) / s)
    if loss == "cauchy":
        return 1.0 / (1.0 + s2 / c2)
    raise ValueError(f"unknown loss {loss!r}; use 'huber', 'cauchy' or 'linear'")


def _solve(model: EivModel, weights: F64, opts: MLOptions) -> tuple[EivModel, int, bool]:
    """One weighted least-squares solve; returns the model recentred at the optimum."""
    sqrt_w = np.sqrt(weights)
    dense = model.n_params <= opts.dense_max_params
    x0 = np.zeros(model.n_params)
    kw = dict(xtol=1e-10, ftol=1e-12, gtol=1e-12, max_nfev=opts.max_nfev, x_scale="jac")
    if dense:
        res = least_squares(
            lambda x: model.residual_vector(x, sqrt_w),
            x0,
            jac=lambda x: model.jacobian_matrix(x, sqrt_w, as_sparse=False),
            method="lm",
            **kw,
        )
    else:
        res = least_squares(
            lambda x: model.residual_vector(x, sqrt_w),
            x0,
            jac=lambda x: model.jacobian_matrix(x, sqrt_w, as_sparse=True),
            method="trf",
            tr_solver="lsmr",
            **kw,
        )
    return model.recentred(res.x), int(res.nfev), bool(res.status > 0)


def _per_sample_cost(model: EivModel, st: EivState) -> F64:
    return np.sum(model.whitened(st) ** 2, axis=1)


def _redundancy_groups(model: EivModel, st: EivState, weights: F64) -> tuple[F64, F64]:
    """Per noise group (``variance.group_rows``): sum of weighted squared residuals, redundancy."""
    use = weights > 0
    h = model.hat_diagonal(st, weights)[use]
    e2 = (model.whitened(st)[use] ** 2) * weights[use][:, None]
    groups = group_rows(model)
    omega = np.array([e2[:, g].sum() for g in groups])
    redund = np.array([(1.0 - h[:, g]).sum() for g in groups])
    return omega, redund


SIGMA_FLOOR = 1e-9  # m or rad: below this a noise component is numerically zero


def _vce_step(model: EivModel, st: EivState, weights: F64, noise: NoiseModel) -> tuple[NoiseModel, F64, F64]:
    omega, redund = _redundancy_groups(model, st, weights)
    factor = np.where(redund >= 1.0, omega / np.maximum(redund, 1e-12), 1.0)
    factor = np.clip(factor, 1e-4, 1e4)
    cam = noise.camera.sigmas6()  # (tx, ty, tz, rx, ry, rz)
    sig: list[tuple[float, ...]] = [noise.robot.trans_sigma, noise.robot.rot_sigma] if model.robot_free else []
    if model.camera_per_sample:  # one common factor of the per-sample covariances (``variance.group_rows``)
        sig.append(tuple(cam))
    else:
        sig += [(c,) for c in cam] if model.camera_axes else [tuple(cam[:3]), tuple(cam[3:])]
    current = np.array([min(g) for g in sig])
    # a component already at the floor cannot shrink further: report it as converged
    factor = np.maximum(factor, (SIGMA_FLOOR / current) ** 2)
    factor = np.where(current * np.sqrt(factor) <= SIGMA_FLOOR * 1.0001, 1.0, factor)
    f = np.sqrt(factor)
    robot = noise.robot
    if model.robot_free:
        robot = noise.robot.scaled(rot_factor=f[1], trans_factor=f[0])
        f = f[2:]
    if model.camera_per_sample:
        assert noise.camera_covariances is not None
        return NoiseModel(robot, noise.camera, noise.camera_covariances * float(f[0]) ** 2), factor, redund
    per_axis = f if model.camera_axes else np.repeat(f, 3)
    camera = PoseNoise(cam[3:] * per_axis[3:], cam[:3] * per_axis[:3])
    return NoiseModel(robot, camera), factor, redund


@dataclass(frozen=True)
class _RobustFit:
    """Phase 1's outcome: the model at the robust optimum and what the later phases need of it."""

    model: EivModel
    weights: F64  # robust weights after the last iteration
    last_solved_w: F64  # the weights of the last solve (phase 4 need not repeat it with the same)
    scale: float  # variance factor of the robust / outlier thresholds
    nfev: int
    converged: bool


@dataclass(frozen=True)
class _Covariance:
    """Phase 4's covariance of (X, Y) and, with the noise estimated, its Kenward-Roger figures."""

    matrix: NDArray[np.floating[Any]]
    dof_x: float = float("inf")
    dof_xy: float = float("inf")
    f_scale_x: float = 1.0
    f_scale_xy: float = 1.0
    kr_inflation_x: float = 1.0


def _threshold_scale(s2: F64, mask: NDArray[np.bool_], noise_declared: bool) -> float:
    """Robust variance factor of the thresholds: median of ``s2`` over ``mask`` against chi-square(6)'s
    median; never below 1 for a declared noise (so a correct noise model is not tightened by chance)."""
    if not np.any(mask):
        return 1.0
    vf = float(np.median(s2[mask]) / CHI2_MEDIAN)
    return max(1.0, vf) if noise_declared else max(vf, 1e-12)


def _robust_fit(model: EivModel, weights: F64, opts: MLOptions) -> _RobustFit:
    """Phase 1: iteratively reweighted least squares (module docstring) from ``weights``."""
    noise_declared = not opts.estimate_noise
    nfev_total, converged = 0, True
    scale = 1.0
    last_solved_w = weights
    for _ in range(opts.max_robust_iterations):
        last_solved_w = weights
        model, nfev, ok = _solve(model, weights, opts)
        nfev_total += nfev
        converged &= ok
        s2 = _per_sample_cost(model, model.state(np.zeros(model.n_params)))
        scale = _threshold_scale(s2, weights > 0.5, noise_declared)
        new_w = _robust_weights(s2, opts.loss, float(stats.chi2.ppf(opts.robust_quantile, DOF_PER_SAMPLE)) * scale)
        if opts.loss != "linear":  # beyond the outlier threshold a sample no longer pulls at all
            new_w[s2 > float(stats.chi2.ppf(opts.outlier_quantile, DOF_PER_SAMPLE)) * scale] = 0.0
        done = np.max(np.abs(new_w - weights)) < 1e-3
        weights = new_w
        if done or opts.loss == "linear":
            break
    return _RobustFit(model, weights, last_solved_w, scale, nfev_total, converged)


def _flag_outliers(
    model: EivModel, n: int, scale: float, opts: MLOptions, notes: list[str]
) -> tuple[NDArray[np.bool_], F64]:
    """Phase 2: the outlier flags and the inlier weights of the later phases (all ``n`` samples, with
    a note, when fewer than 3 inliers would be left)."""
    st = model.state(np.zeros(model.n_params))
    s2 = _per_sample_cost(model, st)
    out_thr = float(stats.chi2.ppf(opts.outlier_quantile, DOF_PER_SAMPLE)) * scale
    outliers = s2 > out_thr
    if opts.loss == "linear":
        inlier_w = np.ones(n)
    else:
        inlier_w = (~outliers).astype(float)
    if np.count_nonzero(inlier_w) < 3:
        notes.append("fewer than 3 inliers: the robust fit could not separate outliers; all samples used")
        inlier_w = np.ones(n)
        outliers = np.zeros(n, dtype=bool)
    return outliers, inlier_w


def _flag_with_estimated_noise(
    model: EivModel, outliers: NDArray[np.bool_], opts: MLOptions
) -> tuple[NDArray[np.bool_], F64, TailFit]:
    """Phase 3's outlier flags, on the noise just estimated (Pope's tau test, per sample): each
    sample's cost studentized by its redundancy ``r_i`` (the sum of its residuals' redundancy
    numbers, at most 6): ``6 s_i^2 / r_i`` for a sample in the fit, ``r_i s_i^2 / 6`` for one left
    out (its residual is a prediction, wider by ``1 / (1 - h)``), against ``6 F(6, nu)`` at
    ``outlier_quantile``, ``nu`` the redundancy the noise was estimated from. The flags and the
    inlier weights; none flagged when fewer than 3 inliers would be left. With
    ``MLOptions.heavy_tails`` the bound moves out when the costs show a heavier tail than Gaussian
    noise gives (``tails.fit_tail``: a multivariate-t tail, Lange, Little & Taylor 1989); the fit
    is returned too."""
    st = model.state(np.zeros(model.n_params), jacobian=True)
    s2 = _per_sample_cost(model, st)
    h = model.hat_diagonal(st, np.ones(model.n))
    r = np.clip(np.sum(1.0 - h, axis=1), 0.5, DOF_PER_SAMPLE)
    stud = np.where(outliers, s2 * r / DOF_PER_SAMPLE, s2 * DOF_PER_SAMPLE / r)
    nu = max(float(np.sum(r[~outliers])) - 12.0, 1.0)
    thr = DOF_PER_SAMPLE * float(stats.f.ppf(opts.outlier_quantile, DOF_PER_SAMPLE, nu))
    tail = fit_tail(stud, thr, opts.outlier_quantile) if opts.heavy_tails else TailFit(thr, False)
    flagged = stud > tail.threshold
    if np.count_nonzero(~flagged) < 3:
        flagged = outliers
    return flagged, np.ones(model.n) if opts.loss == "linear" else (~flagged).astype(float), tail


def _estimate_noise(
    model: EivModel, inlier_w: F64, noise: NoiseModel, opts: MLOptions
) -> tuple[EivModel, NoiseModel, NDArray[np.bool_], int]:
    """Phase 3: variance-component estimation on the inliers (module docstring). Returns the model
    with the estimated noise, that noise, the groups estimable (redundancy >= 1) and the evaluations."""
    nfev_total = 0
    current = noise
    previous: F64 | None = None
    for _ in range(opts.max_noise_iterations):
        model, nfev, _ok = _solve(model, inlier_w, opts)
        nfev_total += nfev
        st = model.state(np.zeros(model.n_params), jacobian=True)
        xy = np.concatenate([st.X[:3, 3], st.Y[:3, 3]])
        # stop when the noise update no longer moves the estimate (1 % of its sigma)
        if previous is not None:
            cov = np.linalg.pinv(model.information_xy(st, inlier_w))
            sd_t = np.sqrt(np.clip(np.diag(cov)[[0, 1, 2, 6, 7, 8]], 1e-300, None))
            if np.max(np.abs(xy - previous) / sd_t) < 0.01:
                break
        previous = xy
        current, factor, redund = _vce_step(model, st, inlier_w, current)
        model = model.with_noise(current)
        if np.all(np.abs(factor - 1.0) < 0.01):
            break
    return model, current, redund >= 1.0, nfev_total


def _covariance(
    model: EivModel, st: EivState, inlier_w: F64, estimated_groups: NDArray[np.bool_] | None, notes: list[str]
) -> _Covariance:
    """Phase 4's covariance: the inverse Fisher information at the optimum (the pseudo-inverse, with a
    note, when singular); Kenward-Roger's (``variance``) when ``estimated_groups`` says the noise was
    estimated."""
    info = model.information_xy(st, inlier_w)
    try:
        cov = np.linalg.inv(info)
    except np.linalg.LinAlgError:
        cov = np.linalg.pinv(info)
        notes.append("information matrix singular: covariance from the pseudo-inverse")
    if estimated_groups is None:
        return _Covariance(cov)
    # the covariance rests on estimated variances: Kenward-Roger (``variance``)
    kr = kenward_roger(model, st, inlier_w, estimated_groups, [slice(0, 6), slice(0, 12)])
    kr_inflation_x = float(np.trace(np.linalg.solve(cov[:6, :6], kr.covariance[:6, :6]))) / 6.0
    dof_x, dof_xy = kr.dof
    f_scale_x, f_scale_xy = kr.f_scale
    return _Covariance(kr.covariance, dof_x, dof_xy, f_scale_x, f_scale_xy, kr_inflation_x)


MIN_REDUNDANCY_PER_COMPONENT = 8.0


def _camera_axes(opts: MLOptions, n: int, noise: NoiseModel) -> bool:
    """Whether the camera noise is estimated per axis (``MLOptions.camera_axes``)."""
    if opts.camera_axes is not None:
        return opts.camera_axes
    components = (2 if not noise.robot.is_exact else 0) + 6
    return DOF_PER_SAMPLE * n - 12 >= MIN_REDUNDANCY_PER_COMPONENT * components


def refine_ml(
    setup: Setup,
    T_base_tcp: F64,
    T_cam_target: F64,
    X0: F64,
    Y0: F64,
    noise: NoiseModel,
    *,
    options: MLOptions | None = None,
    initial_weights: F64 | None = None,
) -> MLFit:
    """ML estimate of X, Y (and the true robot poses) from validated samples; see module docstring."""
    opts = options or MLOptions()
    n = T_base_tcp.shape[0]
    notes: list[str] = []
    prior = noise
    estimable = 0
    model = EivModel(setup, T_base_tcp, T_cam_target, noise, X0, Y0, camera_axes=_camera_axes(opts, n, noise))
    estimated_groups = np.zeros(len(group_rows(model)), dtype=bool)
    weights = np.ones(n)
    if initial_weights is not None and opts.loss != "linear":
        weights = np.asarray(initial_weights, dtype=float).copy()

    robust = _robust_fit(model, weights, opts)
    model, nfev_total, converged = robust.model, robust.nfev, robust.converged
    outliers, inlier_w = _flag_outliers(model, n, robust.scale, opts, notes)
    tail: TailFit | None = None
    if opts.estimate_noise:
        for _ in range(1 + opts.max_reflag_rounds):
            model, noise, estimated_groups, nfev = _estimate_noise(model, inlier_w, noise, opts)
            nfev_total += nfev
            # the flags of phase 2 rest on the prior's shape of the noise: flagged again with the estimate
            again, again_w, tail = _flag_with_estimated_noise(model, outliers, opts)
            if np.array_equal(again, outliers):
                break
            outliers, inlier_w = again, again_w
        estimable = int(np.count_nonzero(estimated_groups))

    # ---- phase 4: final ML fit on inliers and covariance (phase 1 already is it when nothing changed)
    if opts.estimate_noise or not np.array_equal(inlier_w, robust.last_solved_w):
        model, nfev, ok = _solve(model, inlier_w, opts)
        nfev_total += nfev
        converged &= ok
    st = model.state(np.zeros(model.n_params), jacobian=True)
    s2 = _per_sample_cost(model, st)
    cov = _covariance(model, st, inlier_w, estimated_groups if opts.estimate_noise else None, notes)
    return MLFit(
        X=st.X,
        Y=st.Y,
        M=st.M.copy(),
        e_robot=st.e_robot,
        e_camera=st.e_camera,
        s2=s2,
        weights=robust.weights,
        outliers=outliers,
        covariance=0.5 * (cov.matrix + cov.matrix.T),
        noise=noise,
        chi2=float(np.sum(s2[inlier_w > 0])),
        dof=DOF_PER_SAMPLE * int(np.count_nonzero(inlier_w)) - 12,
        threshold_scale=robust.scale,
        nfev=nfev_total,
        converged=converged,
        noise_groups_estimated=estimable,
        camera_covariance_factor=_covariance_factor(prior, noise),
        dof_x=cov.dof_x,
        dof_xy=cov.dof_xy,
        f_scale_x=cov.f_scale_x,
        f_scale_xy=cov.f_scale_xy,
        kr_inflation_x=cov.kr_inflation_x,
        outlier_quantile=opts.outlier_quantile,
        tail=tail,
        notes=notes,
    )


def _covariance_factor(prior: NoiseModel, noise: NoiseModel) -> float:
    """The factor per-sample camera covariances were multiplied by from *prior* to *noise* (1 without)."""
    if prior.camera_covariances is None or noise.camera_covariances is None:
        return 1.0
    return float(np.trace(noise.camera_covariances[0]) / np.trace(prior.camera_covariances[0]))


def chi2_at(
    setup: Setup, T_base_tcp: F64, T_cam_target: F64, X0: F64, Y0: F64, noise: NoiseModel, weights: F64
) -> tuple[float, F64, F64]:
    """The ML optimum with the noise and the sample weights held (a profile over something outside
    the model, e.g. the camera's scale in ``free_scale``): its chi-square and (X, Y)."""
    model = EivModel(setup, T_base_tcp, T_cam_target, noise, X0, Y0)
    model, _, _ = _solve(model, weights, MLOptions())
    st = model.state(np.zeros(model.n_params))
    return float(np.sum(weights * _per_sample_cost(model, st))), st.X, st.Y
