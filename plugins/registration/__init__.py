"""Point-cloud matchers of seed 000 (method A: cloud registration; method B: feature frame) and the
planar-corrected global registration of seed 004.

Every matcher returns a :class:`RegistrationResult` whose ``T_match`` maps CURRENT points onto the
TEMPLATE (``p_template = T_match @ p_current``), with a verdict (ok / ambiguous / failed) and reasons,
and never raises on bad input. See docs/registration.md.

Public API::

    register_fine(current, template, T_init=None, params=FineParams())       -> RegistrationResult
        (FineParams(edges=EdgeParams(mode="auto" | "on" | "off")): the contour term, edges.py)
    register_global(current, template, params=GlobalParams())                 -> RegistrationResult
    register_feature_frame(current, template_frame_or_cloud, FeatureFrameParams()) -> RegistrationResult
    fit_feature_frame(cloud, FeatureFrameParams(), reference=None)            -> FeatureFrame
    prepare_cloud(cloud, PreprocessParams())                                  -> PreparedCloud
    make_template(cloud, T_base_tcp_photo, name=..., kind="cloud" | "feature_frame") -> Template
    save_template(template, directory) -> Path;  load_template(path) -> Template
"""

from plugins.registration.edges import EdgeParams
from plugins.registration.feature_frame import (
    FeatureFrame,
    FeatureFrameParams,
    fit_feature_frame,
    register_feature_frame,
)
from plugins.registration.fine import FineParams, register_fine
from plugins.registration.fine_backends import BACKENDS
from plugins.registration.fpfh_ransac import FpfhParams
from plugins.registration.global_registration import GlobalParams, register_global
from plugins.registration.planar import PlanarParams
from plugins.registration.preprocess import PreparedCloud, PreprocessParams, RoiBox, prepare_cloud
from plugins.registration.result import Hypothesis, RegistrationResult, Verdict, WeakDirection
from plugins.registration.template import Template, load_template, make_template, save_template
from plugins.registration.validation import InvalidInputError

__all__ = [
    "BACKENDS",
    "EdgeParams",
    "FeatureFrame",
    "FeatureFrameParams",
    "FineParams",
    "FpfhParams",
    "GlobalParams",
    "Hypothesis",
    "InvalidInputError",
    "PlanarParams",
    "PreparedCloud",
    "PreprocessParams",
    "RegistrationResult",
    "RoiBox",
    "Template",
    "Verdict",
    "WeakDirection",
    "fit_feature_frame",
    "load_template",
    "make_template",
    "prepare_cloud",
    "register_feature_frame",
    "register_fine",
    "register_global",
    "save_template",
]
