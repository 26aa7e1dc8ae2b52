"""Calibration from chessboard images (layer 2): the paper's section 4 and its evaluation.

``corners`` (detection, corners files, input checks), ``pose`` (board poses, PnP),
``calibration`` (FC_eq.d. and the OpenCV baselines), ``evaluation`` (the protocol of the
paper's Tables 3 and 4) and ``corner_term`` (corners as an evidence term of ``core.estimation``). Imports ``core.lens`` and ``core.zeroshot``; never ``core.lines``
(its sibling evidence source) or anything above.
"""
