"""Interactive light-field viewer: one self-contained HTML file per frame.

The page carries a focal stack over the depth range, the all-in-focus image, the depth map and
its confidence, and the metadata, all inline (images as data: URIs, a Content-Security-Policy
that forbids every network load). Clicking a point refocuses at its depth; the cursor reads the
depth in millimetres.

DOM contract (stable, for tests and scripts): the image element has id ``lf-view``; the text of
``lf-focus-depth`` is the shown focus depth in metres (``0.500``); ``lf-cursor-depth`` is the
depth under the cursor (``512 mm``, or ``-`` where unknown).
"""

from lfring.viewer.page import inspection_overlays, viewer_html, write_viewer

__all__ = ["inspection_overlays", "viewer_html", "write_viewer"]
