"""Pictures for a user to look at (OpenCV drawing only): the calibration report of ``solve``,
``refine`` and ``calibrate`` (``calibration_report``) and ``refine``'s contact sheet of the
curves in every image (``debug_sheet``); ``canvas`` draws, ``synthetic`` makes a ruled scene for
a camera without an image."""
