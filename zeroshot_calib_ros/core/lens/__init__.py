"""Lens models (layer 0, the bottom): how a camera maps rays to pixels and back.

One class per model, all with the ``CameraModel`` interface (``project`` rays -> pixels,
``unproject`` pixels -> unit rays, ``fields_of_view``, ``K``): the paper's ``ZeroShotCamera``,
``KannalaBrandtCamera`` (ROS ``equidistant``), ``PlumbBobCamera``, ``PinholeCamera`` and the
wide-FOV ``WideFovCamera``; the four fisheye laws of the paper (``projections``); and the fits of
the ROS models to a radial lens (``fitting``). Imports numpy / scipy / OpenCV only, nothing of
this package above it. A new lens model is a new class here (docs/architecture.md).
"""
