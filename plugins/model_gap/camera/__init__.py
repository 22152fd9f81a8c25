"""The model-gap workflow for the camera model: ``vgr gap --camera IMAGES --board SPEC``.

From board detections (plugins.calibration.boards.detect), the baseline camera (pinhole + k1, k2,
fitted by ``cv2.calibrateCamera``) is compared with the detected corners view by view on held-out
views; a catalog effect (:mod:`.catalog`: a third radial term, tangential, thin prism, the rational
model, a tilted sensor; each a set of OpenCV's distortion coefficients) is named only when it
predicts held-out views better than noise explains (:mod:`.selection`), added, and the loop repeats
(:mod:`.workflow`); structure left in the residuals makes the verdict ``unexplained``
(:mod:`.structure`). :mod:`.fitting` and :mod:`.crossval` fit and cross-validate, :mod:`.inputs`
reads images / detections files, :mod:`.report` writes the ``vgr.camera_gap_report/1`` document,
:mod:`.cli` is the verb's camera half. docs/camera_gap.md has the maths and the measured figures.

Nothing is imported here: ``vgr`` imports the verb's parser on every start.
"""
