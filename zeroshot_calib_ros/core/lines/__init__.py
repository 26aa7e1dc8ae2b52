"""Evidence from straight lines in ordinary images (layer 2): a straight 3-D edge images, through
any central camera, to a curve whose rays lie on one plane through the centre of projection.

``detect`` finds such curves in raw (fisheye) images: virtual pinhole views of the current
camera estimate, LSD segments there, sub-pixel edge points mapped back to raw pixels, pieces of
one line merged across views (``detect_curves``, ``make_views``, ``draw_curves``).
``straightness`` is the evidence term: the pixel-space (maximum-likelihood) residual of a curve
under a camera. May import ``core.lens`` and ``core.zeroshot``; never ``core.checkerboard`` or
anything above (``core.estimation`` combines the evidence).
"""
