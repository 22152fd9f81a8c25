"""Small least-squares helpers shared by the Vive desk and TCP-by-camera calibrations.

Owns: covariance / rank / identifiability of a whitened least-squares problem, residual
consistency (chi-square) and studentised per-sample outlier tests (also against the data's own
scale), and input checks (finite arrays, rotations, metre-vs-millimetre magnitude).

Perturbation convention used by these solvers ("decoupled", documented in docs/vive_and_tcp.md):
a pose ``T_a_b = [R, t]`` is perturbed as ``t' = t + v`` and ``R' = exp(w) R`` with ``v``, ``w``
both expressed in frame *a*; the 6 tangent coordinates are ordered ``(v, w)``. Position standard
deviations therefore read directly in metres along the axes of *a*.
"""

from plugins.calibration.pose_lsq.checks import (
    as_rotation_stack,
    finite_array,
    looks_like_millimetres,
)
from plugins.calibration.pose_lsq.stats import (
    Identifiability,
    analyse_identifiability,
    chi2_consistency,
    marginal_covariance,
    robust_block_pvalues,
    robust_variance_factor,
    studentised_block_tests,
)
from plugins.calibration.pose_lsq.verdict import Issue, combine_verdict, result_from_issues

__all__ = [
    "Identifiability",
    "Issue",
    "analyse_identifiability",
    "as_rotation_stack",
    "chi2_consistency",
    "combine_verdict",
    "finite_array",
    "looks_like_millimetres",
    "marginal_covariance",
    "result_from_issues",
    "robust_block_pvalues",
    "robust_variance_factor",
    "studentised_block_tests",
]
