"""Calibration from straight lines in ordinary images (layer 2; issue 13, not built yet).

The place for the second evidence source beside ``core.checkerboard``: line detection, the
straightness residual of a lens model, and the refinement of the zero-shot camera from it.
May import ``core.lens`` and ``core.zeroshot``; never ``core.checkerboard`` or anything above.
"""
