"""Estimation: one maximum-a-posteriori fit of a camera over all its evidence (layer 3, issue 13).

The evidence sources of layer 2 (``core.lines``: straight lines in ordinary images;
``core.checkerboard``: boards) each give residual blocks; this package weighs them against the
spec sheet and stated priors and decides whether the result may replace the zero-shot camera.
May import ``core.lens``, ``core.zeroshot``, ``core.lines`` and ``core.checkerboard``; never
``core.ros_formats``, ``core.streaming``, ``core`` itself, the CLI or the node.

- ``parameters.py``: parameter layouts (vector <-> camera): ``KannalaBrandtLayout`` (f, cx, cy and
  k1..kn as deviations from a base shape; the refined camera, ROS ``equidistant``) and
  ``ZeroShotLayout`` (the zero-shot model's f and a = w f, the principal point and a deviation of
  the law, for the zero-shot camera's own error bar).
- ``terms.py``: one evidence type per class, each with unwhitened ``residuals(camera)``, its
  ``sigma`` and its robust ``loss``: ``FovTerm`` (the spec's FOVs with a tolerance),
  ``PrincipalPointPrior``, ``ShapePrior``; ``core.lines.straightness.StraightnessTerm`` has the
  same interface.
- ``problem.py``: ``Problem`` stacks and whitens the terms, applies each term's robust loss and
  solves with ``scipy.optimize.least_squares``; it knows nothing of what the terms mean.
- ``zero_shot.py``: ``zero_shot_start``, the spec's zero-shot result made once per run (the solution,
  its camera fitted to Kannala-Brandt k1..k4 at the images' size: ``zero_shot_camera``, its error
  bar) as a ``ZeroShotStart``, which every fit below takes as its ``solution`` instead of solving
  the spec again.
- ``fit.py``: the robust MAP fit over line evidence: outlier curves rejected by their RMS, the
  model order chosen by an information criterion.
- ``uncertainty.py``: covariance from the whitened Jacobian at the solution, propagated to the
  RMS over the image of the 1-sigma pixel displacement; ``zero_shot_uncertainty``; explicitly
  ``None`` with the reason when it cannot be estimated.
- ``refine.py``: ``refine_camera`` (the fit plus the quality gate, returning a ``Refinement``)
  ``refine_from_frames`` (it over several frames, what stays put across them left out: what
  ``refine_from_images`` and the node's refine worker both fit) and ``refine_from_images``
  (detection and fit in a loop).
- ``board_fit.py``: ``fit_board``: the MAP over chessboard corners (``core.checkerboard.corner_term.
  CornerTerm``), the spec FOVs and the priors; ``calibrate`` with the spec as evidence.

How to add an evidence type: a class with ``name``, ``residuals(camera)`` (1-D, unwhitened, in
its natural unit), ``sigma`` (scalar or per residual, same unit), ``loss`` (None, 'soft_l1' or
'cauchy'), ``loss_scale`` (in sigmas) and ``group`` (residuals per robust unit, e.g. 2 for a
pixel); append an instance to a ``Problem``'s terms. Nothing else changes.
"""
