"""The ready-made scenes: what the inspection part refuses."""

import pytest

from lfring.errors import InvalidInputError
from lfring.synth.presets import MAX_DEFECT_SIZE_M, PART_SIZE_M, part_scene


def test_part_defect_size_bound():
    # The largest defect still fits on the plate with its clearance; a larger one is refused
    # as a bad input (not a failure of the random placement).
    part = part_scene(defect_heights_m=(0.01,), defect_size_m=MAX_DEFECT_SIZE_M).surfaces[0]
    assert part.bumps[0].size_m == (MAX_DEFECT_SIZE_M, MAX_DEFECT_SIZE_M)
    for size in (0.0, -0.01, MAX_DEFECT_SIZE_M * 1.001, 12.0, float("nan")):
        with pytest.raises(InvalidInputError, match=f"defect size must be .* on the {PART_SIZE_M:g} m part"):
            part_scene(defect_size_m=size)
    with pytest.raises(InvalidInputError, match="give fewer or smaller defects"):
        part_scene(defect_heights_m=(0.01,) * 4, defect_size_m=0.05)
