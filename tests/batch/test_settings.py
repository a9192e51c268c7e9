"""lfring.batch.settings: what BatchSettings refuses, and the keys of earlier versions' records."""

import pytest

from lfring.batch import BatchSettings
from lfring.errors import InvalidInputError


@pytest.mark.parametrize(
    "kwargs, text",
    [
        ({}, "nothing to do"),
        ({"refocus_m": (0.0,)}, "positive"),
        ({"refocus_m": (0.5, 0.5)}, "repeat"),
        ({"depth": True}, "zmin_m and zmax_m"),
        ({"depth": True, "zmin_m": 0.8, "zmax_m": 0.4}, "smaller"),
        ({"refocus_m": (0.5,), "bit_depth": 12}, "bit_depth"),
        ({"refocus_m": (0.5,), "planes": 1}, "planes"),
        # Two planes leave the semi-global depth nothing to judge its answers against: the
        # batch's own depth map or the viewer's.
        ({"depth": True, "zmin_m": 0.3, "zmax_m": 1.0, "planes": 2}, "planes must be an integer >= 3"),
        ({"viewer": True, "planes": 2}, "planes must be an integer >= 3"),
    ],
)
def test_settings_errors(kwargs, text):
    with pytest.raises(InvalidInputError, match=text):
        BatchSettings(**kwargs)


def test_legacy_key_is_the_key_of_records_before_output_keys():
    # 6e76e9ced5695793 is what BatchSettings(refocus_m=(0.5,)).key() returned before per-output
    # keys (commit 188722c): folders made then resume instead of being refused.
    # (its default interpolation was cubic then).
    assert BatchSettings(refocus_m=(0.5,), interpolation="cubic").legacy_key() == "6e76e9ced5695793"
    assert BatchSettings(refocus_m=(0.5,), pattern="RGGB").legacy_key() is None
