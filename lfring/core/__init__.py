"""The core that several stages share (refocusing, depth, inspection, the checks and the torch
twins): each question answered once, in one place that the stages import.

- :mod:`lfring.core.validate`: the argument checks of every public function.
- :mod:`lfring.core.protocols`: what the stages need of a calibration.
- :mod:`lfring.core.registry`: the table of a stage's named strategies.
- :mod:`lfring.core.viewstack`: view stacks, their valid discs and the per-calibration cache.
- :mod:`lfring.core.warping`: warping into the reference frame and the translation test.
- :mod:`lfring.core.shift`: the shift engine (bilinear shifts in cache-sized strips).
- :mod:`lfring.core.filters`: luminance, its local normalisation, the box filter.
- :mod:`lfring.core.threads`: the thread pool and numba's thread count.
- :mod:`lfring.core.geometry`: homography helpers.
- :mod:`lfring.core.records`: short reprs of records that hold arrays.
- :mod:`lfring.core.backend`: the backends and the lazy import of torch.
- :mod:`lfring.core.signals`: Ctrl-C and SIGTERM held around work that must not be cut in two.
"""
