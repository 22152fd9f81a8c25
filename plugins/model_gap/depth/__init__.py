"""The model-gap workflow for a depth camera's range errors: ``vgr gap --depth CAPTURES``.

From depth images of a known flat target (:mod:`.data`, read by :mod:`.inputs`), the range each pixel
measures is compared with the range the target predicts, capture by capture on held-out captures
(:mod:`.crossval`); a catalog effect (:mod:`.catalog`: a range scale, a bias, a quadratic range error,
radial and polynomial per-pixel bias patterns, a ToF's wiggling) is named only when it predicts
held-out captures better than noise explains (the camera workflow's rule,
:mod:`plugins.model_gap.camera.selection`), added, and the loop repeats (:mod:`.workflow`); flying
pixels are screened out first (:mod:`.fitting`); structure left in the residuals makes the verdict
``unexplained`` (:mod:`.structure`). :mod:`.report` writes the ``vgr.depth_gap_report/1`` document,
:mod:`.cli` is the verb's depth half. docs/depth_gap.md has the maths and the measured figures.

Nothing is imported here: ``vgr`` imports the verb's parser on every start.
"""
